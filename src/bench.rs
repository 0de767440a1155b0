//! `bench`: every mesh of a corpus through the pipeline, one table row each, plus JSON.

use crate::config::Settings;
use crate::cook::{Cooked, Report, Timings, cook};
use crate::eval::{Quality, evaluate_where_it_can};
use crate::gpu::{self, Gpu, GpuError};
use crate::mesh::{Format, Mesh, load_file, topology::orient_closed_components};
use indicatif::ProgressBar;
use serde::Serialize;
use serde_json::Value;
use std::collections::HashMap;
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
        "{:<34} {:>4} {:>7} {:>5} {:>5} {:>5} {:>5} {:>5} {:>8} {:>7} {:>7} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>9}",
        "mesh",
        "dev",
        "tris_in",
        "tris",
        "boxes",
        "quads",
        "ptchs",
        "surfp",
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
    // The device's own time for the cook's passes, eval left out like in cook_ms.
    let device = &r.device_timings_ms;
    let gpu_ms = match device.is_empty() {
        true => "-".to_string(),
        false => format!("{:.1}", device.total() - device.get("eval")),
    };
    println!(
        "{:<34} {:>4} {:>7} {:>5} {:>5} {:>5} {:>5} {:>5} {:>7.1}% {:>7} {:>7} {:>7.2}% {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8.1} {:>8} {:>8.1} {:>9}",
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
        r.occluder.surface_pieces,
        q.coverage * 100.0,
        q.false_pixels,
        q.false_pixels_non_below,
        q.outside_samples * 100.0,
        t.get("device"),
        t.get("surface"),
        t.get("inside"),
        stage_sum(t, EXPOSURE_STAGES),
        stage_sum(
            t,
            &["boxes", "refine", "quads", "patches", "surface-pieces", "select+merge"]
        ),
        r.cook_ms,
        gpu_ms,
        t.get("eval"),
        judged.map_or("-".into(), |q| q.false_pixels_non_below.to_string()),
    );
}

/// One mesh's figures as a bench JSON holds them (this run's or an earlier one's).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Figures {
    /// The cook's milliseconds, eval left out.
    cook_ms: f64,
    coverage: f64,
    triangles: u64,
    false_non_below: u64,
}

fn figures(row: &Value) -> Option<Figures> {
    let report = &row["report"];
    let timings = report["timings_ms"].as_object()?;
    // Reports from before stages ran side by side have no wall time: theirs is the stages' sum.
    let stages: f64 = timings.values().filter_map(Value::as_f64).sum();
    let eval = timings.get("eval").and_then(Value::as_f64).unwrap_or(0.0);
    Some(Figures {
        cook_ms: report["cook_ms"].as_f64().unwrap_or(stages - eval),
        coverage: report["quality"]["coverage"].as_f64()?,
        triangles: report["occluder"]["triangles"].as_u64()?,
        false_non_below: report["quality"]["false_pixels_non_below"].as_u64()?,
    })
}

/// The run's totals: meshes cooked per second of cook time (wall time, eval left out), and each
/// stage's share of the stages' time, largest first.
pub fn summary(rows: &[BenchRow]) -> String {
    let reports: Vec<&Report> = rows.iter().filter_map(|r| r.report.as_ref()).collect();
    let mut stages = Timings::default();
    for r in &reports {
        for (stage, ms) in r.timings_ms.0.iter().filter(|(stage, _)| stage != "eval") {
            stages.add(stage, *ms);
        }
    }
    let (total, stage_total) = (reports.iter().map(|r| r.cook_ms).sum::<f64>(), stages.total());
    stages.0.sort_by(|a, b| b.1.total_cmp(&a.1));
    let shares: Vec<String> = stages
        .0
        .iter()
        .filter(|(_, ms)| *ms >= 0.005 * stage_total)
        .map(|(stage, ms)| format!("{stage} {:.1}%", 100.0 * ms / stage_total))
        .collect();
    format!(
        "{} meshes in {:.2} s of cook time: {:.2} meshes/s; stage shares: {}",
        reports.len(),
        total / 1e3,
        reports.len() as f64 / (total / 1e3).max(1e-9),
        shares.join(", ")
    )
}

/// This run against an earlier bench JSON, mesh by mesh: cook time and speed-up (earlier over
/// now), coverage, triangles and non-below false pixels, then the totals over the meshes both
/// cooked.
pub fn compare(rows: &[BenchRow], earlier: &Value) -> Result<String, String> {
    let now = serde_json::to_value(rows).map_err(|e| e.to_string())?;
    side_by_side(std::slice::from_ref(earlier), &[now])
}

/// Rounds of two builds' bench JSONs (`bench --against`), mesh by mesh: the median cook time
/// under each, the ratio of the medians (earlier over later), the median of the rounds' own
/// ratios (round k of one against round k of the other), and the last round's coverage,
/// triangles and non-below false pixels; then the totals of the medians over the meshes that
/// every round cooked. One round each is [`compare`].
pub fn side_by_side(earlier: &[Value], later: &[Value]) -> Result<String, String> {
    let figures_of = |runs: &[Value]| -> Result<Vec<HashMap<String, Figures>>, String> {
        let run = |json: &Value| {
            let rows = json.as_array().ok_or("a run is not a bench JSON (an array of rows)")?;
            let meshes = rows
                .iter()
                .filter_map(|row| Some((row["mesh"].as_str()?.to_string(), figures(row)?)));
            Ok(meshes.collect())
        };
        runs.iter().map(run).collect()
    };
    let (then, now) = (figures_of(earlier)?, figures_of(later)?);
    let (Some(then_last), Some(now_last)) = (then.last(), now.last()) else {
        return Err("no runs to compare".into());
    };
    let mut lines = vec![format!(
        "{:<34} {:>9} {:>9} {:>8} {:>8} {:>17} {:>11} {:>9}",
        "mesh", "then_ms", "now_ms", "speedup", "by_round", "coverage", "triangles", "false_nb"
    )];
    let (mut then_total, mut now_total) = (0.0, 0.0);
    let rounds = then.len().min(now.len());
    // In the order of the later run's rows.
    let names = later.last().and_then(Value::as_array).into_iter().flatten();
    for mesh in names.filter_map(|row| row["mesh"].as_str()) {
        let times = |runs: &[HashMap<String, Figures>]| -> Option<Vec<f64>> {
            runs.iter().map(|run| Some(run.get(mesh)?.cook_ms)).collect()
        };
        let (Some(then_ms), Some(now_ms), Some(before), Some(after)) =
            (times(&then), times(&now), then_last.get(mesh), now_last.get(mesh))
        else {
            continue;
        };
        let by_round: Vec<f64> = (0..rounds).map(|r| then_ms[r] / now_ms[r].max(1e-9)).collect();
        let (then_ms, now_ms) = (median(then_ms), median(now_ms));
        then_total += then_ms;
        now_total += now_ms;
        lines.push(format!(
            "{:<34} {:>9.1} {:>9.1} {:>7.2}x {:>7.2}x {:>6.1}% -> {:>5.1}% {:>4} -> {:>4} {:>3} -> {:>2}",
            mesh,
            then_ms,
            now_ms,
            then_ms / now_ms.max(1e-9),
            median(by_round),
            before.coverage * 100.0,
            after.coverage * 100.0,
            before.triangles,
            after.triangles,
            before.false_non_below,
            after.false_non_below,
        ));
    }
    let of_rounds = match rounds {
        1 => String::new(),
        n => format!(", medians of {n} rounds"),
    };
    lines.push(format!(
        "{} meshes in both{of_rounds}: {:.2} s then, {:.2} s now, {:.2}x",
        lines.len() - 1,
        then_total / 1e3,
        now_total / 1e3,
        then_total / now_total.max(1e-9)
    ));
    Ok(lines.join("\n"))
}

/// The middle value, or the mean of the middle two.
fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    match n {
        0 => f64::NAN,
        _ if n % 2 == 1 => values[n / 2],
        _ => 0.5 * (values[n / 2 - 1] + values[n / 2]),
    }
}

#[cfg(test)]
mod tests {
    use super::{BenchRow, EXPOSURE_STAGES, compare, figures, judge, side_by_side, stage_sum, summary};
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
    fn compare_gives_the_speedup_against_an_earlier_run() {
        let settings = crate::config::load(None, &[]).expect("defaults load");
        let cooked = cook(torus(1.0, 0.45, 32, 16), Default::default(), 0.0, &settings, true).expect("cooks");
        let rows = vec![BenchRow {
            mesh: "torus".into(),
            report: Some(cooked.report),
            judged: None,
            error: None,
        }];
        // The same run, twice as slow.
        let mut earlier = serde_json::to_value(&rows).expect("rows serialize");
        let cook_ms = &mut earlier[0]["report"]["cook_ms"];
        *cook_ms = (cook_ms.as_f64().expect("ms") * 2.0).into();
        let table = compare(&rows, &earlier).expect("compares");
        let line = table
            .lines()
            .find(|l| l.starts_with("torus"))
            .expect("a row for the torus");
        assert!(line.contains(" 2.00x"), "{table}");
        assert!(table.ends_with("2.00x"), "{table}");
        assert!(compare(&rows, &serde_json::json!({})).is_err());
        let summary = summary(&rows);
        assert!(
            summary.starts_with("1 meshes in ") && summary.contains("meshes/s"),
            "{summary}"
        );
        assert!(!summary.contains("eval"), "{summary}");
    }

    #[test]
    fn side_by_side_gives_the_ratio_of_the_medians_and_the_median_of_the_rounds_ratios() {
        let run = |ms: f64| {
            serde_json::json!([{"mesh": "m", "report": {
                "cook_ms": ms,
                "timings_ms": {"quads": ms},
                "quality": {"coverage": 0.5, "false_pixels_non_below": 0},
                "occluder": {"triangles": 12},
            }}])
        };
        let (then, now) = ([10.0, 40.0, 30.0].map(run), [5.0, 10.0, 20.0].map(run));
        let table = side_by_side(&then, &now).expect("compares");
        let row: Vec<&str> = table
            .lines()
            .find(|l| l.starts_with("m "))
            .expect("a row")
            .split_whitespace()
            .collect();
        // Medians 30 and 10; the rounds' ratios 2, 4 and 1.5.
        assert_eq!(row[1..5], ["30.0", "10.0", "3.00x", "2.00x"], "{table}");
        assert!(
            table.ends_with("1 meshes in both, medians of 3 rounds: 0.03 s then, 0.01 s now, 3.00x"),
            "{table}"
        );
        assert!(side_by_side(&[], &now).is_err());
    }

    #[test]
    fn a_report_without_a_wall_time_took_its_stages_sum() {
        let row = serde_json::json!({"report": {
            "timings_ms": {"ingest": 1.0, "quads": 2.5, "eval": 40.0},
            "quality": {"coverage": 0.5, "false_pixels_non_below": 0},
            "occluder": {"triangles": 12}
        }});
        assert_eq!(figures(&row).expect("figures").cook_ms, 3.5);
        let mut row = row;
        row["report"]["cook_ms"] = 3.0.into();
        assert_eq!(figures(&row).expect("figures").cook_ms, 3.0);
    }

    #[test]
    fn expo_ms_sums_every_exposure_stage() {
        let timings = Timings(STAGES.iter().map(|s| (s.to_string(), 1.0)).collect());
        let exposure = STAGES.iter().filter(|s| s.starts_with("exposure-")).count();
        assert_eq!(EXPOSURE_STAGES.len(), exposure);
        assert_eq!(stage_sum(&timings, EXPOSURE_STAGES), exposure as f64);
    }
}
