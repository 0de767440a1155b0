use super::{SettingsArgs, write};
use anyhow::{Context, Result, bail};
use clap::Args;
use occluder_cook::bench;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

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
    #[arg(long, value_name = "OLD.json", conflicts_with = "against")]
    compare: Option<PathBuf>,
    /// Another build of occluder-cook to time this one against, side by side: each runs this
    /// bench as a fresh process in turn, `--rounds` times, which goes first alternating, and
    /// the table gives each mesh's median cook time under both, the ratio of the medians and
    /// the median of the rounds' ratios. The settings flags go to both; the judging is skipped.
    /// The rounds' JSONs go to a folder named after --json (bench.json: bench.rounds/).
    #[arg(long, value_name = "OLD_BINARY")]
    against: Option<PathBuf>,
    /// Rounds of --against.
    #[arg(long, default_value_t = 5, requires = "against", value_parser = clap::value_parser!(u32).range(1..=100))]
    rounds: u32,
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
    if let Some(old) = &args.against {
        return side_by_side(old, args.rounds, &corpus, &args.settings, &args.json);
    }
    let earlier = match &args.compare {
        Some(path) => Some(read_bench_json(path)?),
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

fn read_bench_json(path: &Path) -> Result<Value> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let json = serde_json::from_slice::<Value>(&bytes);
    let json = json.with_context(|| format!("{} is not JSON", path.display()))?;
    if !json.is_array() {
        bail!("{} is not a bench JSON (an array of rows)", path.display());
    }
    Ok(json)
}

/// `bench --against`: this binary and `old` run the bench in turn, `rounds` times.
fn side_by_side(old: &Path, rounds: u32, corpus: &Path, settings: &SettingsArgs, json: &Path) -> Result<()> {
    let new = std::env::current_exe().context("cannot find this program's own binary")?;
    let folder = json.with_extension("rounds");
    std::fs::create_dir_all(&folder).with_context(|| format!("cannot create {}", folder.display()))?;
    let flags = settings.as_flags()?;
    let builds = [("old", old), ("new", new.as_path())];
    // Which builds take --judge-views, to skip the judging with 0; one from before the flag
    // judges at its eval's views, outside the cook's time.
    let has_judge_views = [takes_judge_views(old)?, true];
    let mut runs: [Vec<Value>; 2] = Default::default();
    let bar = occluder_cook::service::client::count_bar("rounds");
    bar.set_length(u64::from(rounds) * 2);
    for round in 1..=rounds {
        let order = if round % 2 == 1 { [0, 1] } else { [1, 0] };
        for side in order {
            let (name, binary) = builds[side];
            let out = folder.join(format!("{name}.{round}.json"));
            let mut command = Command::new(binary);
            command
                .arg("bench")
                .arg("--corpus")
                .arg(corpus)
                .arg("--json")
                .arg(&out)
                .args(&flags);
            if has_judge_views[side] {
                command.args(["--judge-views", "0"]);
            }
            let ran = command
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .output();
            let ran = ran.with_context(|| format!("cannot run {}", binary.display()))?;
            if !ran.status.success() {
                let stderr = String::from_utf8_lossy(&ran.stderr);
                let last = stderr
                    .lines()
                    .rev()
                    .find(|l| !l.trim().is_empty())
                    .unwrap_or("no message");
                bail!("{} bench failed in round {round}: {last}", binary.display());
            }
            runs[side].push(read_bench_json(&out)?);
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    println!("{} (then) against {} (now):", old.display(), new.display());
    println!(
        "{}",
        bench::side_by_side(&runs[0], &runs[1]).map_err(anyhow::Error::msg)?
    );
    println!("wrote the rounds' JSONs to {}", folder.display());
    Ok(())
}

/// Whether `binary`'s bench takes `--judge-views`, from its help.
fn takes_judge_views(binary: &Path) -> Result<bool> {
    let help = Command::new(binary)
        .args(["bench", "--help"])
        .stdin(Stdio::null())
        .output();
    let help = help.with_context(|| format!("cannot run {}", binary.display()))?;
    if !help.status.success() {
        bail!("{} has no bench command", binary.display());
    }
    Ok(String::from_utf8_lossy(&help.stdout).contains("--judge-views"))
}
