//! `report.html`: the Markdown report rendered as one self-contained page: a table of contents whose
//! links resolve to the sections' ids, each figure embedded as a base64 PNG preview at display size
//! (at most [`PREVIEW_WIDTH_PX`] wide) linking to the full-resolution file, with its caption, tables as
//! HTML tables; so the page can be mailed or archived as a single file. Writing to a `String` cannot
//! fail, so `writeln!` results are discarded.

use std::fmt::Write as _;
use std::path::Path;

use base64::Engine as _;

use super::report::slug;
use crate::io::{png_preview, write_atomic_bytes};
use crate::{Error, Result};

/// Width (px) of the embedded figure previews: the page's display width.
pub const PREVIEW_WIDTH_PX: u32 = super::figures::PAGE_WIDTH_PX;

const STYLE: &str = ".wide{overflow-x:auto;max-width:100%}code{background:#f3f3f3;padding:0 3px;border-radius:3px;font-size:0.92em}body{font-family:'DejaVu Sans',sans-serif;max-width:1040px;margin:auto;\
padding:0 16px;line-height:1.45;color:#222}h1{border-bottom:2px solid #444}h2{border-bottom:1px solid #bbb;\
margin-top:2em}table{border-collapse:collapse;margin:0.6em 0}td,th{border:1px solid #999;padding:2px 8px}\
th{background:#eee}figure{margin:1.2em 0}img{max-width:100%;height:auto;border:1px solid #ddd}\
figcaption{font-size:0.9em;color:#444}nav ul{columns:2}";

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// `(text, target)` of a line that is one Markdown link `[text](target)` or image `![text](target)`.
fn link(item: &str) -> Option<(&str, &str)> {
    let item = item.trim_start_matches('!');
    let close = item.find("](")?;
    Some((item.get(1..close)?, item.get(close + 2..item.len() - 1)?))
}

/// `text` escaped, with Markdown code spans as `<code>`, links `[a](b)` as `<a href="b">a</a>` and
/// `**bold**` as `<strong>`.
fn inline(text: &str) -> String {
    // Code spans first (Markdown gives them precedence): `x` pair by pair; an unpaired backtick stays.
    let parts: Vec<&str> = text.split('`').collect();
    if parts.len() > 1 && parts.len() % 2 == 1 {
        return parts
            .iter()
            .enumerate()
            .map(|(i, p)| {
                if i % 2 == 1 {
                    format!("<code>{}</code>", escape(p))
                } else {
                    links(p)
                }
            })
            .collect();
    }
    links(text)
}

/// Links and bold of a text without code spans.
fn links(text: &str) -> String {
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
        h.push_str(&strong(&escape(&rest[..open])));
        let _ = write!(h, "<a href=\"{}\">{}</a>", escape(target), escape(label));
        rest = &rest[open + len..];
    }
    h.push_str(&strong(&escape(rest)));
    h
}

/// Markdown's `**bold**` as `<strong>`, pair by pair; an unpaired `**` stays as written. Each piece's
/// `*emphasis*` becomes `<em>` ([`emphasis`]).
fn strong(text: &str) -> String {
    let parts: Vec<&str> = text.split("**").collect();
    if parts.len().is_multiple_of(2) {
        return emphasis(text);
    }
    let mut h = String::with_capacity(text.len() + 8 * parts.len());
    for (i, part) in parts.iter().enumerate() {
        if i % 2 == 1 {
            let _ = write!(h, "<strong>{}</strong>", emphasis(part));
        } else {
            h.push_str(&emphasis(part));
        }
    }
    h
}

/// Markdown's `*emphasis*` as `<em>`: an opening `*` at the start, after a space or an opening bracket
/// or quote (`;` ends an escaped `&quot;`) and before a letter or digit; the closing one after a
/// character other than a space and before the end, a space or punctuation. Any other `*` (a glob such
/// as `opencv-*`) stays as written.
fn emphasis(text: &str) -> String {
    let chars: Vec<char> = text.chars().collect();
    let opens = |i: usize| {
        (i == 0 || chars[i - 1].is_whitespace() || "([\"';".contains(chars[i - 1]))
            && chars.get(i + 1).is_some_and(|c| c.is_alphanumeric())
    };
    let closes = |i: usize| {
        i > 0
            && !chars[i - 1].is_whitespace()
            && chars[i - 1] != '*'
            && chars
                .get(i + 1)
                .is_none_or(|c| c.is_whitespace() || ".,;:!?)]'\"&-—–".contains(*c))
    };
    let mut h = String::with_capacity(text.len());
    let mut i = 0;
    while i < chars.len() {
        if chars[i] == '*'
            && opens(i)
            && let Some(end) = (i + 1..chars.len()).find(|&j| chars[j] == '*' && closes(j))
        {
            h.push_str("<em>");
            h.extend(&chars[i + 1..end]);
            h.push_str("</em>");
            i = end + 1;
        } else {
            h.push(chars[i]);
            i += 1;
        }
    }
    h
}

fn table_row(line: &str, cell: &str) -> String {
    let cells: Vec<String> = line
        .trim_matches('|')
        .split('|')
        .map(|c| format!("<{cell}>{}</{cell}>", inline(c.trim())))
        .collect();
    format!("<tr>{}</tr>\n", cells.join(""))
}

/// `data:image/png;base64,…` of the PNG at `path`, downscaled to [`PREVIEW_WIDTH_PX`] wide if wider and
/// posterised to [`PREVIEW_LEVELS`] levels per channel ([`crate::io::png_preview`]).
fn preview_uri(path: &Path) -> Result<String> {
    let png = png_preview(path, PREVIEW_WIDTH_PX, PREVIEW_LEVELS)?;
    Ok(format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(png)
    ))
}

/// Levels per channel of the embedded previews.
pub const PREVIEW_LEVELS: u32 = 16;

/// The caption of an italic `_Figure …_` line.
fn caption(line: Option<&&str>) -> Option<String> {
    let l = line?.trim();
    l.strip_prefix("_Figure ")
        .and_then(|c| c.strip_suffix('_'))
        .map(|c| format!("Figure {c}"))
}

/// What block the renderer is inside.
#[derive(PartialEq)]
enum Block {
    None,
    Table,
    List,
    Nav,
}

/// Renders the subset of Markdown that `report.md` uses: headings (`##`, `###` with their [`slug`] as
/// id), paragraphs with links, lists (the one under "Contents" as the page's `<nav>`), tables, and
/// figures (an image line and its caption line).
pub fn markdown_to_html(md: &str, out: &Path) -> Result<String> {
    let mut h = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>spinedrr study</title>\n\
<style>{STYLE}</style></head><body>\n"
    );
    let mut block = Block::None;
    let lines: Vec<&str> = md.lines().collect();
    let mut i = 0;
    while i < lines.len() {
        let line = lines[i];
        i += 1;
        let close = match block {
            Block::Table if !line.starts_with('|') => "</table></div>\n",
            Block::List if !line.starts_with("- ") => "</ul>\n",
            Block::Nav if !line.starts_with("- ") => "</ul></nav>\n",
            _ => "",
        };
        if !close.is_empty() {
            h.push_str(close);
            block = Block::None;
        }
        if let Some(t) = line.strip_prefix("### ") {
            let _ = writeln!(h, "<h3 id=\"{}\">{}</h3>", slug(t), escape(t));
        } else if let Some(t) = line.strip_prefix("## ") {
            let _ = writeln!(h, "<h2 id=\"{}\">{}</h2>", slug(t), escape(t));
        } else if let Some(t) = line.strip_prefix("# ") {
            let _ = writeln!(h, "<h1>{}</h1>", escape(t));
        } else if line.starts_with("|---") {
            continue;
        } else if line.starts_with('|') {
            if block == Block::Table {
                h.push_str(&table_row(line, "td"));
            } else {
                h.push_str("<div class=\"wide\"><table>\n");
                h.push_str(&table_row(line, "th"));
                block = Block::Table;
            }
        } else if let Some(item) = line.strip_prefix("- ") {
            if block == Block::None {
                // The list right under "Contents" is the page's navigation.
                if h.trim_end().ends_with("id=\"contents\">Contents</h2>") {
                    h.push_str("<nav><ul>\n");
                    block = Block::Nav;
                } else {
                    h.push_str("<ul>\n");
                    block = Block::List;
                }
            }
            let _ = writeln!(h, "<li>{}</li>", inline(item));
        } else if let Some((alt, target)) = line.starts_with("![").then(|| link(line)).flatten() {
            let cap = caption(lines.get(i));
            if cap.is_some() {
                i += 1;
            }
            let uri = preview_uri(&out.join(target))?;
            let _ = writeln!(
                h,
                "<figure><a href=\"{0}\"><img alt=\"{1}\" src=\"{uri}\"></a><figcaption>{2}</figcaption></figure>",
                escape(target),
                escape(alt),
                cap.map_or_else(|| escape(alt), |c| inline(&c))
            );
        } else if !line.trim().is_empty() {
            let _ = writeln!(h, "<p>{}</p>", inline(line));
        }
    }
    h.push_str(match block {
        Block::Table => "</table></div>\n",
        Block::List => "</ul>\n",
        Block::Nav => "</ul></nav>\n",
        Block::None => "",
    });
    h.push_str("</body></html>\n");
    Ok(h)
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
    use super::inline;

    #[test]
    fn inline_links_become_anchors_and_text_is_escaped() {
        assert_eq!(
            inline("a < b ([t.csv](tables/t.csv), [f](figures/f.png))."),
            "a &lt; b (<a href=\"tables/t.csv\">t.csv</a>, <a href=\"figures/f.png\">f</a>)."
        );
        assert_eq!(inline("no [link here"), "no [link here");
    }

    #[test]
    fn bold_becomes_strong_and_an_unpaired_marker_stays() {
        assert_eq!(
            inline("**L3, ap+lat.** the **assumed** K ([t](t.csv))"),
            "<strong>L3, ap+lat.</strong> the <strong>assumed</strong> K (<a href=\"t.csv\">t</a>)"
        );
        assert_eq!(inline("a ** b"), "a ** b");
    }

    #[test]
    fn emphasis_becomes_em_and_a_glob_stays() {
        assert_eq!(
            inline(
                "(opencv-*) cannot (see *Physical geometry errors: focal*); the *nominal* poses"
            ),
            "(opencv-*) cannot (see <em>Physical geometry errors: focal</em>); the <em>nominal</em> poses"
        );
        assert_eq!(
            inline("**a *b* c** and *Spectral fixed images* below, `*_detector`"),
            "<strong>a <em>b</em> c</strong> and <em>Spectral fixed images</em> below, <code>*_detector</code>"
        );
        assert_eq!(inline("2 * 3 and a*b"), "2 * 3 and a*b");
    }

    #[test]
    fn code_spans_become_code_and_keep_their_markup_literal() {
        assert_eq!(
            inline("the `study.toml` (**B** `a<b>**c**`)"),
            "the <code>study.toml</code> (<strong>B</strong> <code>a&lt;b&gt;**c**</code>)"
        );
        assert_eq!(inline("one ` tick"), "one ` tick");
    }
}
