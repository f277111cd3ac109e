//! The report's provenance line — which build wrote it, from which configuration and which input files
//! (each by its BLAKE3 digest, which `b3sum` recomputes), when and with how many threads — and
//! `inputs.csv` beside the report, the input files one per row (not among the result tables: two runs
//! of one config on inputs in other places have equal tables).

use std::fmt::Write as _;
use std::path::Path;

use serde::Serialize;

use crate::io::write_atomic_bytes;
use crate::study::config::StudyConfig;
use crate::study::identity::InputFile;
use crate::study::timings::RunFacts;
use crate::{Error, Result};

/// How the report's provenance line starts.
pub const PROVENANCE: &str = "**Provenance.** Written by";

/// The table of input files, beside the report.
pub const INPUTS_CSV: &str = "inputs.csv";

/// Input files named one by one in the provenance line; more are counted (all are in the CSV).
const NAMED_MAX: usize = 4;

#[derive(Serialize)]
struct InputRow<'a> {
    file: String,
    bytes: u64,
    blake3: &'a str,
}

/// Writes the first line of the report after its title, starting with [`PROVENANCE`], and (when the
/// config reads any file) `inputs.csv`. Two runs whose configuration and input files have the
/// same digests wrote the same tables; only the date and the thread count differ between them.
pub fn line(
    md: &mut String,
    out: &Path,
    cfg: &StudyConfig,
    (run, inputs): (&RunFacts, &[InputFile]),
) -> Result<()> {
    let config = std::fs::read(out.join("study.toml"))
        .ok()
        .or_else(|| toml::to_string(cfg).ok().map(String::into_bytes))
        .map_or_else(
            || "unknown".to_string(),
            |b| blake3::hash(&b).to_hex().to_string(),
        );
    let name = |f: &InputFile| {
        f.path.file_name().map_or_else(
            || f.path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        )
    };
    let files = match inputs {
        [] => " and no input file (built-in anatomy and geometry)".to_string(),
        few if few.len() <= NAMED_MAX => format!(
            " and its input file{} {} (all in [{INPUTS_CSV}]({INPUTS_CSV}) with their paths and sizes)",
            if few.len() == 1 { "" } else { "s" },
            few.iter()
                .map(|f| format!("`{}` (BLAKE3 `{}`)", name(f), f.blake3))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        many => format!(
            " and its {} input files (each with its path, size and BLAKE3 digest in \
             [{INPUTS_CSV}]({INPUTS_CSV}))",
            many.len()
        ),
    };
    let _ = writeln!(
        md,
        "{PROVENANCE} spinedrr {} (git commit `{}`) from the configuration `study.toml` (BLAKE3 `{}`){files} \
         on {} with {} thread{}.\n",
        env!("CARGO_PKG_VERSION"),
        env!("SPINEDRR_GIT_COMMIT"),
        config,
        humantime::format_rfc3339_seconds(std::time::SystemTime::now()),
        run.threads,
        if run.threads == 1 { "" } else { "s" }
    );
    if inputs.is_empty() {
        return Ok(());
    }
    let mut w = csv::Writer::from_writer(Vec::new());
    for f in inputs {
        w.serialize(InputRow {
            file: std::path::absolute(&f.path)
                .unwrap_or_else(|_| f.path.clone())
                .display()
                .to_string(),
            bytes: f.bytes,
            blake3: &f.blake3,
        })
        .map_err(|e| Error::encode(INPUTS_CSV, e))?;
    }
    let bytes = w.into_inner().map_err(|e| Error::encode(INPUTS_CSV, e))?;
    write_atomic_bytes(&out.join(INPUTS_CSV), &bytes)
}
