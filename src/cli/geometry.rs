//! `spinedrr geometry`: print the default geometry TOML (or check a geometry file).

use std::path::PathBuf;

use anyhow::Context;
use spinedrr::geometry::{CArm, DEFAULT_GEOMETRY_TOML};

#[derive(clap::Args)]
pub struct Args {
    /// Instead of printing the default, load this geometry file and print its views' K and
    /// world_to_camera (a validity check).
    #[arg(long)]
    check: Option<PathBuf>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let Some(path) = a.check else {
        print!("{DEFAULT_GEOMETRY_TOML}");
        return Ok(());
    };
    let carm =
        CArm::from_file(&path).with_context(|| format!("loading geometry {}", path.display()))?;
    for v in &carm.views {
        println!("view {}:", v.name);
        println!("  K = {:?}", v.intrinsics.matrix_rows());
        println!("  world_to_camera = {:?}", v.world_to_camera.to_rows());
        println!("  source_mm = {:?}", v.source_world().to_array());
    }
    Ok(())
}
