use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use occluder_cook::config::{self, Settings};
use occluder_cook::gpu::DeviceChoice;
use occluder_cook::mesh::{self, topology::orient_closed_components};
use occluder_cook::service::{self, client};
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
    /// Run the cook service: the HTTP API, a pool of workers and the sled cache.
    Serve {
        /// service.listen: address and port (port 0 picks a free one).
        #[arg(long)]
        listen: Option<String>,
        /// service.data_dir: where jobs, inputs and results are kept.
        #[arg(long)]
        data_dir: Option<PathBuf>,
        /// Serve the API and run no jobs (an API node of a NATS cluster).
        #[arg(long)]
        no_workers: bool,
        /// service.nats_url: keep jobs and results in NATS JetStream instead of sled.
        #[arg(long)]
        nats: Option<String>,
        #[command(flatten)]
        settings: SettingsArgs,
    },
    /// Run cook workers only, taking jobs from NATS JetStream (a worker node of a cluster).
    Worker {
        /// service.nats_url.
        #[arg(long)]
        nats: Option<String>,
        #[command(flatten)]
        settings: SettingsArgs,
    },
    /// Print the content key of a mesh with these settings, offline (to HEAD a server first).
    Key {
        input: PathBuf,
        #[command(flatten)]
        settings: SettingsArgs,
    },
    /// Upload meshes to a server. Exit codes: 0 done, 1 local error, 2 rejected by the server,
    /// 3 a job failed, 4 server unreachable or failing.
    Submit {
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// e.g. http://127.0.0.1:8650
        #[arg(long)]
        server: String,
        /// Wait for the jobs and write each occluder as OUT_DIR/<name>.occluder.glb.
        #[arg(long)]
        wait: bool,
        #[arg(short, long)]
        out_dir: Option<PathBuf>,
        #[command(flatten)]
        settings: SettingsArgs,
    },
    /// Download a cooked occluder by key (exit codes as submit).
    Fetch {
        key: String,
        #[arg(long)]
        server: String,
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Bake a level (a JSON manifest, or an OBJ whose groups are the instances) into a few merged
    /// occluder batches, cooking each unique mesh once through the same sled cache as the service.
    Level {
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
    },
    /// Culling test of a level's occluders (ours or any other mesh): cameras inside the level,
    /// instance boxes against a low-resolution depth buffer of the occluders, and ground truth
    /// from the real meshes at 512 pixels.
    CullEval {
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
    /// cook.device: where the voxel stages run.
    #[arg(long, value_enum)]
    device: Option<DeviceChoice>,
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
        Ok(config::load(self.config.as_deref(), &self.overrides()?)?)
    }

    /// The flags and `--set`s as `key=value` pairs, in order.
    fn overrides(&self) -> Result<Vec<(String, toml::Value)>> {
        let mut overrides = Vec::new();
        let mut flag = |key: &str, value: Option<toml::Value>| {
            if let Some(v) = value {
                overrides.push((key.to_string(), v));
            }
        };
        let int = |v: Option<usize>| v.map(|v| toml::Value::Integer(v as i64));
        flag("cook.resolution", int(self.resolution));
        let name = |v: &dyn std::fmt::Debug| toml::Value::String(format!("{v:?}").to_lowercase());
        flag("cook.inside", self.inside.as_ref().map(|m| name(m)));
        flag("cook.device", self.device.as_ref().map(|d| name(d)));
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
        Ok(overrides)
    }
}

fn main() {
    // Mesa's device-select layer probes for a display (and complains without one); wgpu picks
    // the adapter itself. Set before any thread starts, as set_var requires.
    if std::env::var_os("NODEVICE_SELECT").is_none() {
        // SAFETY: no other thread exists yet.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()))
        .without_time()
        .init();
    if let Err(e) = run(Cli::parse()) {
        eprintln!("error: {e:#}");
        let code = e.downcast_ref::<client::Exit>().map_or(1, client::Exit::code);
        std::process::exit(code);
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
            let cooked = cook::cook(mesh, stats, ingest_ms, &settings, eval)?;
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
            let cooked = cook::cook(mesh, stats, 0.0, &config::load(None, &[])?, true)?;
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
            let placement = occluder_cook::gpu::for_choice(settings.cook.device)?;
            let q = eval::evaluate(
                &original_mesh,
                &topology.boundary,
                &occluder_mesh,
                &settings.eval,
                placement.gpu.as_deref(),
            )?;
            match &placement.gpu {
                Some(gpu) => println!("rendered on        {}", gpu.name()),
                None => println!("rendered on        cpu"),
            }
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
        Command::Serve {
            listen,
            data_dir,
            no_workers,
            nats,
            settings,
        } => {
            let mut overrides = settings.overrides()?;
            if let Some(url) = nats {
                overrides.push(("service.nats_url".into(), toml::Value::String(url)));
            }
            if let Some(listen) = listen {
                overrides.push(("service.listen".into(), toml::Value::String(listen)));
            }
            if let Some(dir) = data_dir {
                overrides.push((
                    "service.data_dir".into(),
                    toml::Value::String(dir.display().to_string()),
                ));
            }
            let settings = config::load(settings.config.as_deref(), &overrides)?;
            tokio::runtime::Runtime::new()?.block_on(service::serve(settings, no_workers))?;
        }
        Command::Worker { nats, settings } => {
            let mut overrides = settings.overrides()?;
            if let Some(url) = nats {
                overrides.push(("service.nats_url".into(), toml::Value::String(url)));
            }
            let settings = config::load(settings.config.as_deref(), &overrides)?;
            tokio::runtime::Runtime::new()?.block_on(service::work(settings))?;
        }
        Command::Key { input, settings } => {
            let settings = settings.load()?;
            let (mesh, _) = mesh::load_file(&input)?;
            println!("{}", occluder_cook::key::cache_key(&mesh, &settings.cook));
        }
        Command::Submit {
            files,
            server,
            wait,
            out_dir,
            settings: args,
        } => {
            let settings = args.load()?;
            // Only cook settings travel with a job; the server checks them again.
            let query: Vec<(String, String)> = args
                .overrides()?
                .into_iter()
                .filter(|(k, _)| k.starts_with("cook."))
                .map(|(k, v)| {
                    let value = match v {
                        toml::Value::String(s) => s,
                        other => other.to_string(),
                    };
                    (k, value)
                })
                .collect();
            let out_dir = client::output_dir(out_dir)?;
            let client = client::Client::new(&server);
            for file in &files {
                let key = client.submit(file, &settings, &query, wait, &out_dir)?;
                println!("{}\t{key}", file.display());
            }
        }
        Command::Fetch { key, server, output } => {
            client::Client::new(&server).fetch(&key, &output)?;
            println!("wrote {}", output.display());
        }
        Command::Level {
            manifest,
            output,
            report,
            batches,
            data_dir,
            settings,
        } => {
            let mut overrides = settings.overrides()?;
            if let Some(dir) = data_dir {
                overrides.push((
                    "service.data_dir".into(),
                    toml::Value::String(dir.display().to_string()),
                ));
            }
            let settings = config::load(settings.config.as_deref(), &overrides)?;
            let level = occluder_cook::level::load(&manifest)?;
            let dir = settings.service.data_dir();
            std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
            let store = occluder_cook::store::sled::SledStore::open(&dir)
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
            let baked = tokio::runtime::Runtime::new()?
                .block_on(occluder_cook::level::bake(&level, &settings, &store, &progress))?;
            bar.finish_and_clear();
            write(&output, &baked.glb)?;
            let batches = batches.unwrap_or_else(|| output.with_extension("batches.json"));
            write(&batches, &serde_json::to_vec_pretty(&baked.batches)?)?;
            if let Some(path) = report {
                write(&path, &serde_json::to_vec_pretty(&baked.report)?)?;
            }
            let r = &baked.report;
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
        Command::CullEval {
            level,
            occluders,
            cameras,
            pixels,
            json,
            device,
        } => {
            if !(64..=256).contains(&pixels) || cameras == 0 {
                bail!("--pixels must be 64 to 256 and --cameras at least 1");
            }
            let level = occluder_cook::level::load(&level)?;
            let (occluder, _) =
                mesh::load_file(&occluders).with_context(|| format!("occluders {}", occluders.display()))?;
            let placement = occluder_cook::gpu::for_choice(device)?;
            let start = Instant::now();
            let report =
                occluder_cook::level::cull::cull_eval(&level, &occluder, cameras, pixels, placement.gpu.as_deref())
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
            if let Some(path) = json {
                write(&path, &serde_json::to_vec_pretty(&report)?)?;
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
            if let Some(r) = rows.iter().find_map(|row| row.report.as_ref()) {
                println!(
                    "device: {} (dev gpu: every GPU stage on it; mix: inside fell back to the CPU)",
                    r.device
                );
            }
            write(&json, &serde_json::to_vec_pretty(&rows)?)?;
            println!("wrote {}", json.display());
        }
    }
    Ok(())
}

fn write_occluder(path: &Path, cooked: &cook::Cooked) -> Result<()> {
    write(path, &cooked.glb())
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
