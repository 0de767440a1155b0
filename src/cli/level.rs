use super::{SettingsArgs, path_setting, write};
use anyhow::{Context, Result};
use clap::Args;
use occluder_cook::level;
use occluder_cook::store::sled::SledStore;
use std::path::{Path, PathBuf};

#[derive(Args)]
pub struct LevelArgs {
    manifest: PathBuf,
    /// The level's occluder GLB: one mesh per batch.
    #[arg(short, long)]
    output: PathBuf,
    /// Write the report JSON here.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Write the batch list (bounds, triangles, instances) here [default: OUTPUT.batches.json].
    #[arg(long)]
    batches: Option<PathBuf>,
    /// Write a PNG sheet: a top view of the instances by batch, and three cull-test cameras with
    /// the culled instances seen through the walls.
    #[arg(long, value_name = "PNG", conflicts_with = "server")]
    preview: Option<PathBuf>,
    /// Cook the level as one soup: every instance placed into one map, its flat surface pieces
    /// chosen cell by cell (the level.eye_height and level.soup_* settings). Without it, a level
    /// read from one file whose parts overlap across the map, or one large mesh, is cooked as a
    /// soup too, with a note that says so.
    #[arg(long, conflicts_with_all = ["server", "preview"])]
    soup: bool,
    /// service.data_dir: the cache.
    #[arg(long, conflicts_with = "server")]
    data_dir: Option<PathBuf>,
    /// Bake on a server instead (a JSON manifest, with the meshes it names next to it).
    #[command(flatten)]
    server: Option<super::ServerArgs>,
    #[command(flatten)]
    settings: SettingsArgs,
}

pub fn run(args: LevelArgs) -> Result<()> {
    if let Some(server) = &args.server {
        return run_on_server(server, &args);
    }
    let settings = args
        .settings
        .load_with(&[("service.data_dir", path_setting(args.data_dir.clone()))])?;
    let level = level::load(&args.manifest, &settings.ingest_limits())?;
    let dir = settings.service.data_dir();
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let store = SledStore::open(&dir, settings.service.sled_cache_bytes)
        .with_context(|| "the cache is in use (a server on the same data_dir?): pass --data-dir".to_string())?;
    let bar = occluder_cook::service::client::count_bar("unique meshes");
    let progress = |done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    let never = |_: &str, _: f64| Ok(());
    let runtime = tokio::runtime::Runtime::new()?;
    let soup = match args.soup {
        true => Some("asked for (--soup)".to_string()),
        false => level::soup::soup_reason(&level, &settings.level),
    };
    if let (Some(why), Some(_)) = (&soup, &args.preview) {
        anyhow::bail!("this level cooks as a soup ({why}): --preview draws instances, and a soup has none");
    }
    let baked = match &soup {
        Some(why) => runtime.block_on(level::soup::bake_soup(&level, &settings, &store, why))?,
        None => runtime.block_on(level::bake(&level, &settings, &store, &progress, &never))?,
    };
    bar.finish_and_clear();
    write(&args.output, &baked.glb)?;
    if let Some(path) = &args.preview {
        let meshes = runtime
            .block_on(level::placed_meshes(&level, &store, &settings.ingest_limits()))
            .map_err(anyhow::Error::msg)?;
        let r = &baked.report;
        let caption = level::preview::LevelCaption {
            name: match level.name.is_empty() {
                true => super::file_name(&args.manifest),
                false => level.name.clone(),
            },
            instances: r.instances,
            batches: r.batches,
            triangles: r.triangles_after,
            cull: r.cull.as_ref().map(|c| (c.culled_share, c.wrongly_culled, c.cameras)),
        };
        let groups: Vec<Vec<usize>> = baked.batches.iter().map(|b| b.instances.clone()).collect();
        let occluder = level::occluder_mesh(&baked.glb).map_err(anyhow::Error::msg)?;
        let sheet = level::preview::sheet(&level, &meshes, &occluder, &groups, &caption).map_err(anyhow::Error::msg)?;
        write(path, &occluder_cook::eval::preview::png(&sheet))?;
    }
    let mut report = serde_json::to_value(&baked.report)?;
    if let Some(mib) = peak_memory_mib() {
        report["peak_memory_mib"] = mib.into();
    }
    write_outputs(&args, &report, &serde_json::to_value(&baked.batches)?)
}

/// The most memory this process has held at once (Linux's VmHWM), in MiB.
fn peak_memory_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line
        .trim_start_matches("VmHWM:")
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kib / 1024.0)
}

/// Uploads the manifest and its meshes to `/v1/levels`, waits, and writes what a local bake
/// writes.
fn run_on_server(server: &super::ServerArgs, args: &LevelArgs) -> Result<()> {
    let query = args.settings.job_query(&["cook", "level"])?;
    let (_, mut report) = server.client()?.submit_level(&args.manifest, &query, &args.output)?;
    // The server's report holds the batch list where a local one holds their count.
    let batches = report["batches"].take();
    report["batches"] = batches.as_array().map_or(0, Vec::len).into();
    write_outputs(args, &report, &batches)
}

/// The batch list, the report if asked for, and the summary line.
fn write_outputs(args: &LevelArgs, report: &serde_json::Value, batches: &serde_json::Value) -> Result<()> {
    let batches_path = args
        .batches
        .clone()
        .unwrap_or_else(|| args.output.with_extension("batches.json"));
    write(&batches_path, &serde_json::to_vec_pretty(batches)?)?;
    if let Some(path) = &args.report {
        write(path, &serde_json::to_vec_pretty(report)?)?;
    }
    summarize(&args.manifest, report);
    Ok(())
}

fn summarize(manifest: &Path, r: &serde_json::Value) {
    let total_ms: f64 = r["timings_ms"].as_object().map_or(0.0, |stages| {
        stages.values().filter_map(serde_json::Value::as_f64).sum()
    });
    println!(
        "{}: {} instances of {} unique meshes ({} cached), {} batches, {} occluder triangles \
         ({} placed source triangles), draw calls {} -> {}, {total_ms:.0} ms",
        manifest.display(),
        r["instances"],
        r["unique_meshes"],
        r["cache_hits"],
        r["batches"],
        r["triangles_after"],
        r["triangles_before"],
        r["draw_calls_before"],
        r["draw_calls_after"],
    );
    let soup = &r["soup"];
    if soup.is_object() {
        let grid = &soup["grid"];
        println!(
            "soup: {} surface pieces ({} triangles) in {} cells of {:.1}, {} eye points at {}; grid {} bricks \
             on {}, {:.1} MiB, voxel {:.3} (effective {}); peak memory {:.0} MiB",
            soup["pieces"],
            soup["piece_triangles"],
            soup["cells"],
            soup["cell_size"].as_f64().unwrap_or_default(),
            soup["eye_points"],
            soup["eye_height"],
            grid["bricks"],
            soup["bricks_device"].as_str().unwrap_or("?"),
            grid["bytes"].as_f64().unwrap_or_default() / f64::from(1 << 20),
            grid["voxel_size"].as_f64().unwrap_or_default(),
            grid["effective_resolution"],
            r["peak_memory_mib"].as_f64().unwrap_or_default(),
        );
    }
    let cull = &r["cull"];
    if let Some(share) = cull["culled_share"].as_f64() {
        println!(
            "cull test: {} cameras culled {:.1}% of the instances in view, {} wrongly",
            cull["cameras"],
            share * 100.0,
            cull["wrongly_culled"]
        );
    }
    for note in r["notes"].as_array().into_iter().flatten() {
        println!("note: {}", note.as_str().unwrap_or_default());
    }
}
