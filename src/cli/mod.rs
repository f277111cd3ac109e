//! Command-line interface: one file per subcommand, each an `Args` struct and a `run` function.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod geometry;
mod render_ct;

/// Calibration-sensitivity analysis of vertebral DRRs: renders digitally reconstructed radiographs of
/// vertebrae under ground-truth and perturbed C-arm intrinsics and measures what changes.
#[derive(Parser)]
#[command(name = "spinedrr", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the default C-arm geometry (detector, AP and LAT views) as an editable TOML file.
    Geometry(geometry::Args),
    /// Render a CT volume DRR (Siddon or trilinear), optionally of one segmented vertebra.
    RenderCt(Box<render_ct::Args>),
}

/// Parses the command line, runs the subcommand, prints errors with their context chain.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Geometry(a) => geometry::run(a),
        Command::RenderCt(a) => render_ct::run(*a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
