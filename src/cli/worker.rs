use super::SettingsArgs;
use anyhow::Result;
use clap::Args;
use occluder_cook::service;

#[derive(Args)]
pub struct WorkerArgs {
    /// service.nats_url.
    #[arg(long)]
    nats: Option<String>,
    #[command(flatten)]
    settings: SettingsArgs,
}

pub fn run(args: WorkerArgs) -> Result<()> {
    let settings = args.settings.load_with(&[("service.nats_url", args.nats)])?;
    tokio::runtime::Runtime::new()?.block_on(service::work(settings))?;
    Ok(())
}
