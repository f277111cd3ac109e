//! Command-line interface: one file per subcommand, each an `Args` struct and a `run` function.

use std::process::ExitCode;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

mod calibrate;
mod compare;
mod geometry;
mod mesh;
mod phantom;
mod register;
mod render;
mod render_checks;
mod render_ct;
mod render_spectral;
mod render_timing;
mod study;
mod values;

/// Calibration-sensitivity analysis of vertebral DRRs: renders digitally reconstructed radiographs of
/// vertebrae under ground-truth and perturbed C-arm intrinsics and measures what changes.
#[derive(Parser)]
#[command(
    name = "spinedrr",
    version,
    about,
    long_about = None,
    after_help = "Environment:\n  SPINEDRR_CACHE_DIR  where built phantom meshes are cached for reuse by later runs of this \
                  same build (default $XDG_CACHE_HOME/spinedrr or ~/.cache/spinedrr; `off` disables). An \
                  entry is used only if the code and every phantom option match; results are identical \
                  with or without it."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the default C-arm geometry (detector, AP and LAT views) as an editable TOML file.
    Geometry(geometry::Args),
    /// Build the parametric lumbar phantom (L1–L5): cortical and cancellous meshes, discs, soft tissue
    /// and landmarks.json.
    Phantom(phantom::Args),
    /// Render a DRR (thickness DRR of the phantom or mesh files, or CT volume DRR) under the reference or a
    /// perturbed calibration (K, or the focal spot and detector moved in mm and degrees).
    Render(Box<render::Args>),
    /// Compare a reference and a perturbed DRR: landmark shifts, contours, Dice/IoU, image similarity,
    /// difference heatmap (metrics.json, absdiff.tiff, heatmap.png).
    Compare(compare::Args),
    /// Register a rigid vertebra pose from landmark observations (direct LM, Kabsch, OpenCV).
    Register(register::Args),
    /// Mesh one vertebra label of a NIfTI segmentation (closed surface, optional smoothing, decimation
    /// and automatic landmarks).
    Mesh(mesh::Args),
    /// Run the sensitivity study (paper defaults, --quick, or --config FILE): CSV tables, PNG figures,
    /// report.md; parallel, deterministic and resumable.
    Study(study::Args),
    /// Simulate a C-arm calibration with a BB phantom (plate, helix or a JSON file) under detection
    /// noise, N Monte-Carlo trials: calibrations.csv (K, poses, reprojection RMS, held-out 3-D error)
    /// and phantom.json.
    Calibrate(calibrate::Args),
}

/// The command line's grammar, with every flag that takes a value accepting a negative number as that
/// value: `--repeat -1` then reaches the flag's parser, which says what the value must be, instead of
/// being refused as an unknown flag `-1`; a flag whose value may be negative (an offset) takes it.
fn command() -> clap::Command {
    fn negatives(cmd: clap::Command) -> clap::Command {
        cmd.mut_args(|a| {
            if a.get_action().takes_values() && !a.is_positional() {
                a.allow_negative_numbers(true)
            } else {
                a
            }
        })
        .mut_subcommands(negatives)
    }
    negatives(Cli::command())
}

/// Parses the command line, runs the subcommand, prints errors with their context chain.
pub fn main() -> ExitCode {
    let matches = command().get_matches();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    if let Some(cache) = spinedrr::anatomy::MeshCache::from_env() {
        spinedrr::anatomy::phantom_cache::enable(cache);
    }
    let result = match cli.command {
        Command::Geometry(a) => geometry::run(a),
        Command::Phantom(a) => phantom::run(a),
        Command::Render(a) => render::run(*a),
        Command::Compare(a) => compare::run(a),
        Command::Register(a) => register::run(a),
        Command::Mesh(a) => mesh::run(a),
        Command::Study(a) => study::run(a),
        Command::Calibrate(a) => calibrate::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
