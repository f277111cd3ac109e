//! The sensitivity study: a config, independent work units run in parallel and resumably, CSV tables,
//! figures and a Markdown report.
//!
//! `config` (TOML parsed once into typed values, defaults = the paper), `units` (the work units),
//! `schema` (the typed table rows, CSV via the `csv` crate), `runner` (parallel, deterministic,
//! resumable execution), `experiments` (what a unit computes), `paper` (the paper's reported figures, which
//! figures and report both read), `figures` (plotters), `report` (Markdown findings with the paper's
//! numbers beside ours), `timings` (where an invocation's time went).
//!
//! Data flows one way: config → units → experiments → rows (unit files) → tables → figures, report.

pub mod cohort;
pub mod config;
pub mod experiments;
pub mod figures;
pub mod folder;
pub mod identity;
pub mod lock;
pub mod paper;
pub mod report;
pub mod report_html;
pub mod runner;
pub mod schema;
pub mod shard;
pub mod slurm;
pub mod timings;
pub mod units;

pub use config::StudyConfig;
pub use runner::{RunOptions, RunSummary, run_study};
pub use schema::StudyTables;
