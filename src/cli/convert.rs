use anyhow::Result;
use clap::Args;
use occluder_cook::mesh::{self, glb};
use std::path::PathBuf;

#[derive(Args)]
pub struct ConvertArgs {
    /// A mesh in any format the cook reads.
    input: PathBuf,
    /// The GLB to write.
    output: PathBuf,
    #[command(flatten)]
    settings: super::SettingsArgs,
}

/// Writes the geometry exactly as the cook reads it (placed, converted to metres and +Y up,
/// welded) as a plain GLB, with what ingest saw in the node's extras.
pub fn run(args: ConvertArgs) -> Result<()> {
    let settings = args.settings.load()?;
    let (mesh, stats) = mesh::load_file(&args.input, &settings.ingest_limits())?;
    let part = glb::Part {
        name: "mesh",
        mesh: &mesh,
        double_sided: false,
    };
    let extras = serde_json::json!({ "source": args.input.display().to_string(), "ingest": stats });
    super::write(&args.output, &glb::write(&[part], extras))?;
    println!(
        "{}: {} triangles over {} welded vertices written to {}",
        args.input.display(),
        mesh.triangles.len(),
        stats.welded_vertices,
        args.output.display()
    );
    for warning in &stats.warnings {
        println!("note: {warning}");
    }
    if let Some(frame) = &stats.source_frame {
        println!(
            "note: authored in units of {} m with {} up; converted to {}",
            frame.unit_meters, frame.up_axis, frame.converted_to
        );
    }
    Ok(())
}
