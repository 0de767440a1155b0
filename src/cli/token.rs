use super::SettingsArgs;
use anyhow::{Result, bail};
use clap::{Args, Subcommand};
use occluder_cook::service::auth::{self, Scope};
use std::path::PathBuf;

#[derive(Args)]
pub struct TokenArgs {
    #[command(subcommand)]
    command: TokenCommand,
}

#[derive(Subcommand)]
enum TokenCommand {
    /// Make a token: print it once, and append its hash to the tokens file.
    New {
        /// Who it is for: what the server logs and its metrics name.
        #[arg(long)]
        name: String,
        /// What it may do: read, cook, admin (comma-separated).
        #[arg(long, value_enum, value_delimiter = ',', required = true)]
        scopes: Vec<Scope>,
        /// The tokens file; default service.tokens_file.
        #[arg(long)]
        file: Option<PathBuf>,
        #[command(flatten)]
        settings: SettingsArgs,
    },
}

pub fn run(args: TokenArgs) -> Result<()> {
    let TokenCommand::New {
        name,
        scopes,
        file,
        settings,
    } = args.command;
    let settings = settings.load()?;
    let file = match file {
        Some(file) => file,
        None if settings.service.tokens_file.is_empty() => {
            bail!("no tokens file: pass --file or set service.tokens_file")
        }
        None => settings.service.tokens_file.into(),
    };
    let (token, entry) = auth::new_token(&name, &scopes).map_err(anyhow::Error::msg)?;
    auth::append(&file, entry).map_err(anyhow::Error::msg)?;
    println!("{token}");
    eprintln!("token `{name}` added to {}; it is shown only this once", file.display());
    Ok(())
}
