use super::SettingsArgs;
use anyhow::Result;
use clap::Args;
use occluder_cook::{key, mesh};
use std::path::PathBuf;

#[derive(Args)]
pub struct KeyArgs {
    input: PathBuf,
    #[command(flatten)]
    settings: SettingsArgs,
}

pub fn run(args: KeyArgs) -> Result<()> {
    let settings = args.settings.load()?;
    let (mesh, _) = mesh::load_file(&args.input, &settings.ingest_limits())?;
    println!("{}", key::cache_key(&mesh, &settings.cook));
    Ok(())
}
