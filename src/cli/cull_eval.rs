use super::write;
use anyhow::{Context, Result, bail};
use clap::Args;
use occluder_cook::gpu::{self, DeviceChoice};
use occluder_cook::{level, mesh};
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args)]
pub struct CullEvalArgs {
    level: PathBuf,
    occluders: PathBuf,
    #[arg(long, default_value_t = 100)]
    cameras: usize,
    /// Width of the occluder depth buffer (64 to 256, as runtimes use).
    #[arg(long, default_value_t = 128)]
    pixels: usize,
    #[arg(long)]
    json: Option<PathBuf>,
    /// Where the ground truth renders (auto: a hardware GPU if there is one).
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    device: DeviceChoice,
}

pub fn run(args: CullEvalArgs) -> Result<()> {
    let (cameras, pixels) = (args.cameras, args.pixels);
    if !(64..=256).contains(&pixels) || cameras == 0 {
        bail!("--pixels must be 64 to 256 and --cameras at least 1");
    }
    let limits = mesh::IngestLimits::default();
    let level = level::load(&args.level, &limits)?;
    let (occluder, _) =
        mesh::load_file(&args.occluders, &limits).with_context(|| format!("occluders {}", args.occluders.display()))?;
    let placement = gpu::for_choice(args.device)?;
    let start = Instant::now();
    let meshes = level::cull::load_meshes(&level, &Default::default()).map_err(anyhow::Error::msg)?;
    let report = level::cull::cull_eval(&level, &meshes, &occluder, cameras, pixels, placement.gpu.as_deref())
        .map_err(anyhow::Error::msg)?;
    println!(
        "ground truth on {}: {:.0} ms",
        report.truth_device,
        start.elapsed().as_secs_f64() * 1e3
    );
    println!(
        "{} cameras, {} instances, {} occluder triangles at {} px: culled {:.1}% of the instances in view, wrongly culled {}",
        report.cameras,
        report.instances,
        report.occluder_triangles,
        pixels,
        report.culled_share * 100.0,
        report.wrongly_culled
    );
    if let Some((eye, dir, n)) = report.worst_camera {
        println!("worst camera at {eye:?} looking {dir:?}: {n} wrongly culled");
    }
    if let Some(path) = args.json {
        write(&path, &serde_json::to_vec_pretty(&report)?)?;
    }
    Ok(())
}
