use super::SettingsArgs;
use anyhow::Result;
use clap::Args;
use occluder_cook::service::client;
use std::path::PathBuf;

#[derive(Args)]
pub struct SubmitArgs {
    #[arg(required_unless_present = "level")]
    files: Vec<PathBuf>,
    /// Upload a level manifest and the meshes it names (next to it) to /v1/levels, wait for the
    /// bake, and write OUT_DIR/<name>.occluder.glb.
    #[arg(long, value_name = "MANIFEST")]
    level: Option<PathBuf>,
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
    let out_dir = client::output_dir(args.out_dir)?;
    let client = args.server.client()?;
    if let Some(manifest) = &args.level {
        let out = out_dir.join(format!(
            "{}.occluder.glb",
            manifest.file_stem().unwrap_or_default().to_string_lossy()
        ));
        let query = args.settings.job_query(&["cook", "level"])?;
        let (key, _) = client.submit_level(manifest, &query, &out)?;
        println!("{}	{key}", manifest.display());
    }
    let query = args.settings.job_query(&["cook"])?;
    for file in &args.files {
        let key = client.submit(file, &settings, &query, args.wait, &out_dir)?;
        println!("{}\t{key}", file.display());
    }
    Ok(())
}
