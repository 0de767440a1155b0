use super::SettingsArgs;
use anyhow::{Result, bail};
use clap::Args;
use occluder_cook::fuzz::{self, FuzzSettings};
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args)]
pub struct FuzzArgs {
    /// Folders of seed meshes, searched recursively (default: ../shared/meshes).
    #[arg(long = "corpus")]
    corpus: Vec<PathBuf>,
    /// Mutated inputs to read.
    #[arg(long, default_value_t = 200_000)]
    inputs: usize,
    /// Seed of the mutations: the same seed and corpus give the same inputs.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// An input read more slowly than this is a finding.
    #[arg(long, default_value_t = 2000.0)]
    max_ms: f64,
    /// Where the findings' inputs are written.
    #[arg(long, default_value = "fuzz-findings")]
    findings: PathBuf,
    #[command(flatten)]
    settings: SettingsArgs,
}

/// Fuzzes ingest; exits non-zero when anything panicked or was slow.
pub fn run(args: FuzzArgs) -> Result<()> {
    let settings = args.settings.load()?;
    let dirs = match args.corpus.is_empty() {
        true => vec![PathBuf::from("../shared/meshes")],
        false => args.corpus,
    };
    let seeds = fuzz::seeds_from(&dirs).map_err(|e| anyhow::anyhow!("cannot read the seeds in {dirs:?}: {e}"))?;
    if seeds.is_empty() {
        bail!("no mesh files under {dirs:?} to seed the fuzzer");
    }
    let fuzz_settings = FuzzSettings {
        inputs: args.inputs,
        seed: args.seed,
        max_ms: args.max_ms,
        limits: settings.ingest_limits(),
    };
    let start = Instant::now();
    let progress = |done: usize| {
        if done.is_multiple_of(20_000) {
            eprintln!("{done} inputs, {:.0} s", start.elapsed().as_secs_f64());
        }
    };
    let report = fuzz::run(&seeds, &fuzz_settings, &progress);
    let per_format: Vec<String> = report.per_format.iter().map(|(f, n)| format!("{f} {n}")).collect();
    println!(
        "{} inputs from {} seeds ({}) in {:.1} s: {} read, {} refused, slowest {:.0} ms, {} findings, peak memory {}",
        report.inputs,
        seeds.len(),
        per_format.join(", "),
        start.elapsed().as_secs_f64(),
        report.accepted,
        report.rejected,
        report.slowest_ms,
        report.findings.len(),
        peak_memory().unwrap_or_else(|| "unknown".into())
    );
    if report.findings.is_empty() {
        return Ok(());
    }
    let paths = fuzz::save_findings(&report.findings, &args.findings)?;
    for (finding, path) in report.findings.iter().zip(&paths) {
        println!(
            "{}: {} after {} of {} ({:.0} ms): {}",
            path.display(),
            finding.kind,
            finding.mutation,
            finding.seed,
            finding.ms,
            finding.message
        );
    }
    bail!(
        "{} findings, written to {}",
        report.findings.len(),
        args.findings.display()
    )
}

/// The process's peak resident memory, from /proc (Linux).
fn peak_memory() -> Option<String> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    Some(line.trim_start_matches("VmHWM:").trim().to_string())
}
