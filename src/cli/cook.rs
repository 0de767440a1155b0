use super::{SettingsArgs, summarize, write, write_occluder};
use anyhow::Result;
use clap::Args;
use occluder_cook::{cook, mesh};
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args)]
pub struct CookArgs {
    input: PathBuf,
    /// The occluder GLB to write.
    #[arg(short, long)]
    output: PathBuf,
    /// Write the report JSON here.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Measure coverage, false pixels and outside samples into the report.
    #[arg(long)]
    eval: bool,
    #[command(flatten)]
    settings: SettingsArgs,
}

pub fn run(args: CookArgs) -> Result<()> {
    let settings = args.settings.load()?;
    let start = Instant::now();
    cook::mark_stage("ingest");
    let (mesh, stats) = mesh::load_file(&args.input, &settings.ingest_limits())?;
    let ingest_ms = start.elapsed().as_secs_f64() * 1e3;
    let cooked = cook::cook(mesh, stats, ingest_ms, &settings, args.eval)?;
    write_occluder(&args.output, &cooked)?;
    if let Some(path) = args.report {
        write(&path, &serde_json::to_vec_pretty(&cooked.report)?)?;
    }
    summarize(&args.input, &cooked.report);
    Ok(())
}
