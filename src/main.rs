use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use occluder_cook::config::{self, Settings};
use occluder_cook::mesh::{self, glb, topology::orient_closed_components};
use occluder_cook::occluder::panel_mesh;
use occluder_cook::voxel::InsideMethod;
use occluder_cook::{bench, cook, eval};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Conservative occluders for game meshes: a few dozen triangles inside the mesh that cover
/// as much of its silhouette as they can.
#[derive(Parser)]
#[command(name = "occluder-cook", version)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Cook one mesh (.glb, .gltf, .obj, .stl) into an occluder GLB.
    Cook {
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
    },
    /// Cook the built-in sample, a torus, with evaluation: a check that everything works.
    Demo {
        #[arg(short, long, default_value = "torus.occluder.glb")]
        output: PathBuf,
    },
    /// Judge any occluder mesh against its original.
    Eval {
        original: PathBuf,
        occluder: PathBuf,
        /// Also write the figures as JSON.
        #[arg(long)]
        json: Option<PathBuf>,
        #[command(flatten)]
        settings: SettingsArgs,
    },
    /// Cook and evaluate every mesh of a corpus; print a table and write JSON.
    Bench {
        /// Folder of meshes [default: $OCCLUDER_CORPUS or ../shared/meshes].
        #[arg(long)]
        corpus: Option<PathBuf>,
        #[arg(long, default_value = "bench.json")]
        json: PathBuf,
        #[command(flatten)]
        settings: SettingsArgs,
    },
}

#[derive(Args)]
struct SettingsArgs {
    /// A TOML file over the built-in config/default.toml.
    #[arg(long)]
    config: Option<PathBuf>,
    /// cook.resolution: voxels along the longest axis.
    #[arg(long)]
    resolution: Option<usize>,
    /// cook.inside: the inside/outside method.
    #[arg(long, value_enum)]
    inside: Option<InsideMethod>,
    /// cook.max_triangles: the occluder's triangle budget.
    #[arg(long)]
    max_triangles: Option<usize>,
    /// cook.target_coverage: share of the inner volume the boxes should fill.
    #[arg(long)]
    target_coverage: Option<f64>,
    /// Views of eval: a number of directions around the mesh (eval.views), `outside` for those,
    /// or `inside` for a cube map from the centre of its bounds (eval.view_set).
    #[arg(long)]
    views: Option<String>,
    /// eval.pixels: image size.
    #[arg(long)]
    pixels: Option<usize>,
    /// Any setting, e.g. --set cook.refine=false (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
}

impl SettingsArgs {
    fn load(&self) -> Result<Settings> {
        let mut overrides = Vec::new();
        let mut flag = |key: &str, value: Option<toml::Value>| {
            if let Some(v) = value {
                overrides.push((key.to_string(), v));
            }
        };
        let int = |v: Option<usize>| v.map(|v| toml::Value::Integer(v as i64));
        flag("cook.resolution", int(self.resolution));
        flag(
            "cook.inside",
            self.inside
                .map(|m| toml::Value::String(format!("{m:?}").to_lowercase())),
        );
        flag("cook.max_triangles", int(self.max_triangles));
        flag("cook.target_coverage", self.target_coverage.map(toml::Value::Float));
        match self.views.as_deref().map(|v| (v, v.parse::<usize>())) {
            Some((_, Ok(n))) => flag("eval.views", int(Some(n))),
            Some((set, Err(_))) => flag("eval.view_set", Some(toml::Value::String(set.to_string()))),
            None => {}
        }
        flag("eval.pixels", int(self.pixels));
        for assignment in &self.set {
            overrides.push(config::parse_assignment(assignment)?);
        }
        Ok(config::load(self.config.as_deref(), &overrides)?)
    }
}

fn main() {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()))
        .without_time()
        .init();
    if let Err(e) = run(Cli::parse()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Cook {
            input,
            output,
            report,
            eval,
            settings,
        } => {
            let settings = settings.load()?;
            let start = Instant::now();
            let (mesh, stats) = mesh::load_file(&input)?;
            let ingest_ms = start.elapsed().as_secs_f64() * 1e3;
            let cooked = cook::cook(mesh, stats, ingest_ms, &settings, eval);
            write_occluder(&output, &cooked)?;
            if let Some(path) = report {
                write(&path, &serde_json::to_vec_pretty(&cooked.report)?)?;
            }
            summarize(&input, &cooked.report);
        }
        Command::Demo { output } => {
            let mesh = mesh::shapes::torus(1.0, 0.45, 64, 32);
            let stats = mesh::IngestStats {
                input_triangles: mesh.triangles.len(),
                input_vertices: mesh.positions.len(),
                welded_vertices: mesh.positions.len(),
                ..Default::default()
            };
            let cooked = cook::cook(mesh, stats, 0.0, &config::load(None, &[])?, true);
            write_occluder(&output, &cooked)?;
            summarize(Path::new("built-in torus"), &cooked.report);
        }
        Command::Eval {
            original,
            occluder,
            json,
            settings,
        } => {
            let settings = settings.load()?;
            let (mut original_mesh, _) = mesh::load_file(&original)?;
            let topology = orient_closed_components(&mut original_mesh);
            let occluder_mesh = match mesh::load_file(&occluder) {
                Ok((m, _)) => m,
                // An empty occluder is a fair answer for a mesh with no volume.
                Err(mesh::IngestError::Empty(_)) => mesh::Mesh::default(),
                Err(e) => return Err(e).with_context(|| format!("occluder {}", occluder.display())),
            };
            let q = eval::evaluate(&original_mesh, &topology.boundary, &occluder_mesh, &settings.eval);
            println!("triangles          {}", q.occluder_triangles);
            println!(
                "coverage           {:.2}% (min {:.2}%) over {} views",
                q.coverage * 100.0,
                q.coverage_min * 100.0,
                q.views
            );
            println!("false pixels       {} (all views)", q.false_pixels);
            println!(
                "false pixels       {} ({} non-below views)",
                q.false_pixels_non_below, q.views_non_below
            );
            println!("outside samples    {:.3}% of {}", q.outside_samples * 100.0, q.samples);
            if let Some(path) = json {
                write(&path, &serde_json::to_vec_pretty(&q)?)?;
            }
        }
        Command::Bench { corpus, json, settings } => {
            let settings = settings.load()?;
            let corpus = corpus
                .or_else(|| std::env::var_os("OCCLUDER_CORPUS").map(PathBuf::from))
                .unwrap_or_else(|| PathBuf::from("../shared/meshes"));
            if !corpus.is_dir() {
                bail!(
                    "corpus folder {} not found: pass --corpus DIR or set OCCLUDER_CORPUS",
                    corpus.display()
                );
            }
            let files = bench::corpus_files(&corpus)?;
            let rows = bench::run(&files, &settings);
            write(&json, &serde_json::to_vec_pretty(&rows)?)?;
            println!("wrote {}", json.display());
        }
    }
    Ok(())
}

fn write_occluder(path: &Path, cooked: &cook::Cooked) -> Result<()> {
    let r = &cooked.report;
    let extras = serde_json::json!({
        "key": r.key,
        "pipeline_version": r.pipeline_version,
        "source_triangles": r.input.triangles,
        "boxes": r.occluder.boxes,
        "quads": r.occluder.quads,
        "patches": r.occluder.patches,
        "triangles": r.occluder.triangles,
    });
    let panels = panel_mesh(&cooked.occluder.panels);
    let parts = [
        glb::Part {
            name: "occluder-solid",
            mesh: &cooked.occluder.solid,
            double_sided: false,
        },
        glb::Part {
            name: "occluder-panels",
            mesh: &panels,
            double_sided: true,
        },
    ];
    write(path, &glb::write(&parts, extras))
}

fn summarize(input: &Path, r: &cook::Report) {
    print!(
        "{}: {} triangles in, occluder of {} triangles from {} boxes, {} quads and {} patches in {:.1} ms",
        input.display(),
        r.input.triangles,
        r.occluder.triangles,
        r.occluder.boxes,
        r.occluder.quads,
        r.occluder.patches,
        r.timings_ms.total()
    );
    match &r.quality {
        Some(q) => println!(
            "; coverage {:.1}%, false pixels {} ({} in non-below views), outside samples {:.2}%",
            q.coverage * 100.0,
            q.false_pixels,
            q.false_pixels_non_below,
            q.outside_samples * 100.0
        ),
        None => println!(),
    }
    for note in &r.notes {
        println!("note: {note}");
    }
}

fn write(path: &Path, bytes: &[u8]) -> Result<()> {
    std::fs::write(path, bytes).with_context(|| format!("cannot write {}", path.display()))
}
