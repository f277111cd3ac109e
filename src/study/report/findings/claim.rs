//! The data behind each sentence of *Findings*: a [`Claim`] is one number with where it comes from
//! (which table, which rows, which column, which statistic — or which other claims, or the paper's
//! file), and a [`Fact`] one categorical word (a verdict against the paper, a trend, a tie) with the
//! rule and claims that decide it. `tables/findings.json` holds them all, so a reader (and the pytest
//! recomputation) can re-derive every number and word of the prose from the CSV tables alone.
//!
//! Row selection is the same in both places by construction: a table is held as the text of its CSV
//! cells ([`Table`]), and a claim's `where` names the cell texts its rows must have.

use std::collections::BTreeMap;

use serde::Serialize;

use crate::study::schema::TableRow;

/// A table as its CSV cells' text, one map per data row (in file order).
pub struct Table {
    pub name: &'static str,
    pub rows: Vec<BTreeMap<String, String>>,
}

impl Table {
    /// The cells of `rows` as the CSV writer writes them (the same serde derive).
    pub fn of<R: TableRow>(rows: &[R]) -> Table {
        let rows = rows
            .iter()
            .map(|r| match serde_json::to_value(r) {
                Ok(serde_json::Value::Object(m)) => m
                    .into_iter()
                    .map(|(k, v)| {
                        let text = match v {
                            serde_json::Value::String(s) => s,
                            other => other.to_string(),
                        };
                        (k, text)
                    })
                    .collect(),
                _ => BTreeMap::new(),
            })
            .collect();
        Table {
            name: R::TABLE,
            rows,
        }
    }

    /// The file name, `<name>.csv`.
    pub fn file(&self) -> String {
        format!("{}.csv", self.name)
    }

    /// Indices of the rows whose cells match every condition of `w`.
    pub fn select(&self, w: &Where) -> Vec<usize> {
        self.rows
            .iter()
            .enumerate()
            .filter(|(_, r)| {
                w.0.iter()
                    .all(|(k, allowed)| r.get(k).is_some_and(|v| allowed.contains(v)))
            })
            .map(|(i, _)| i)
            .collect()
    }

    /// The cell `column` of row `i` as a number (NaN when absent or not a number).
    pub fn number(&self, i: usize, column: &str) -> f64 {
        self.rows[i]
            .get(column)
            .and_then(|v| v.parse().ok())
            .unwrap_or(f64::NAN)
    }

    /// The distinct texts of `column` over the rows matching `w`, in order of first appearance.
    pub fn distinct(&self, w: &Where, column: &str) -> Vec<String> {
        let mut out: Vec<String> = Vec::new();
        for i in self.select(w) {
            if let Some(v) = self.rows[i].get(column)
                && !out.contains(v)
            {
                out.push(v.clone());
            }
        }
        out
    }
}

/// Row conditions: column → the cell texts allowed.
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct Where(pub BTreeMap<String, Vec<String>>);

impl Where {
    pub fn new() -> Where {
        Where::default()
    }
    /// The cell of `column` is `value` (a number as the CSV writes it: Rust's `{}`).
    pub fn is(mut self, column: &str, value: impl ToString) -> Where {
        self.0.insert(column.into(), vec![value.to_string()]);
        self
    }
    /// The cell of `column` is one of `values`.
    pub fn any<S: ToString>(mut self, column: &str, values: impl IntoIterator<Item = S>) -> Where {
        self.0.insert(
            column.into(),
            values.into_iter().map(|v| v.to_string()).collect(),
        );
        self
    }
}

/// What is applied to each cell before the statistic.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
#[serde(rename_all = "snake_case")]
pub enum Transform {
    Identity,
    /// `1 − x` (Dice → silhouette loss).
    OneMinus,
}

/// The statistic over the selected cells (non-finite cells are skipped; NaN without any).
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
#[serde(rename_all = "snake_case")]
pub enum Stat {
    /// The one selected row's cell.
    Value,
    Mean,
    Min,
    Max,
    /// √(mean x²).
    Rms,
    /// The 95th percentile, linear between order statistics (position 0.95·(n − 1)).
    P95,
}

/// Where a claim's value comes from.
#[derive(Debug, Clone, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Source {
    /// `stat` of `transform(column)` over the rows of `table` matching `where` (0-based data rows).
    Column {
        table: String,
        column: String,
        transform: Transform,
        stat: Stat,
        #[serde(rename = "where")]
        filter: Where,
        rows: Vec<usize>,
    },
    /// Of the points (`columns[0]`, `columns[1]`) of the selected rows: the distance of their centroid
    /// from `about` (`offset`) or their RMS distance from their centroid (`spread`).
    Points {
        table: String,
        columns: [String; 2],
        about: [f64; 2],
        geometry: Geometry,
        #[serde(rename = "where")]
        filter: Where,
        rows: Vec<usize>,
    },
    /// A formula of other claims (by id): `ratio` a / b, `hypot` √(a² + b²), `share_pct` 100·a²/(a² + b²),
    /// `min` and `max` of all, `value` the one claim's value (printed at another precision).
    Formula { op: Op, of: Vec<String> },
    /// How many of `items` there are.
    Count { items: Vec<String> },
    /// In how many of the pairs (a, b) of claims a > b by more than the printed precision: their
    /// texts at `decimals` decimals differ (equal texts are a tie).
    CountGreater {
        pairs: Vec<[String; 2]>,
        decimals: usize,
    },
    /// A value of the paper (`reference/paper-results.toml`): `key` a dotted path; `index` picks from a
    /// list; `mean_of_index` the mean over a table's entries of their `index`-th value.
    Paper {
        key: String,
        index: Option<usize>,
        mean_over_entries: bool,
    },
    /// A constant of the report's rules, named.
    Rule { name: String },
    /// A value of the run's configuration (`study.toml`), `key` a dotted path.
    Config { key: String },
    /// `px` × the detector's pixel pitch along u, `sdd_mm / K[0][0]` of the reference sidecar
    /// `reference` (a path under the study folder): a focal offset's SDD error, or a piercing shift's move
    /// on the detector, in mm.
    Detector { px: f64, reference: String },
    /// How many of the facts (by id) have the word `word`.
    CountWord { facts: Vec<String>, word: String },
}

/// Which of [`Source::Points`]'s two statistics.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
#[serde(rename_all = "snake_case")]
pub enum Geometry {
    Offset,
    Spread,
}

/// A formula of [`Source::Formula`].
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
#[serde(rename_all = "snake_case")]
pub enum Op {
    Ratio,
    Hypot,
    SharePct,
    Min,
    Max,
    Value,
}

impl Op {
    /// The formula of `v` (two values for the first three).
    pub fn apply(self, v: &[f64]) -> f64 {
        let (a, b) = (
            v.first().copied().unwrap_or(f64::NAN),
            v.get(1).copied().unwrap_or(f64::NAN),
        );
        match self {
            Op::Ratio => a / b,
            Op::Hypot => a.hypot(b),
            Op::SharePct => 100.0 * a * a / (a * a + b * b),
            Op::Min => v.iter().copied().fold(f64::INFINITY, f64::min),
            Op::Max => v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            Op::Value => a,
        }
    }
}

/// One number of the findings.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Claim {
    pub id: String,
    pub value: f64,
    /// As the prose prints it; `None` for a building block of other claims or facts.
    pub text: Option<String>,
    pub decimals: usize,
    pub unit: &'static str,
    /// How many values it is computed over.
    pub n: usize,
    pub target: String,
    pub view: String,
    pub family: String,
    /// The perturbation cell (its parameters, px).
    pub cell: BTreeMap<String, f64>,
    pub source: Source,
}

impl Claim {
    pub fn new(id: impl Into<String>, value: f64, source: Source) -> Claim {
        Claim {
            id: id.into(),
            value,
            text: None,
            decimals: 0,
            unit: "",
            n: 1,
            target: String::new(),
            view: String::new(),
            family: String::new(),
            cell: BTreeMap::new(),
            source,
        }
    }
    /// Printed with `decimals` decimals and `unit`.
    pub fn shown(mut self, decimals: usize, unit: &'static str) -> Claim {
        self.decimals = decimals;
        self.unit = unit;
        self
    }
    pub fn about(mut self, target: &str, view: &str, family: &str) -> Claim {
        self.target = target.into();
        self.view = view.into();
        self.family = family.into();
        self
    }
    pub fn cell(mut self, key: &str, value: f64) -> Claim {
        self.cell.insert(key.into(), value);
        self
    }
    pub fn count(mut self, n: usize) -> Claim {
        self.n = n;
        self
    }
    /// The value as printed.
    pub fn printed(&self) -> String {
        format!("{:.*}", self.decimals, self.value)
    }
}

/// One categorical word of the prose and the rule that decides it from claims: `interval` (args: our
/// low, our high, the paper's low, high → inside, overlapping or outside), `trend` (args: the first
/// and last value and their confidence half-widths → rising, falling or flat), `tie` (args a, b and a tolerance claim in % → tied), `paper` (the word
/// is the value of the paper's key `of[0]`).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Fact {
    pub id: String,
    pub word: String,
    pub rule: &'static str,
    pub of: Vec<String>,
}

/// One bullet of *Findings*: its Markdown and the claims and facts behind it.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Finding {
    pub id: String,
    pub text: String,
    pub claims: Vec<Claim>,
    pub facts: Vec<Fact>,
}

impl Finding {
    pub fn new(id: &str) -> Finding {
        Finding {
            id: id.into(),
            text: String::new(),
            claims: Vec::new(),
            facts: Vec::new(),
        }
    }

    /// Records `c` as printed and returns its text.
    pub fn say(&mut self, mut c: Claim) -> String {
        let t = c.printed();
        c.text = Some(t.clone());
        self.claims.push(c);
        t
    }

    /// Records `c` as a building block (not printed); returns its value.
    pub fn keep(&mut self, c: Claim) -> f64 {
        let v = c.value;
        self.claims.push(c);
        v
    }

    /// Records a categorical word and returns it.
    pub fn fact(&mut self, id: &str, word: &str, rule: &'static str, of: Vec<String>) -> String {
        self.facts.push(Fact {
            id: id.into(),
            word: word.into(),
            rule,
            of,
        });
        word.to_string()
    }

    /// The value of the claim `id`.
    pub fn value(&self, id: &str) -> Option<f64> {
        self.claims.iter().find(|c| c.id == id).map(|c| c.value)
    }
}
