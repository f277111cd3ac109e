//! The paper's comparison tables as one typed value ([`PaperTable`]), rendered as a Markdown table (in
//! `report.md`) and as a LaTeX `booktabs` table (`tables/<name>.tex`, next to the CSVs).

use std::fmt::Write as _;
use std::path::Path;

use crate::Result;
use crate::io::write_atomic_bytes;

/// A table of strings: a header row and body rows of the same width.
#[derive(Debug, Clone, PartialEq)]
pub struct PaperTable {
    /// The `.tex` file stem and LaTeX label (`tab:<name>`).
    pub name: &'static str,
    pub caption: String,
    pub header: Vec<String>,
    pub rows: Vec<Vec<String>>,
}

impl PaperTable {
    /// The Markdown table (header, separator, rows).
    pub fn to_markdown(&self) -> String {
        let mut md = format!("| {} |\n", self.header.join(" | "));
        let _ = writeln!(md, "|{}", "---|".repeat(self.header.len()));
        for r in &self.rows {
            let _ = writeln!(md, "| {} |", r.join(" | "));
        }
        md
    }

    /// A `table` float with a `booktabs` `tabular` (first column left-aligned, the others right).
    pub fn to_latex(&self) -> String {
        let cols = format!("l{}", "r".repeat(self.header.len().saturating_sub(1)));
        let line = |cells: &[String]| {
            let c: Vec<String> = cells.iter().map(|c| escape(c)).collect();
            format!("    {} \\\\\n", c.join(" & "))
        };
        let mut t = String::from("% Requires \\usepackage{booktabs}. Written by spinedrr study.\n");
        t.push_str("\\begin{table}[htbp]\n  \\centering\n");
        let _ = writeln!(t, "  \\caption{{{}}}", escape(&self.caption));
        let _ = writeln!(t, "  \\label{{tab:{}}}", self.name.replace('_', "-"));
        let _ = writeln!(t, "  \\begin{{tabular}}{{{cols}}}");
        t.push_str("    \\toprule\n");
        t.push_str(&line(&self.header));
        t.push_str("    \\midrule\n");
        for r in &self.rows {
            t.push_str(&line(r));
        }
        t.push_str("    \\bottomrule\n  \\end{tabular}\n\\end{table}\n");
        t
    }

    /// Writes [`PaperTable::to_latex`] to `dir/<name>.tex`.
    pub fn write_latex(&self, dir: &Path) -> Result<()> {
        write_atomic_bytes(
            &dir.join(format!("{}.tex", self.name)),
            self.to_latex().as_bytes(),
        )
    }
}

/// `s` as LaTeX text: the ten special characters escaped, the non-ASCII symbols the report uses as
/// math or text commands.
pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '\\' => out.push_str("\\textbackslash{}"),
            '&' | '%' | '$' | '#' | '_' | '{' | '}' => {
                out.push('\\');
                out.push(c);
            }
            '~' => out.push_str("\\textasciitilde{}"),
            '^' => out.push_str("\\textasciicircum{}"),
            '<' => out.push_str("\\textless{}"),
            '>' => out.push_str("\\textgreater{}"),
            'Δ' => out.push_str("$\\Delta$"),
            'α' => out.push_str("$\\alpha$"),
            'μ' => out.push_str("$\\mu$"),
            '·' => out.push_str("$\\cdot$"),
            '×' => out.push_str("$\\times$"),
            '±' => out.push_str("$\\pm$"),
            '–' => out.push_str("--"),
            '—' => out.push_str("---"),
            '≈' => out.push_str("$\\approx$"),
            _ => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specials_are_escaped() {
        assert_eq!(
            escape(r"a_b & 50% #1 {x} $y ~ ^ \ Δf – 2"),
            r"a\_b \& 50\% \#1 \{x\} \$y \textasciitilde{} \textasciicircum{} \textbackslash{} $\Delta$f -- 2"
        );
    }

    #[test]
    fn latex_has_one_line_per_row_between_the_rules() {
        let t = PaperTable {
            name: "t_x",
            caption: "c".into(),
            header: vec!["a".into(), "b".into()],
            rows: vec![vec!["left_pedicle".into(), "1".into()]; 3],
        };
        let tex = t.to_latex();
        let body: Vec<&str> = tex
            .lines()
            .skip_while(|l| !l.contains("\\midrule"))
            .skip(1)
            .take_while(|l| !l.contains("\\bottomrule"))
            .collect();
        assert_eq!(body, vec!["    left\\_pedicle & 1 \\\\"; 3]);
        assert!(tex.contains("\\begin{tabular}{lr}") && tex.contains("\\label{tab:t-x}"));
    }
}
