//! The sensitivity study: a config, independent work units run in parallel and resumably, CSV tables,
//! figures and a Markdown report.
//!
//! `config` (TOML, defaults = the paper), `units` (the work units and their rows), `runner` (parallel,
//! deterministic, resumable execution), `experiments` (what a unit computes), `tables` (CSV),
//! `figures` (plotters), `report` (Markdown with the paper's numbers beside ours).

pub mod config;
pub mod experiments;
pub mod figures;
pub mod report;
pub mod report_html;
pub mod runner;
pub mod tables;
pub mod timings;
pub mod units;

pub use config::StudyConfig;
pub use runner::{RunOptions, RunSummary, run_study};
