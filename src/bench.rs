//! `bench`: every mesh of a corpus through the pipeline, one table row each, plus JSON.

use crate::config::Settings;
use crate::cook::{Cooked, Report, Timings, cook};
use crate::eval::{Quality, evaluate_where_it_can};
use crate::gpu::{self, Gpu, GpuError};
use crate::mesh::{Format, Mesh, load_file, topology::orient_closed_components};
use indicatif::ProgressBar;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Serialize)]
pub struct BenchRow {
    pub mesh: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub report: Option<Report>,
    /// The occluder judged again from more views (`bench --judge-views`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub judged: Option<Quality>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// Mesh files directly in `corpus` and one folder down, skipping `broken/` (malformed on purpose).
pub fn corpus_files(corpus: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(corpus)? {
        let path = entry?.path();
        if path.is_dir() {
            if path.file_name().is_some_and(|n| n != "broken") {
                for inner in std::fs::read_dir(&path)? {
                    files.push(inner?.path());
                }
            }
        } else {
            files.push(path);
        }
    }
    files.retain(|p| Format::from_extension(p).is_ok());
    files.sort();
    Ok(files)
}

/// Cooks and evaluates every file, printing a row as each finishes (above `bar`, which counts
/// the meshes and names the one cooking); with `judge_views` above 0, judges each occluder again
/// from that many views, on the cook's device when it has one.
pub fn run(files: &[PathBuf], settings: &Settings, judge_views: usize, bar: &ProgressBar) -> Vec<BenchRow> {
    let judge_gpu = gpu::for_choice(settings.cook.device).ok().and_then(|p| p.gpu);
    println!(
        "{:<34} {:>4} {:>7} {:>5} {:>5} {:>5} {:>5} {:>8} {:>7} {:>7} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>9}",
        "mesh",
        "dev",
        "tris_in",
        "tris",
        "boxes",
        "quads",
        "ptchs",
        "coverage",
        "false",
        "false_nb",
        "outside",
        "open_ms",
        "surf_ms",
        "inside_ms",
        "expo_ms",
        "pieces_ms",
        "cook_ms",
        "gpu_ms",
        "eval_ms",
        format!("nb@{judge_views}"),
    );
    bar.set_length(files.len() as u64);
    let rows = files
        .iter()
        .map(|path| {
            let name = path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            bar.set_message(name.clone());
            let start = Instant::now();
            let cooked = load_file(path, &settings.ingest_limits())
                .map_err(|e| e.to_string())
                .and_then(|(mesh, stats)| {
                    let ingest_ms = start.elapsed().as_secs_f64() * 1e3;
                    let cooked = cook(mesh.clone(), stats, ingest_ms, settings, true).map_err(|e| e.to_string())?;
                    let judged = (judge_views > 0)
                        .then(|| judge(mesh, &cooked, settings, judge_views, judge_gpu.as_deref()))
                        .transpose()
                        .map_err(|e| e.to_string())?;
                    Ok((cooked, judged))
                });
            bar.inc(1);
            match cooked {
                Ok((cooked, judged)) => {
                    let report = cooked.report;
                    bar.suspend(|| print_row(&name, &report, judged.as_ref()));
                    BenchRow {
                        mesh: name,
                        report: Some(report),
                        judged,
                        error: None,
                    }
                }
                Err(e) => {
                    bar.suspend(|| println!("{name:<34} rejected: {e}"));
                    BenchRow {
                        mesh: name,
                        report: None,
                        judged: None,
                        error: Some(e),
                    }
                }
            }
        })
        .collect();
    bar.finish_and_clear();
    rows
}

/// The quality of `cooked`'s occluder for `original` from `views` views, on `gpu` where it can.
fn judge(
    mut original: Mesh,
    cooked: &Cooked,
    settings: &Settings,
    views: usize,
    gpu: Option<&Gpu>,
) -> Result<Quality, GpuError> {
    let topology = orient_closed_components(&mut original);
    let eval = crate::eval::EvalSettings {
        views,
        ..settings.eval.clone()
    };
    let (judged, _) = evaluate_where_it_can(&original, &topology.boundary, &cooked.occluder.mesh(), &eval, gpu)?;
    Ok(judged)
}

/// The stages of the exposure test, all summed into `expo_ms`.
const EXPOSURE_STAGES: &[&str] = &["exposure-render", "exposure-voxels", "exposure-boxes", "exposure-quads"];

fn stage_sum(timings: &Timings, stages: &[&str]) -> f64 {
    stages.iter().map(|s| timings.get(s)).sum()
}

fn print_row(name: &str, r: &Report, judged: Option<&Quality>) {
    let q = r.quality.as_ref().expect("bench always evaluates");
    let t = &r.timings_ms;
    let cook_ms = t.total() - t.get("eval");
    // The device's own time for the cook's passes, eval left out like in cook_ms.
    let device = &r.device_timings_ms;
    let gpu_ms = match device.is_empty() {
        true => "-".to_string(),
        false => format!("{:.1}", device.total() - device.get("eval")),
    };
    println!(
        "{:<34} {:>4} {:>7} {:>5} {:>5} {:>5} {:>5} {:>7.1}% {:>7} {:>7} {:>7.2}% {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8} {:>8.1} {:>9}",
        name,
        match (r.gpu_stages.is_empty(), r.gpu_stages.contains(&"inside")) {
            (true, _) => "cpu",
            (false, true) => "gpu",
            (false, false) => "mix",
        },
        r.input.triangles,
        r.occluder.triangles,
        r.occluder.boxes,
        r.occluder.quads,
        r.occluder.patches,
        q.coverage * 100.0,
        q.false_pixels,
        q.false_pixels_non_below,
        q.outside_samples * 100.0,
        t.get("device"),
        t.get("surface"),
        t.get("inside"),
        stage_sum(t, EXPOSURE_STAGES),
        stage_sum(t, &["boxes", "refine", "quads", "patches", "select+merge"]),
        cook_ms,
        gpu_ms,
        t.get("eval"),
        judged.map_or("-".into(), |q| q.false_pixels_non_below.to_string()),
    );
}

#[cfg(test)]
mod tests {
    use super::{EXPOSURE_STAGES, judge, stage_sum};
    use crate::cook::{STAGES, Timings, cook};
    use crate::mesh::shapes::torus;

    #[test]
    fn judge_views_the_occluder_from_as_many_directions_as_asked() {
        let settings = crate::config::load(None, &[]).expect("defaults load");
        let mesh = torus(1.0, 0.45, 32, 16);
        let cooked = cook(mesh.clone(), Default::default(), 0.0, &settings, false).expect("cooks");
        let judged = judge(mesh, &cooked, &settings, 200, None).expect("the CPU judges");
        assert_eq!(judged.views, 200);
        assert_eq!(judged.views_non_below, 100);
        assert_eq!(judged.false_pixels, 0);
        assert!(judged.coverage > 0.5, "{judged:?}");
    }

    #[test]
    fn expo_ms_sums_every_exposure_stage() {
        let timings = Timings(STAGES.iter().map(|s| (s.to_string(), 1.0)).collect());
        let exposure = STAGES.iter().filter(|s| s.starts_with("exposure-")).count();
        assert_eq!(EXPOSURE_STAGES.len(), exposure);
        assert_eq!(stage_sum(&timings, EXPOSURE_STAGES), exposure as f64);
    }
}
