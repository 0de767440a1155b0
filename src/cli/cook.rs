use super::{SettingsArgs, summarize, write, write_occluder, write_preview};
use anyhow::Result;
use clap::Args;
use occluder_cook::eval::preview::{self, Caption};
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
    /// Write a PNG sheet of four views: the original in grey, the occluder over it by kind of
    /// piece, false pixels in red.
    #[arg(long, value_name = "PNG")]
    preview: Option<PathBuf>,
    #[command(flatten)]
    settings: SettingsArgs,
}

pub fn run(args: CookArgs) -> Result<()> {
    let settings = args.settings.load()?;
    let start = Instant::now();
    cook::mark_stage("ingest");
    let (mesh, stats) = mesh::load_file(&args.input, &settings.ingest_limits())?;
    let ingest_ms = start.elapsed().as_secs_f64() * 1e3;
    let original = args.preview.is_some().then(|| mesh.clone());
    let bar = occluder_cook::service::client::stage_bar(&super::file_name(&args.input));
    let progress = |stage: &str, done: f64| {
        bar.set_position((done * 1000.0) as u64);
        bar.set_message(stage.to_string());
        Ok(())
    };
    let cooked = cook::cook_with_progress(mesh, stats, ingest_ms, &settings, args.eval, &progress)?;
    bar.finish_and_clear();
    write_occluder(&args.output, &cooked)?;
    if let Some(path) = args.report {
        write(&path, &serde_json::to_vec_pretty(&cooked.report)?)?;
    }
    if let (Some(path), Some(original)) = (&args.preview, original) {
        let r = &cooked.report;
        let caption = Caption {
            name: super::file_name(&args.input),
            triangles_in: r.input.triangles,
            triangles_out: r.occluder.triangles,
            judged: r.quality.as_ref().map(|q| (q.coverage, q.false_pixels, q.views)),
            openings: r.openings_closed.iter().flat_map(|o| o.outline.clone()).collect(),
        };
        write_preview(path, &original, &preview::pieces(&cooked.occluder), &caption)?;
    }
    summarize(&args.input, &cooked.report);
    Ok(())
}
