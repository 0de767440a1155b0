use super::{SettingsArgs, path_setting, write};
use anyhow::{Context, Result};
use clap::Args;
use occluder_cook::level::{self, LevelReport};
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
    /// service.data_dir: the cache.
    #[arg(long)]
    data_dir: Option<PathBuf>,
    #[command(flatten)]
    settings: SettingsArgs,
}

pub fn run(args: LevelArgs) -> Result<()> {
    let settings = args
        .settings
        .load_with(&[("service.data_dir", path_setting(args.data_dir))])?;
    let level = level::load(&args.manifest, &settings.ingest_limits())?;
    let dir = settings.service.data_dir();
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let store = SledStore::open(&dir)
        .with_context(|| "the cache is in use (a server on the same data_dir?): pass --data-dir".to_string())?;
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template("unique meshes [{bar:30}] {pos}/{len}")
            .expect("the template parses")
            .progress_chars("=> "),
    );
    let progress = |done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    };
    let never = |_: &str, _: f64| Ok(());
    let baked = tokio::runtime::Runtime::new()?.block_on(level::bake(&level, &settings, &store, &progress, &never))?;
    bar.finish_and_clear();
    write(&args.output, &baked.glb)?;
    let batches = args
        .batches
        .unwrap_or_else(|| args.output.with_extension("batches.json"));
    write(&batches, &serde_json::to_vec_pretty(&baked.batches)?)?;
    if let Some(path) = args.report {
        write(&path, &serde_json::to_vec_pretty(&baked.report)?)?;
    }
    summarize(&args.manifest, &baked.report);
    Ok(())
}

fn summarize(manifest: &Path, r: &LevelReport) {
    println!(
        "{}: {} instances of {} unique meshes ({} cached), {} batches, {} occluder triangles \
         ({} placed source triangles), draw calls {} -> {}, {:.0} ms",
        manifest.display(),
        r.instances,
        r.unique_meshes,
        r.cache_hits,
        r.batches,
        r.triangles_after,
        r.triangles_before,
        r.draw_calls_before,
        r.draw_calls_after,
        r.timings_ms.total()
    );
}
