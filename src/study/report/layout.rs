//! The report's navigation and figure blocks: a table of contents of its `##` sections, figures as
//! `![title](figures/x.png)` followed by an italic caption line (`report.html` turns the pair into a
//! captioned figure with the full-resolution image a click away), and the products: every table (CSV,
//! and LaTeX where written) and every figure (PNG and SVG) as links.

use std::fmt::Write as _;
use std::path::Path;

use crate::study::figures::{FigureEntry, Section};
use crate::{Error, Result};

/// `v` with `digits` decimals, or `n/a` when it is not finite (a table cell of the report).
pub fn num(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "n/a".into()
    }
}

/// A mean of `n` non-negative values (errors, distances) as the report prints it, three decimals:
/// `value (all n agree)` where the values agree, `value (n = 1)` for one value, else `mean [lo, hi]`
/// with its 95 % confidence half-width `ci95` (a lower bound below 0 is shown as 0).
pub fn mean_text(mean: f64, ci95: f64, n: usize, agree: bool) -> String {
    if agree {
        return format!("{} (all {n} agree)", num(mean, 3));
    }
    if n < 2 || !ci95.is_finite() {
        return format!("{} (n = {n})", num(mean, 3));
    }
    format!(
        "{} [{}, {}]",
        num(mean, 3),
        num((mean - ci95).max(0.0), 3),
        num(mean + ci95, 3)
    )
}

/// The anchor of a heading: lower case, letters and digits kept, runs of anything else one `-`
/// (GitHub's rule for ASCII headings; `report.html` gives each `h2` this id).
pub fn slug(heading: &str) -> String {
    let mut s = String::new();
    for c in heading.chars().flat_map(char::to_lowercase) {
        if c.is_ascii_alphanumeric() {
            s.push(c);
        } else if !s.ends_with('-') && !s.is_empty() {
            s.push('-');
        }
    }
    s.trim_end_matches('-').to_string()
}

/// `## Contents`: a link to each of `headings`.
pub fn contents(md: &mut String, headings: &[String]) {
    let _ = writeln!(md, "## Contents\n");
    for h in headings {
        let _ = writeln!(md, "- [{h}](#{})", slug(h));
    }
    let _ = writeln!(md);
}

/// The primary figures of `section`, numbered from `*n`, each an image line and a caption line; then
/// the section's other figures as one line of links.
pub fn figures(md: &mut String, all: &[FigureEntry], section: Section, n: &mut usize) {
    for f in all.iter().filter(|f| f.section == section && f.primary) {
        *n += 1;
        let svg = f.file.replace(".png", ".svg");
        let _ = writeln!(md, "![{}](figures/{})", f.title, f.file);
        let _ = writeln!(
            md,
            "_Figure {n}. {} ([PNG](figures/{}), [SVG](figures/{svg}))_\n",
            f.caption, f.file
        );
    }
    let others: Vec<String> = all
        .iter()
        .filter(|f| f.section == section && !f.primary)
        .map(|f| format!("[{}](figures/{})", f.title, f.file))
        .collect();
    if !others.is_empty() {
        let _ = writeln!(md, "More figures: {}.\n", others.join(", "));
    }
}

/// `## Products`: the tables and figures folders, file by file, as links.
pub fn products(md: &mut String, out: &Path) -> Result<()> {
    let _ = writeln!(md, "## Products\n");
    for (dir, what) in [
        (
            "tables",
            "Tables (CSV; the paper's tables also as LaTeX booktabs .tex)",
        ),
        (
            "figures",
            "Figures (PNG, SVG; index.json lists them with captions)",
        ),
    ] {
        let path = out.join(dir);
        let mut names: Vec<String> = std::fs::read_dir(&path)
            .map_err(|e| Error::io(&path, e))?
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| !n.starts_with('.') && !n.ends_with(".json") || n == "index.json")
            .collect();
        names.sort();
        let links: Vec<String> = names.iter().map(|n| format!("[{n}]({dir}/{n})")).collect();
        let _ = writeln!(md, "{what}: {}.\n", links.join(", "));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::slug;

    #[test]
    fn slugs_follow_the_heading_text() {
        assert_eq!(slug("Findings"), "findings");
        assert_eq!(
            slug("Registration: Kabsch vs direct (paper ranges)"),
            "registration-kabsch-vs-direct-paper-ranges"
        );
        assert_eq!(
            slug("Where the time goes (this invocation)"),
            "where-the-time-goes-this-invocation"
        );
    }
}
