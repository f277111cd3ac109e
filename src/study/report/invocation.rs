//! *Where the time goes (this invocation)*: how many work units this invocation ran and how many it
//! found done, the timing table, and the shards' own timing tables beside an assembled report.

use std::fmt::Write as _;
use std::path::Path;

use super::TIMINGS;
use crate::study::timings::{RunFacts, TimingRow, shard_timings, to_markdown};

/// `n` and `what`, plural unless `n` is 1.
fn count(n: usize, what: &str) -> String {
    format!("{n} {what}{}", if n == 1 { "" } else { "s" })
}

/// The section: what ran here, the timing table (without the report's own writing, which is not
/// known yet: it is in timings.csv), and the shards' timing tables in `out`.
pub fn section(md: &mut String, out: &Path, rows: &[TimingRow], run: &RunFacts) {
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let _ = writeln!(md, "## {TIMINGS}\n");
    let done = run.total_units - run.ran_units;
    let where_done = "already in the folder, from an earlier invocation or from shards";
    let ran = match (run.ran_units, done) {
        (0, _) => format!(
            "None of the {} work units ran in this invocation: every result was {where_done}, and it \
built the tables, figures and report from them.",
            run.total_units
        ),
        (ran, 0) => format!(
            "All {ran} work units ran in this invocation, on {} ({cores} cores available).",
            count(run.threads, "worker thread")
        ),
        (ran, done) => format!(
            "{ran} of {} work units ran in this invocation, on {} ({cores} cores available); the other \
{done} were {where_done}.",
            run.total_units,
            count(run.threads, "worker thread")
        ),
    };
    let _ = writeln!(
        md,
        "{ran} Wall-clock phases are elapsed time; the indented unit phases are summed over worker \
threads, so together they are about threads × the units' wall time. Report writing itself is in \
timings.csv.\n"
    );
    let rows: Vec<TimingRow> = rows
        .iter()
        .filter(|r| !r.phase.starts_with("report"))
        .cloned()
        .collect();
    let _ = writeln!(md, "{}", to_markdown(&rows));
    let shards: Vec<String> = shard_timings(out)
        .into_iter()
        .map(|s| match s {
            Ok(s) => format!(
                "[{file}]({file}) ({} in {:.1} s of wall time, {:.1} s in all)",
                count(s.units as usize, "unit"),
                s.units_wall_s,
                s.total_wall_s,
                file = s.file
            ),
            Err(e) => format!("{e} (unreadable)"),
        })
        .collect();
    if !shards.is_empty() {
        let _ = writeln!(
            md,
            "The shards' own timing tables are in this folder: {}.\n",
            shards.join(", ")
        );
    }
}
