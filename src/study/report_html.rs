//! `report.html`: the Markdown report rendered as one self-contained page (figures embedded as base64
//! PNG data URIs, tables as HTML tables), so it can be mailed or archived as a single file. Writing to a
//! `String` cannot fail, so `writeln!` results are discarded.

use std::fmt::Write as _;
use std::path::Path;

use crate::io::write_atomic_bytes;
use crate::{Error, Result};

/// Standard base64 (RFC 4648, with padding).
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (u32::from(c[0]) << 16)
            | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
            | u32::from(*c.get(2).unwrap_or(&0));
        for (i, shift) in [18, 12, 6, 0].into_iter().enumerate() {
            if i <= c.len() {
                s.push(A[(n >> shift & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// `(text, target)` of a Markdown link `[text](target)` or image `![text](target)` after the list dash.
fn link(item: &str) -> Option<(&str, &str)> {
    let item = item.trim_start_matches('!');
    let close = item.find("](")?;
    Some((item.get(1..close)?, item.get(close + 2..item.len() - 1)?))
}

/// `text` escaped, with inline Markdown links `[a](b)` as `<a href="b">a</a>`.
fn inline(text: &str) -> String {
    let mut h = String::new();
    let mut rest = text;
    while let Some(open) = rest.find('[') {
        let Some((label, target, len)) = rest[open..].find("](").and_then(|close| {
            let after = &rest[open + close + 2..];
            let end = after.find(')')?;
            Some((
                &rest[open + 1..open + close],
                &after[..end],
                close + 2 + end + 1,
            ))
        }) else {
            break;
        };
        h.push_str(&escape(&rest[..open]));
        let _ = write!(h, "<a href=\"{}\">{}</a>", escape(target), escape(label));
        rest = &rest[open + len..];
    }
    h.push_str(&escape(rest));
    h
}

fn table_row(line: &str, cell: &str) -> String {
    let cells: Vec<String> = line
        .trim_matches('|')
        .split('|')
        .map(|c| format!("<{cell}>{}</{cell}>", escape(c.trim())))
        .collect();
    format!("<tr>{}</tr>\n", cells.join(""))
}

/// Renders the subset of Markdown that `report.md` uses: headings, paragraphs, link/image lists, tables.
pub fn markdown_to_html(md: &str, out: &Path) -> Result<String> {
    let mut h = String::from(
        "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>spinedrr study</title>\n<style>\
body{font-family:sans-serif;max-width:1000px;margin:auto}table{border-collapse:collapse}\
td,th{border:1px solid #999;padding:2px 8px}img{max-width:100%}</style></head><body>\n",
    );
    let mut in_table = false;
    for line in md.lines() {
        if in_table && !line.starts_with('|') {
            h.push_str("</table>\n");
            in_table = false;
        }
        if let Some(t) = line.strip_prefix("## ") {
            let _ = writeln!(h, "<h2>{}</h2>", escape(t));
        } else if let Some(t) = line.strip_prefix("# ") {
            let _ = writeln!(h, "<h1>{}</h1>", escape(t));
        } else if line.starts_with("|---") {
            continue;
        } else if line.starts_with('|') {
            if !in_table {
                h.push_str("<table>\n");
                h.push_str(&table_row(line, "th"));
                in_table = true;
            } else {
                h.push_str(&table_row(line, "td"));
            }
        } else if let Some(item) = line.strip_prefix("- ") {
            list_item(&mut h, item, out)?;
        } else if !line.trim().is_empty() {
            let _ = writeln!(h, "<p>{}</p>", inline(line));
        }
    }
    if in_table {
        h.push_str("</table>\n");
    }
    h.push_str("</body></html>\n");
    Ok(h)
}

fn list_item(h: &mut String, item: &str, out: &Path) -> Result<()> {
    match link(item) {
        Some((text, target)) if item.starts_with('!') => {
            let path = out.join(target);
            let bytes = std::fs::read(&path).map_err(|e| Error::io(&path, e))?;
            let _ = writeln!(
                h,
                "<figure><img alt=\"{0}\" src=\"data:image/png;base64,{1}\"><figcaption>{0}</figcaption></figure>",
                escape(text),
                base64(&bytes)
            );
        }
        Some((text, target)) if item.starts_with('[') && item.ends_with(')') => {
            let _ = writeln!(
                h,
                "<p><a href=\"{}\">{}</a></p>",
                escape(target),
                escape(text)
            );
        }
        _ => {
            let _ = writeln!(h, "<p>• {}</p>", inline(item));
        }
    }
    Ok(())
}

/// Writes `out/report.html` from `out/report.md`.
pub fn write(out: &Path) -> Result<()> {
    let md_path = out.join("report.md");
    let md = std::fs::read_to_string(&md_path).map_err(|e| Error::io(&md_path, e))?;
    let html = markdown_to_html(&md, out)?;
    write_atomic_bytes(&out.join("report.html"), html.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::{base64, inline};

    #[test]
    fn inline_links_become_anchors_and_text_is_escaped() {
        assert_eq!(
            inline("a < b ([t.csv](tables/t.csv), [f](figures/f.png))."),
            "a &lt; b (<a href=\"tables/t.csv\">t.csv</a>, <a href=\"figures/f.png\">f</a>)."
        );
        assert_eq!(inline("no [link here"), "no [link here");
    }

    #[test]
    fn base64_matches_rfc4648_test_vectors() {
        for (plain, enc) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(plain.as_bytes()), enc);
        }
    }
}
