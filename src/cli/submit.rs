use super::SettingsArgs;
use anyhow::Result;
use clap::Args;
use occluder_cook::service::client;
use std::path::PathBuf;

#[derive(Args)]
pub struct SubmitArgs {
    #[arg(required = true)]
    files: Vec<PathBuf>,
    #[command(flatten)]
    server: super::ServerArgs,
    /// Wait for the jobs and write each occluder as OUT_DIR/<name>.occluder.glb.
    #[arg(long)]
    wait: bool,
    #[arg(short, long)]
    out_dir: Option<PathBuf>,
    #[command(flatten)]
    settings: SettingsArgs,
}

pub fn run(args: SubmitArgs) -> Result<()> {
    let settings = args.settings.load()?;
    // Only cook settings travel with a job; the server checks them again.
    let query: Vec<(String, String)> = args
        .settings
        .overrides()?
        .into_iter()
        .filter(|(k, _)| k.starts_with("cook.") && k != "cook.max_placed_triangles")
        .map(|(k, v)| (k, super::query_value(v)))
        .collect();
    let out_dir = client::output_dir(args.out_dir)?;
    let client = args.server.client()?;
    for file in &args.files {
        let key = client.submit(file, &settings, &query, args.wait, &out_dir)?;
        println!("{}\t{key}", file.display());
    }
    Ok(())
}
