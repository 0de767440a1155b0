use anyhow::{Context, Result, bail};
use clap::Args;
use occluder_cook::soak::{SoakOptions, soak};
use std::path::PathBuf;
use std::time::Duration;

#[derive(Args)]
pub struct SoakArgs {
    /// How long the load runs: seconds, or with a unit (90s, 10m, 1h).
    #[arg(long, default_value = "10m", value_parser = duration)]
    duration: Duration,
    /// Time between SIGKILLs of the server, which is started again at once on the same port (with
    /// --worker-nodes: of the server and each worker node, in turn).
    #[arg(long, default_value = "2m", value_parser = duration)]
    restart_every: Duration,
    /// Client threads.
    #[arg(long, default_value_t = 4)]
    clients: usize,
    /// Scratch folder for the server's data, its tokens file and its log (server.log); emptied
    /// first.
    #[arg(long, default_value = "soak")]
    dir: PathBuf,
    /// Writes the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// A `service.*` setting for the soaked server and worker nodes, KEY=VALUE (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    server_settings: Vec<String>,
    /// Soak a cluster: this many `worker` nodes beside the server, which runs no cook, all on the
    /// NATS server that `--set service.nats_url=…` names.
    #[arg(long, default_value_t = 0)]
    worker_nodes: usize,
}

/// `90`, `90s`, `10m` or `1h`.
fn duration(text: &str) -> Result<Duration, String> {
    let (number, unit) = match text.find(|c: char| c.is_ascii_alphabetic()) {
        Some(at) => text.split_at(at),
        None => (text, "s"),
    };
    let seconds = match unit {
        "s" => 1.0,
        "m" => 60.0,
        "h" => 3600.0,
        _ => return Err(format!("unknown unit `{unit}`: use s, m or h")),
    };
    match number.parse::<f64>() {
        Ok(n) if n.is_finite() && n > 0.0 && n * seconds < 1e7 => Ok(Duration::from_secs_f64(n * seconds)),
        _ => Err(format!("`{text}` is not a duration such as 90s or 10m")),
    }
}

/// Soaks a server of this binary; exits non-zero when a job was lost, wrong bytes were served
/// or an answer broke the API's promises.
pub fn run(args: SoakArgs) -> Result<()> {
    if args.clients == 0 || args.clients > 256 {
        bail!("--clients must be 1 to 256");
    }
    if let Some(other) = args.server_settings.iter().find(|s| !s.starts_with("service.")) {
        bail!("--set {other}: only service.* settings (the soak computes keys with the default cook settings)");
    }
    if args.worker_nodes > 16 {
        bail!("--worker-nodes must be at most 16");
    }
    let on_nats = args
        .server_settings
        .iter()
        .any(|s| s.strip_prefix("service.nats_url=").is_some_and(|url| !url.is_empty()));
    if args.worker_nodes > 0 && !on_nats {
        bail!("--worker-nodes needs --set service.nats_url=…: worker nodes take their jobs from NATS");
    }
    let _ = std::fs::remove_dir_all(&args.dir);
    let options = SoakOptions {
        duration: args.duration,
        restart_every: args.restart_every,
        clients: args.clients,
        dir: args.dir,
        binary: std::env::current_exe().context("cannot find this binary")?,
        server_settings: args.server_settings,
        worker_nodes: args.worker_nodes,
    };
    let report = soak(&options).map_err(anyhow::Error::msg)?;
    for minute in &report.minutes {
        println!(
            "minute {:>2}: {:>6} cached GETs, p99 {:>6.2} ms, peak RSS {:>6.1} MiB",
            minute.minute, minute.cached_gets, minute.cached_get_p99_ms, minute.peak_rss_mib
        );
    }
    let requests: u64 = report.requests.values().sum();
    println!(
        "{:.0} s, {} restarts (SIGKILL) of the server and {} of worker nodes, {requests} requests ({} without an answer, {} refused as busy): \
         {} jobs accepted, {} done, {} failed, {} cancelled ({} ended otherwise), {} lost, {} started again after a kill; \
         {} occluders fetched, {} with wrong bytes, {} wrong keys; \
         {} unexpected answers; RSS from minute 2 on: highest peak {:.2}x the lowest",
        report.seconds,
        report.restarts,
        report.worker_restarts,
        report.unavailable.values().sum::<u64>(),
        report.busy,
        report.jobs_accepted,
        report.jobs_done,
        report.jobs_failed,
        report.jobs_cancelled,
        report.cancels_undone,
        report.jobs_lost,
        report.jobs_started_again,
        report.occluders_fetched,
        report.wrong_bytes,
        report.wrong_keys,
        report.unexpected.values().sum::<u64>(),
        report.rss_spread,
    );
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report).expect("reports serialize");
        std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))?;
    }
    if let Some(fault) = report.fault() {
        bail!("{fault}");
    }
    Ok(())
}
