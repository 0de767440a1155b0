use anyhow::Result;
use clap::Args;
use occluder_cook::service::client;
use std::path::PathBuf;

#[derive(Args)]
pub struct FetchArgs {
    key: String,
    #[arg(long)]
    server: String,
    #[arg(short, long)]
    output: PathBuf,
}

pub fn run(args: FetchArgs) -> Result<()> {
    client::Client::new(&args.server).fetch(&args.key, &args.output)?;
    println!("wrote {}", args.output.display());
    Ok(())
}
