//! `report.html`: the Markdown report rendered as one self-contained page: a table of contents whose
//! links resolve to the sections' ids, each figure embedded as a base64 PNG preview at display size
//! (at most [`PREVIEW_WIDTH_PX`] wide) linking to the full-resolution file, with its caption, tables as
//! HTML tables; so the page can be mailed or archived as a single file. The Markdown is read by
//! pulldown-cmark (CommonMark and GFM tables, as GitHub reads `report.md`), so the page and the file
//! say the same thing.

use std::path::Path;

use base64::Engine as _;
use pulldown_cmark::{Event, HeadingLevel, Options, Parser, Tag, TagEnd, html};

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

/// `s` escaped for an HTML attribute value.
fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
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

/// The index of the event that closes the one opened at `events[start]` (tags nest; every start has
/// its end).
fn end_of(events: &[Event], start: usize) -> usize {
    let mut depth = 0usize;
    for (i, e) in events.iter().enumerate().skip(start) {
        match e {
            Event::Start(_) => depth += 1,
            Event::End(_) => {
                depth -= 1;
                if depth == 0 {
                    return i;
                }
            }
            _ => {}
        }
    }
    events.len() - 1
}

/// The text of `events` as a reader sees it (text and code spans; markup dropped).
fn plain_text(events: &[Event]) -> String {
    events
        .iter()
        .filter_map(|e| match e {
            Event::Text(t) | Event::Code(t) => Some(t.as_ref()),
            Event::SoftBreak | Event::HardBreak => Some(" "),
            _ => None,
        })
        .collect()
}

/// A figure from the events inside a paragraph that starts with an image: the image's preview linking
/// to its file, and as caption the rest of the paragraph (the report's italic `_Figure n. …_` line,
/// without its italics), or the image's alt text where there is no rest.
fn figure<'a>(inner: &[Event<'a>], out: &Path, page: &mut Vec<Event<'a>>) -> Result<()> {
    let Event::Start(Tag::Image { dest_url, .. }) = &inner[0] else {
        return Err(Error::Internal(
            "a figure that does not start with an image".into(),
        ));
    };
    let close = end_of(inner, 0);
    let alt = plain_text(&inner[1..close]);
    let mut rest = &inner[close + 1..];
    while let [Event::SoftBreak | Event::HardBreak, tail @ ..] = rest {
        rest = tail;
    }
    if matches!(rest.first(), Some(Event::Start(Tag::Emphasis)))
        && end_of(rest, 0) == rest.len() - 1
    {
        rest = &rest[1..rest.len() - 1];
    }
    let uri = preview_uri(&out.join(dest_url.as_ref()))?;
    page.push(Event::Html(
        format!(
            "<figure><a href=\"{}\"><img alt=\"{}\" src=\"{uri}\"></a><figcaption>",
            escape(dest_url),
            escape(&alt)
        )
        .into(),
    ));
    if rest.is_empty() {
        page.push(Event::Text(alt.into()));
    } else {
        page.extend(rest.iter().cloned());
    }
    page.push(Event::Html("</figcaption></figure>\n".into()));
    Ok(())
}

/// Renders `report.md` as CommonMark with GFM tables (pulldown-cmark: what GitHub shows of the same
/// file), with the page's additions: each `##`/`###` heading's id its [`slug`] (the targets of the
/// contents' links), the list right under `## Contents` as the page's `<nav>`, each table in a
/// horizontally scrolling box, and each paragraph that starts with an image as a captioned
/// [`figure`] embedding the image's preview. `out` is the folder the report's links are relative to.
pub fn markdown_to_html(md: &str, out: &Path) -> Result<String> {
    // HTML in the Markdown is shown as text: the report's names (targets, landmarks, files) are the
    // user's, and a `<L1>` must read as written, never become markup.
    let events: Vec<Event> = Parser::new_ext(md, Options::ENABLE_TABLES)
        .map(|e| match e {
            Event::Html(t) | Event::InlineHtml(t) => Event::Text(t),
            e => e,
        })
        .collect();
    let mut page: Vec<Event> = Vec::with_capacity(events.len() + 64);
    // Whether the last block was the `## Contents` heading; whether its list (the `<nav>`) is open.
    let mut after_contents = false;
    let mut nav = false;
    let mut lists = 0usize;
    let mut i = 0;
    while i < events.len() {
        let block_start = lists == 0 && matches!(&events[i], Event::Start(_));
        match &events[i] {
            Event::Start(Tag::Heading { level, .. }) => {
                let end = end_of(&events, i);
                let text = plain_text(&events[i + 1..end]);
                let id = (*level != HeadingLevel::H1).then(|| slug(&text).into());
                after_contents = *level == HeadingLevel::H2 && text == "Contents";
                page.push(Event::Start(Tag::Heading {
                    level: *level,
                    id,
                    classes: Vec::new(),
                    attrs: Vec::new(),
                }));
                page.extend(events[i + 1..=end].iter().cloned());
                i = end + 1;
                continue;
            }
            Event::Start(Tag::Paragraph)
                if matches!(events.get(i + 1), Some(Event::Start(Tag::Image { .. }))) =>
            {
                let end = end_of(&events, i);
                figure(&events[i + 1..end], out, &mut page)?;
                i = end + 1;
                after_contents = false;
                continue;
            }
            Event::Start(Tag::Table(_)) => page.push(Event::Html("<div class=\"wide\">".into())),
            Event::Start(Tag::List(_)) => {
                if lists == 0 && after_contents {
                    page.push(Event::Html("<nav>".into()));
                    nav = true;
                }
                lists += 1;
            }
            _ => {}
        }
        if block_start {
            after_contents = false;
        }
        page.push(events[i].clone());
        match &events[i] {
            Event::End(TagEnd::Table) => page.push(Event::Html("</div>\n".into())),
            Event::End(TagEnd::List(_)) => {
                lists -= 1;
                if lists == 0 && std::mem::take(&mut nav) {
                    page.push(Event::Html("</nav>\n".into()));
                }
            }
            _ => {}
        }
        i += 1;
    }
    let mut h = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>spinedrr study</title>\n\
<style>{STYLE}</style></head><body>\n"
    );
    html::push_html(&mut h, page.into_iter());
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
    use super::markdown_to_html;

    /// The page's body for `md` (no figures: `out` is never read).
    fn body(md: &str) -> String {
        let h = markdown_to_html(md, std::path::Path::new("/nonexistent")).expect("html");
        let start = h.find("<body>\n").expect("body") + 7;
        h[start..h.len() - "</body></html>\n".len()].to_string()
    }

    #[test]
    fn inline_markup_follows_commonmark() {
        assert_eq!(
            body("a < b ([t.csv](tables/t.csv), [f](figures/f.png)). no [link here"),
            "<p>a &lt; b (<a href=\"tables/t.csv\">t.csv</a>, <a href=\"figures/f.png\">f</a>). no [link here</p>\n"
        );
        assert_eq!(
            body("**L3, ap+lat.** the *nominal* poses, `a<b>**c**`, 2 * 3 (`opencv-*`, opencv-*)"),
            "<p><strong>L3, ap+lat.</strong> the <em>nominal</em> poses, \
             <code>a&lt;b&gt;**c**</code>, 2 * 3 (<code>opencv-*</code>, opencv-*)</p>\n"
        );
        // CommonMark pairs two bare `*` that touch words (`opencv-*` … `a*b`): the report writes
        // globs in code spans.
        assert_eq!(
            body("(opencv-*) and a*b"),
            "<p>(opencv-<em>) and a</em>b</p>\n"
        );
    }

    #[test]
    fn html_in_the_markdown_is_shown_as_text() {
        assert_eq!(
            body("landmark <L1> and <img src=x onerror=alert(1)> in a name"),
            "<p>landmark &lt;L1&gt; and &lt;img src=x onerror=alert(1)&gt; in a name</p>\n"
        );
        assert_eq!(
            body("<div>\nblock\n</div>\n"),
            "&lt;div&gt;\nblock\n&lt;/div&gt;\n"
        );
    }

    #[test]
    fn headings_get_their_slug_and_the_contents_list_is_the_nav() {
        let h = body(
            "# Study\n\n## Contents\n\n- [Findings](#findings)\n- [Where the time goes](#where-the-time-goes)\n\n\
             ## Findings\n\n- a finding\n\n## Where the time goes\n",
        );
        assert_eq!(
            h,
            "<h1>Study</h1>\n<h2 id=\"contents\">Contents</h2>\n<nav>\n<ul>\n\
             <li><a href=\"#findings\">Findings</a></li>\n\
             <li><a href=\"#where-the-time-goes\">Where the time goes</a></li>\n</ul>\n</nav>\n\
             <h2 id=\"findings\">Findings</h2>\n<ul>\n<li>a finding</li>\n</ul>\n\
             <h2 id=\"where-the-time-goes\">Where the time goes</h2>\n"
        );
    }

    #[test]
    fn tables_scroll_in_their_box() {
        let h = body("| a | b |\n|---|---|\n| `x` | 2 |\n");
        assert!(h.starts_with("<div class=\"wide\"><table>"), "{h}");
        assert!(h.ends_with("</table>\n</div>\n"), "{h}");
        assert!(
            h.contains("<th>a</th>") && h.contains("<td><code>x</code></td>"),
            "{h}"
        );
    }

    #[test]
    fn an_image_and_its_caption_line_are_one_figure() {
        let dir = tempfile::tempdir().expect("dir");
        std::fs::create_dir(dir.path().join("figures")).expect("figures");
        image::RgbImage::from_pixel(4, 3, image::Rgb([200, 10, 10]))
            .save(dir.path().join("figures/f.png"))
            .expect("png");
        let md = "![Shift vs Δf](figures/f.png)\n_Figure 1. The *shift* ([PNG](figures/f.png))_\n\n\
                  ![Alone](figures/f.png)\n";
        let h = markdown_to_html(md, dir.path()).expect("html");
        let figures: Vec<&str> = h.split("<figure>").skip(1).collect();
        assert_eq!(figures.len(), 2, "{h}");
        assert!(figures[0].starts_with(
            "<a href=\"figures/f.png\"><img alt=\"Shift vs Δf\" src=\"data:image/png;base64,"
        ));
        assert!(
            figures[0].contains(
                "<figcaption>Figure 1. The <em>shift</em> (<a href=\"figures/f.png\">PNG</a>)</figcaption></figure>"
            ),
            "{h}"
        );
        assert!(figures[1].contains("<figcaption>Alone</figcaption>"), "{h}");
        assert!(!h.contains("<p><figure>") && !h.contains("<p></p>"), "{h}");
    }
}
