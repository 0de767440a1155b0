use super::{summarize, write_occluder};
use anyhow::Result;
use clap::Args;
use occluder_cook::{config, cook, mesh};
use std::path::{Path, PathBuf};

#[derive(Args)]
pub struct DemoArgs {
    #[arg(short, long, default_value = "torus.occluder.glb")]
    output: PathBuf,
}

pub fn run(args: DemoArgs) -> Result<()> {
    let mesh = mesh::shapes::torus(1.0, 0.45, 64, 32);
    let stats = mesh::IngestStats {
        input_triangles: mesh.triangles.len(),
        input_vertices: mesh.positions.len(),
        welded_vertices: mesh.positions.len(),
        ..Default::default()
    };
    let cooked = cook::cook(mesh, stats, 0.0, &config::load(None, &[])?, true)?;
    write_occluder(&args.output, &cooked)?;
    summarize(Path::new("built-in torus"), &cooked.report);
    Ok(())
}
