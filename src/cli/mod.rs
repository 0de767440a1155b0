//! One module per command: its arguments and what it does. `main.rs` parses and dispatches.

pub mod bench;
pub mod convert;
pub mod cook;
pub mod cull_eval;
pub mod demo;
pub mod eval;
pub mod fetch;
pub mod fuzz;
pub mod key;
pub mod level;
pub mod serve;
pub mod soak;
pub mod submit;
pub mod token;
pub mod worker;

use anyhow::{Context, Result};
use clap::Args;
use occluder_cook::config::{self, Settings};
use occluder_cook::cook::{Cooked, Report};
use occluder_cook::gpu::DeviceChoice;
use occluder_cook::voxel::InsideMethod;
use std::path::{Path, PathBuf};

/// The settings flags every cooking command takes.
#[derive(Args)]
pub struct SettingsArgs {
    /// A TOML file over the built-in config/default.toml.
    #[arg(long)]
    config: Option<PathBuf>,
    /// cook.resolution: voxels along the longest axis.
    #[arg(long)]
    resolution: Option<usize>,
    /// cook.inside: the inside/outside method.
    #[arg(long, value_enum)]
    inside: Option<InsideMethod>,
    /// cook.device: where the voxel stages run.
    #[arg(long, value_enum)]
    device: Option<DeviceChoice>,
    /// cook.max_triangles: the occluder's triangle budget.
    #[arg(long)]
    max_triangles: Option<usize>,
    /// cook.target_coverage: share of the inner volume the boxes should fill.
    #[arg(long)]
    target_coverage: Option<f64>,
    /// cook.smallest_hole: openings narrower than this (world units) count as closed; eval
    /// judges against the original with the same openings closed.
    #[arg(long, value_name = "WIDTH")]
    smallest_hole: Option<f64>,
    /// Views of eval: a number of directions around the mesh (eval.views), `outside` for those,
    /// or `inside` for a cube map from the centre of its bounds (eval.view_set).
    #[arg(long)]
    views: Option<String>,
    /// eval.pixels: image size.
    #[arg(long)]
    pixels: Option<usize>,
    /// Any setting, e.g. --set cook.refine=false (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
}

impl SettingsArgs {
    pub fn load(&self) -> Result<Settings> {
        self.load_with(&[])
    }

    /// The settings with `extra` (key, value) pairs after the flags, as a command's own options
    /// set them.
    pub fn load_with(&self, extra: &[(&str, Option<String>)]) -> Result<Settings> {
        let mut overrides = self.overrides()?;
        for (key, value) in extra {
            if let Some(value) = value {
                overrides.push((key.to_string(), toml::Value::String(value.clone())));
            }
        }
        Ok(config::load(self.config.as_deref(), &overrides)?)
    }

    /// The same settings as flags another build of this program takes: `--config` and a `--set`
    /// for each of [`SettingsArgs::overrides`], its value as TOML writes it.
    pub fn as_flags(&self) -> Result<Vec<std::ffi::OsString>> {
        let mut flags = Vec::new();
        if let Some(config) = &self.config {
            flags.extend(["--config".into(), config.clone().into_os_string()]);
        }
        for (key, value) in self.overrides()? {
            flags.extend(["--set".into(), format!("{key}={value}").into()]);
        }
        Ok(flags)
    }

    /// The overrides that travel with a job as query parameters: those of `sections` (`cook`,
    /// `level`) but the server's own limits. The server checks them again.
    pub fn job_query(&self, sections: &[&str]) -> Result<Vec<(String, String)>> {
        Ok(self
            .overrides()?
            .into_iter()
            .filter(|(k, _)| k != "cook.max_placed_triangles")
            .filter(|(k, _)| sections.iter().any(|s| k.split('.').next() == Some(*s)))
            .map(|(k, v)| (k, query_value(v)))
            .collect())
    }

    /// The flags and `--set`s as `key=value` pairs, in order.
    pub fn overrides(&self) -> Result<Vec<(String, toml::Value)>> {
        let mut overrides = Vec::new();
        let mut flag = |key: &str, value: Option<toml::Value>| {
            if let Some(v) = value {
                overrides.push((key.to_string(), v));
            }
        };
        let int = |v: Option<usize>| v.map(|v| toml::Value::Integer(v as i64));
        flag("cook.resolution", int(self.resolution));
        let name = |v: &dyn std::fmt::Debug| toml::Value::String(format!("{v:?}").to_lowercase());
        flag("cook.inside", self.inside.as_ref().map(|m| name(m)));
        flag("cook.device", self.device.as_ref().map(|d| name(d)));
        flag("cook.max_triangles", int(self.max_triangles));
        flag("cook.target_coverage", self.target_coverage.map(toml::Value::Float));
        flag("cook.smallest_hole", self.smallest_hole.map(toml::Value::Float));
        match self.views.as_deref().map(|v| (v, v.parse::<usize>())) {
            Some((_, Ok(n))) => flag("eval.views", int(Some(n))),
            Some((set, Err(_))) => flag("eval.view_set", Some(toml::Value::String(set.to_string()))),
            None => {}
        }
        flag("eval.pixels", int(self.pixels));
        for assignment in &self.set {
            overrides.push(config::parse_assignment(assignment)?);
        }
        Ok(overrides)
    }
}

/// Where a client command finds the server, and how it proves who it is.
#[derive(Args)]
pub struct ServerArgs {
    /// e.g. http://127.0.0.1:8650, or https://… for a server with service.tls_cert
    #[arg(long)]
    server: String,
    /// A bearer token, for a server with service.auth = "tokens".
    #[arg(long, env = "OCCLUDER_COOK_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// PEM certificates that an https server's certificate must chain to, in place of the
    /// public roots: a self-signed or private CA's.
    #[arg(long, value_name = "PEM")]
    ca_cert: Option<PathBuf>,
}

impl ServerArgs {
    pub fn client(&self) -> Result<occluder_cook::service::client::Client, occluder_cook::service::client::Exit> {
        occluder_cook::service::client::Client::new(&self.server, self.token.clone(), self.ca_cert.as_deref())
    }
}

/// A file's name, for captions.
fn file_name(path: &Path) -> String {
    path.file_name()
        .map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned())
}

/// Draws the preview sheet and writes it as PNG; says how many false pixels its views show.
fn write_preview(
    path: &Path,
    original: &occluder_cook::mesh::Mesh,
    occluder: &[occluder_cook::eval::preview::PieceTriangle],
    caption: &occluder_cook::eval::preview::Caption,
) -> Result<()> {
    let (sheet, false_pixels) = occluder_cook::eval::preview::sheet(original, occluder, caption);
    write(path, &occluder_cook::eval::preview::png(&sheet))?;
    eprintln!(
        "preview: {} ({false_pixels} false pixels in its 4 views)",
        path.display()
    );
    Ok(())
}

/// A setting's value as a query parameter: strings bare, the rest as TOML writes them.
fn query_value(value: toml::Value) -> String {
    match value {
        toml::Value::String(s) => s,
        other => other.to_string(),
    }
}

/// A path as a setting's value.
fn path_setting(path: Option<PathBuf>) -> Option<String> {
    path.map(|p| p.display().to_string())
}

fn write_occluder(path: &Path, cooked: &Cooked) -> Result<()> {
    write(path, &cooked.glb())
}

/// One line on what was cooked, the quality figures when measured, then the notes.
fn summarize(input: &Path, r: &Report) {
    print!(
        "{}: {} triangles in, occluder of {} triangles from {} boxes, {} quads, {} patches and {} surface pieces in {:.1} ms",
        input.display(),
        r.input.triangles,
        r.occluder.triangles,
        r.occluder.boxes,
        r.occluder.quads,
        r.occluder.patches,
        r.occluder.surface_pieces,
        r.total_ms()
    );
    match &r.quality {
        Some(q) => {
            let coverage = match q.views_seeing {
                0 => "no view sees the original, so no coverage".to_string(),
                _ => format!("coverage {:.1}%", q.coverage * 100.0),
            };
            println!(
                "; {coverage}, false pixels {} ({} in non-below views), outside samples {:.2}%",
                q.false_pixels,
                q.false_pixels_non_below,
                q.outside_samples * 100.0
            )
        }
        None => println!(),
    }
    for note in &r.notes {
        println!("note: {note}");
    }
}

fn write(path: &Path, bytes: &[u8]) -> Result<()> {
    std::fs::write(path, bytes).with_context(|| format!("cannot write {}", path.display()))
}
