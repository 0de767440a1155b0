use anyhow::Result;
use clap::Args;
use std::path::PathBuf;

#[derive(Args)]
pub struct FetchArgs {
    key: String,
    #[command(flatten)]
    server: super::ServerArgs,
    #[arg(short, long)]
    output: PathBuf,
}

pub fn run(args: FetchArgs) -> Result<()> {
    args.server.client()?.fetch(&args.key, &args.output)?;
    println!("wrote {}", args.output.display());
    Ok(())
}
