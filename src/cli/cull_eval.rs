use super::write;
use anyhow::{Context, Result, bail};
use clap::Args;
use occluder_cook::gpu::{self, DeviceChoice};
use occluder_cook::level::cull::probes::{Buffer, ProbeReport, probe_eval};
use occluder_cook::level::free_space::FreeSpace;
use occluder_cook::voxel::bricks::BrickGrid;
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
    /// Test N probe boxes standing in the map's free space instead of the level's instances,
    /// from cameras at eye height above its floors, against the occluder and against the map's
    /// own triangles.
    #[arg(long, value_name = "N")]
    probes: Option<usize>,
    /// With --probes: the eye's height above a floor, in the map's units.
    #[arg(long, default_value_t = 1.7)]
    eye_height: f64,
    /// With --probes: the depth buffer, WIDTHxHEIGHT (64 to 1024 wide, at most as high).
    #[arg(long, default_value = "256x128", value_parser = parse_buffer)]
    buffer: Buffer,
    /// With --probes: the width of the ground truth, of the buffer's shape.
    #[arg(long, default_value_t = 1024)]
    truth_pixels: usize,
    /// With --probes: the voxel size of the grid that finds floors and free space [default:
    /// the map's longest side / 1024].
    #[arg(long)]
    voxel_size: Option<f64>,
}

fn parse_buffer(text: &str) -> Result<Buffer, String> {
    let (w, h) = text.split_once('x').ok_or("expected WIDTHxHEIGHT, e.g. 256x128")?;
    let number = |s: &str| s.trim().parse::<usize>().map_err(|e| format!("{s:?}: {e}"));
    let (width, height) = (number(w)?, number(h)?);
    if !(64..=1024).contains(&width) || height == 0 || height > width {
        return Err(format!(
            "{width}x{height}: the width must be 64 to 1024 and the height 1 to the width"
        ));
    }
    Ok(Buffer { width, height })
}

pub fn run(args: CullEvalArgs) -> Result<()> {
    let (cameras, pixels) = (args.cameras, args.pixels);
    if !(64..=256).contains(&pixels) || !(1..=10_000).contains(&cameras) {
        bail!("--pixels must be 64 to 256 and --cameras 1 to 10000");
    }
    let limits = mesh::IngestLimits::default();
    let level = level::load(&args.level, &limits)?;
    let (occluder, _) =
        mesh::load_file(&args.occluders, &limits).with_context(|| format!("occluders {}", args.occluders.display()))?;
    if let Some(probes) = args.probes {
        return run_probes(&args, &level, &occluder, probes);
    }
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

/// The probe test: the map's floors from a bricked grid of its surface, cameras and probes on
/// them, and the occluder against the map's own triangles.
fn run_probes(args: &CullEvalArgs, level: &level::Level, occluder: &mesh::Mesh, probes: usize) -> Result<()> {
    if !(1..=100_000).contains(&probes) {
        bail!("--probes must be 1 to 100000");
    }
    if !(args.eye_height > 0.0 && args.eye_height.is_finite()) {
        bail!("--eye-height must be a positive number");
    }
    if !(64..=4096).contains(&args.truth_pixels) || args.truth_pixels < args.buffer.width {
        bail!("--truth-pixels must be 64 to 4096 and at least the buffer's width");
    }
    let start = Instant::now();
    let meshes = level::cull::load_meshes(level, &Default::default()).map_err(anyhow::Error::msg)?;
    let map = level::cull::placed_map(level, &meshes);
    let (lo, hi) = map.bounds();
    let voxel_size = args.voxel_size.unwrap_or((hi - lo).max_element() as f64 / 1024.0);
    let placement = gpu::for_choice(args.device)?;
    let grid = BrickGrid::voxelize(&map, voxel_size, placement.gpu.as_deref()).map_err(anyhow::Error::msg)?;
    let space = FreeSpace::new(&grid, args.eye_height);
    let poses = space.cameras(args.cameras, 0xc0ffee);
    let boxes = space.probes(probes, 0x9e37_79b9);
    if poses.len() < args.cameras || boxes.len() < probes {
        bail!(
            "the map's floors have room for {} of {} cameras and {} of {probes} probes at --eye-height {:?} (in the map's units)",
            poses.len(),
            args.cameras,
            boxes.len(),
            args.eye_height
        );
    }
    let placed_ms = start.elapsed().as_secs_f64() * 1e3;
    let (width, buffer) = (args.truth_pixels, args.buffer);
    let truth = Buffer {
        width,
        height: (width * buffer.height).div_ceil(buffer.width),
    };
    let report = probe_eval(&map, occluder, &poses, &boxes, buffer, truth);
    let stats = grid.stats();
    println!(
        "{} cameras and {} probes placed in {placed_ms:.0} ms ({} bricks on {}, {:.1} MiB, voxel {:.3}, effective {:?})",
        report.cameras,
        report.probes,
        stats.bricks,
        placement.gpu.as_ref().map_or("cpu".into(), |g| g.name()),
        stats.bytes as f64 / (1 << 20) as f64,
        stats.voxel_size,
        stats.effective_resolution
    );
    print_probes(&report);
    println!("took {:.1} s", start.elapsed().as_secs_f64());
    if let Some(path) = &args.json {
        let mut json = serde_json::to_value(&report)?;
        json["grid"] = serde_json::to_value(stats)?;
        json["eye_height"] = args.eye_height.into();
        write(path, &serde_json::to_vec_pretty(&json)?)?;
    }
    Ok(())
}

fn print_probes(r: &ProbeReport) {
    let line = |what: String, c: &level::cull::probes::ProbeCounts| {
        println!(
            "{what}: culled {} of {} hidden probes ({:.1}%), wrongly culled {}",
            c.probes_culled,
            c.probes_hidden,
            c.culled_share * 100.0,
            c.probes_wrongly_culled
        );
    };
    println!(
        "{} probe views in a {}x{} buffer, truth {}x{}",
        r.probes_in_view, r.buffer.width, r.buffer.height, r.truth.width, r.truth.height
    );
    line(format!("occluder ({} triangles)", r.occluder_triangles), &r.occluder);
    line(format!("limit, the map's own {} triangles", r.map_triangles), &r.limit);
    if r.limit.probes_culled > 0 {
        println!(
            "the occluder culls {:.1}% of what the limit culls",
            100.0 * r.occluder.probes_culled as f64 / r.limit.probes_culled as f64
        );
    }
}
