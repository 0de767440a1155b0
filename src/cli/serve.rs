use super::{SettingsArgs, path_setting};
use anyhow::Result;
use clap::Args;
use occluder_cook::service;
use std::path::PathBuf;

#[derive(Args)]
pub struct ServeArgs {
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
    /// Serve an address other machines can reach with service.auth = "none".
    #[arg(long)]
    insecure_no_auth: bool,
    #[command(flatten)]
    settings: SettingsArgs,
}

pub fn run(args: ServeArgs) -> Result<()> {
    let settings = args.settings.load_with(&[
        ("service.nats_url", args.nats),
        ("service.listen", args.listen),
        ("service.data_dir", path_setting(args.data_dir)),
    ])?;
    tokio::runtime::Runtime::new()?.block_on(service::serve(settings, args.no_workers, args.insecure_no_auth))?;
    Ok(())
}
