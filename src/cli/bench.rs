use super::{SettingsArgs, write};
use anyhow::{Context, Result, bail};
use clap::Args;
use occluder_cook::bench;
use std::path::PathBuf;

#[derive(Args)]
pub struct BenchArgs {
    /// Folder of meshes [default: $OCCLUDER_CORPUS or ../shared/meshes].
    #[arg(long)]
    corpus: Option<PathBuf>,
    #[arg(long, default_value = "bench.json")]
    json: PathBuf,
    /// Judge each occluder again from this many views, into the JSON (`judged`) and the table's
    /// last column (non-below false pixels); 0 skips it.
    #[arg(long, default_value_t = 1024)]
    judge_views: usize,
    /// An earlier run's JSON: prints each mesh's cook time, speed-up, coverage, triangles and
    /// false pixels against it.
    #[arg(long, value_name = "OLD.json")]
    compare: Option<PathBuf>,
    #[command(flatten)]
    settings: SettingsArgs,
}

pub fn run(args: BenchArgs) -> Result<()> {
    let settings = args.settings.load()?;
    let corpus = args
        .corpus
        .or_else(|| std::env::var_os("OCCLUDER_CORPUS").map(PathBuf::from))
        .unwrap_or_else(|| PathBuf::from("../shared/meshes"));
    if !corpus.is_dir() {
        bail!(
            "corpus folder {} not found: pass --corpus DIR or set OCCLUDER_CORPUS",
            corpus.display()
        );
    }
    let earlier = match &args.compare {
        Some(path) => {
            let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
            let json = serde_json::from_slice::<serde_json::Value>(&bytes);
            let json = json.with_context(|| format!("{} is not JSON", path.display()))?;
            if !json.is_array() {
                bail!("{} is not a bench JSON (an array of rows)", path.display());
            }
            Some(json)
        }
        None => None,
    };
    let files = bench::corpus_files(&corpus)?;
    let bar = occluder_cook::service::client::count_bar("meshes");
    let rows = bench::run(&files, &settings, args.judge_views, &bar);
    if let Some(r) = rows.iter().find_map(|row| row.report.as_ref()) {
        println!(
            "device: {} (dev gpu: every GPU stage on it; mix: inside fell back to the CPU)",
            r.device
        );
    }
    println!("{}", bench::summary(&rows));
    if let Some(earlier) = &earlier {
        println!("{}", bench::compare(&rows, earlier).map_err(anyhow::Error::msg)?);
    }
    write(&args.json, &serde_json::to_vec_pretty(&rows)?)?;
    println!("wrote {}", args.json.display());
    Ok(())
}
