//! Settings: config/default.toml (built in), then an optional file, then flags. Every key of an
//! override must exist in the defaults with the same type, and every value is range-checked, so
//! a typo or a bad value is an error that names the key.

use crate::eval::EvalSettings;
use crate::gpu::DeviceChoice;
use crate::occluder::Shape;
use crate::voxel::InsideMethod;
use serde::{Deserialize, Serialize};
use std::path::Path;
use toml::{Table, Value};

pub const DEFAULT_TOML: &str = include_str!("../config/default.toml");

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    pub cook: CookSettings,
    pub eval: EvalSettings,
    pub service: ServiceSettings,
    pub level: LevelSettings,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LevelSettings {
    pub batch_max_triangles: usize,
    pub batch_max_extent: f64,
    /// Cameras of the cull test a bake runs on its own occluder (0: none).
    pub cull_cameras: usize,
    /// A player's eye above the floor, in the level's units: where a soup's cook looks from.
    pub eye_height: f64,
    /// A soup's voxel size in the level's units (0: its longest side / 1024).
    pub voxel_size: f64,
    /// A soup's selection cells' side in the level's units (0: its longest side / 8).
    pub soup_cell_size: f64,
    /// The share of the map's triangles a soup's occluder may use.
    pub soup_triangle_share: f64,
    /// The most triangles one cell of a soup's occluder may use.
    pub soup_cell_triangles: usize,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ServiceSettings {
    pub listen: String,
    pub workers: usize,
    pub evaluate: bool,
    pub data_dir: String,
    pub max_body_bytes: usize,
    pub max_queue: usize,
    pub max_cache_bytes: u64,
    pub nats_url: String,
    pub ack_wait_s: f64,
    pub max_deliver: u32,
    pub auth: AuthMode,
    pub tokens_file: String,
    pub max_resolution: usize,
    pub max_quad_grid: usize,
    pub job_timeout_s: f64,
    pub max_parse_bytes: u64,
    pub token_submissions_per_s: f64,
    pub token_submission_burst: f64,
    pub token_max_queued: usize,
    pub job_retention_s: f64,
    pub sled_cache_bytes: u64,
    pub tls_cert: String,
    pub tls_key: String,
    pub nats_user: String,
    pub nats_password_file: String,
    pub nats_nkey_file: String,
    pub nats_creds_file: String,
    pub nats_ca_cert: String,
}

/// Who may call the service.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum AuthMode {
    /// Anyone who reaches the port: `serve` takes it only on loopback, unless told otherwise.
    None,
    /// A bearer token from `service.tokens_file`, with the scope the endpoint needs.
    Tokens,
}

impl ServiceSettings {
    /// `data_dir`, or the per-user default when it is empty.
    pub fn data_dir(&self) -> std::path::PathBuf {
        if !self.data_dir.is_empty() {
            return self.data_dir.clone().into();
        }
        let base = std::env::var_os("XDG_DATA_HOME")
            .map(std::path::PathBuf::from)
            .or_else(|| std::env::var_os("HOME").map(|h| std::path::PathBuf::from(h).join(".local/share")))
            .unwrap_or_else(|| ".".into());
        base.join("occluder-cook")
    }
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CookSettings {
    pub resolution: usize,
    pub inside: InsideMethod,
    pub device: DeviceChoice,
    pub target_coverage: f64,
    pub min_box_gain: f64,
    pub max_boxes: usize,
    pub min_box_voxels: usize,
    pub max_triangles: usize,
    pub min_silhouette_gain: f64,
    /// At the end, a chosen piece that later ones left with fewer pixels of its own than this
    /// share of the silhouette is dropped.
    pub min_silhouette_own: f64,
    pub refine: bool,
    pub shapes: Vec<Shape>,
    pub quad_grid: usize,
    pub min_patch_area: f64,
    /// When an open mesh's surface pieces alone cover this share of the silhouette, they are the
    /// occluder and the voxel stages are skipped.
    pub surface_enough: f64,
    /// Openings narrower than this, in world units, count as closed (0: none). Left out of
    /// the cache key while 0, so that keys from before it stay valid.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub smallest_hole: f64,
    pub cpsv_pixels: usize,
    pub cpsv_back_share: f64,
    pub cpsv_inside_faces: usize,
    pub cpsv_votes: u32,
    pub max_placed_triangles: u64,
}

impl CookSettings {
    /// The thresholds of `inside = "cpsv"`.
    pub fn cpsv(&self) -> crate::voxel::cpsv::CpsvSettings {
        crate::voxel::cpsv::CpsvSettings {
            pixels: self.cpsv_pixels,
            back_share: self.cpsv_back_share,
            inside_faces: self.cpsv_inside_faces,
            votes: self.cpsv_votes,
        }
    }
}

impl Settings {
    /// What ingest may allocate for a mesh.
    pub fn ingest_limits(&self) -> crate::mesh::IngestLimits {
        crate::mesh::IngestLimits {
            max_placed_triangles: self.cook.max_placed_triangles,
            max_parse_bytes: self.service.max_parse_bytes,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config {path}: {message}")]
    Read { path: String, message: String },
    #[error("unknown setting `{0}`")]
    UnknownKey(String),
    #[error("setting `{key}` must be {expected}, got {got}")]
    WrongType { key: String, expected: String, got: String },
    #[error("setting `{key}` = {value} is out of range: {range}")]
    OutOfRange { key: String, value: String, range: String },
    #[error("setting `{key}`: {message}")]
    Invalid { key: String, message: String },
    #[error("`--set {0}`: expected KEY=VALUE, e.g. cook.resolution=96")]
    BadAssignment(String),
}

/// Builds settings from the defaults, an optional TOML file and `key=value` overrides
/// (keys dotted, e.g. `cook.resolution`).
pub fn load(file: Option<&Path>, overrides: &[(String, Value)]) -> Result<Settings, ConfigError> {
    let mut table: Table = DEFAULT_TOML.parse().expect("the built-in defaults parse");
    let defaults = table.clone();
    if let Some(path) = file {
        let read_error = |message: String| ConfigError::Read {
            path: path.display().to_string(),
            message,
        };
        let text = std::fs::read_to_string(path).map_err(|e| read_error(e.to_string()))?;
        let file_table: Table = text
            .parse()
            .map_err(|e: toml::de::Error| read_error(e.message().to_string()))?;
        overlay(&mut table, &defaults, file_table, "")?;
    }
    finish(table, &defaults, overrides)
}

/// `base` with `key=value` overrides, checked like [`load`]'s.
pub fn load_over(base: &Settings, overrides: &[(String, Value)]) -> Result<Settings, ConfigError> {
    let defaults: Table = DEFAULT_TOML.parse().expect("the built-in defaults parse");
    let table = Table::try_from(base).expect("settings serialize to TOML");
    finish(table, &defaults, overrides)
}

fn finish(mut table: Table, defaults: &Table, overrides: &[(String, Value)]) -> Result<Settings, ConfigError> {
    for (key, value) in overrides {
        let mut nested = Table::new();
        let parts: Vec<&str> = key.split('.').collect();
        let (last, sections) = parts.split_last().expect("split yields one part");
        let mut cursor = &mut nested;
        for s in sections {
            cursor = cursor
                .entry(s.to_string())
                .or_insert_with(|| Value::Table(Table::new()))
                .as_table_mut()
                .expect("just inserted a table");
        }
        cursor.insert(last.to_string(), value.clone());
        overlay(&mut table, defaults, nested, "")?;
    }
    let settings: Settings =
        serde_path_to_error::deserialize(Value::Table(table)).map_err(|e| ConfigError::Invalid {
            key: e.path().to_string(),
            message: e.inner().message().to_string(),
        })?;
    validate(&settings)?;
    Ok(settings)
}

/// Parses `KEY=VALUE`; the value is TOML (`96`, `0.5`, `true`) or else a bare string.
pub fn parse_assignment(text: &str) -> Result<(String, Value), ConfigError> {
    let (key, value) = text
        .split_once('=')
        .ok_or_else(|| ConfigError::BadAssignment(text.to_string()))?;
    let value = value.trim();
    let parsed = format!("v = {value}")
        .parse::<Table>()
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| Value::String(value.to_string()));
    Ok((key.trim().to_string(), parsed))
}

fn overlay(target: &mut Table, defaults: &Table, source: Table, prefix: &str) -> Result<(), ConfigError> {
    for (key, value) in source {
        let path = if prefix.is_empty() {
            key.clone()
        } else {
            format!("{prefix}.{key}")
        };
        let Some(default) = defaults.get(&key) else {
            return Err(ConfigError::UnknownKey(path));
        };
        match (default, value) {
            (Value::Table(d), Value::Table(s)) => {
                let t = target
                    .get_mut(&key)
                    .and_then(Value::as_table_mut)
                    .expect("defaults and target share their shape");
                overlay(t, d, s, &path)?;
            }
            // Every integer setting is a count.
            (Value::Integer(_), Value::Integer(i)) if i < 0 => {
                return Err(ConfigError::OutOfRange {
                    key: path,
                    value: i.to_string(),
                    range: "expected a count, 0 or more".into(),
                });
            }
            // An integer is a fine float.
            (Value::Float(_), Value::Integer(i)) => {
                target.insert(key, Value::Float(i as f64));
            }
            (d, v) if std::mem::discriminant(d) == std::mem::discriminant(&v) => {
                target.insert(key, v);
            }
            (d, v) => {
                return Err(ConfigError::WrongType {
                    key: path,
                    expected: describe(d),
                    got: describe(&v),
                });
            }
        }
    }
    Ok(())
}

fn describe(v: &Value) -> String {
    match v {
        Value::Table(_) => "a table".into(),
        Value::Array(_) => "an array".into(),
        other => format!("{} ({other})", other.type_str()),
    }
}

fn validate(s: &Settings) -> Result<(), ConfigError> {
    let c = &s.cook;
    let e = &s.eval;
    check("cook.resolution", c.resolution as f64, 4.0, 1024.0)?;
    check("cook.target_coverage", c.target_coverage, 0.0, 1.0)?;
    check("cook.min_box_gain", c.min_box_gain, 0.0, 1.0)?;
    check("cook.max_boxes", c.max_boxes as f64, 0.0, 100_000.0)?;
    check("cook.min_box_voxels", c.min_box_voxels as f64, 1.0, 1e12)?;
    check("cook.max_triangles", c.max_triangles as f64, 0.0, 1e9)?;
    check("cook.min_silhouette_gain", c.min_silhouette_gain, 0.0, 1.0)?;
    check("cook.min_silhouette_own", c.min_silhouette_own, 0.0, 1.0)?;
    check("cook.quad_grid", c.quad_grid as f64, 8.0, 4096.0)?;
    check("cook.min_patch_area", c.min_patch_area, 0.0, 1.0)?;
    check("cook.surface_enough", c.surface_enough, 0.0, 1.0)?;
    check("cook.smallest_hole", c.smallest_hole, 0.0, 1e12)?;
    check("cook.cpsv_pixels", c.cpsv_pixels as f64, 8.0, 1024.0)?;
    check("cook.cpsv_back_share", c.cpsv_back_share, 0.0, 1.0)?;
    check("cook.cpsv_inside_faces", c.cpsv_inside_faces as f64, 1.0, 6.0)?;
    check("cook.cpsv_votes", f64::from(c.cpsv_votes), 1.0, 1e6)?;
    check("cook.max_placed_triangles", c.max_placed_triangles as f64, 1.0, 1e10)?;
    check("eval.views", e.views as f64, 1.0, 4096.0)?;
    check(
        "level.batch_max_triangles",
        s.level.batch_max_triangles as f64,
        12.0,
        1e9,
    )?;
    check("level.batch_max_extent", s.level.batch_max_extent, 1e-6, 1e12)?;
    check("level.cull_cameras", s.level.cull_cameras as f64, 0.0, 256.0)?;
    check("level.eye_height", s.level.eye_height, 1e-6, 1e9)?;
    check("level.voxel_size", s.level.voxel_size, 0.0, 1e12)?;
    check("level.soup_cell_size", s.level.soup_cell_size, 0.0, 1e12)?;
    check("level.soup_triangle_share", s.level.soup_triangle_share, 1e-4, 1.0)?;
    check(
        "level.soup_cell_triangles",
        s.level.soup_cell_triangles as f64,
        1.0,
        1e9,
    )?;
    let v = &s.service;
    check("service.workers", v.workers as f64, 1.0, 256.0)?;
    check("service.max_body_bytes", v.max_body_bytes as f64, 1024.0, 4e9)?;
    check("service.max_resolution", v.max_resolution as f64, 4.0, 1024.0)?;
    check("service.max_quad_grid", v.max_quad_grid as f64, 8.0, 4096.0)?;
    check("service.job_timeout_s", v.job_timeout_s, 1.0, 86400.0)?;
    check("service.max_parse_bytes", v.max_parse_bytes as f64, 1048576.0, 1e13)?;
    check("service.token_submissions_per_s", v.token_submissions_per_s, 0.001, 1e6)?;
    check("service.token_submission_burst", v.token_submission_burst, 1.0, 1e6)?;
    check("service.max_queue", v.max_queue as f64, 1.0, 1e7)?;
    check("service.token_max_queued", v.token_max_queued as f64, 1.0, 1e7)?;
    check("service.job_retention_s", v.job_retention_s, 1.0, 1e9)?;
    check("service.sled_cache_bytes", v.sled_cache_bytes as f64, 1048576.0, 1e12)?;
    if v.tls_cert.is_empty() != v.tls_key.is_empty() {
        return Err(ConfigError::Invalid {
            key: if v.tls_cert.is_empty() {
                "service.tls_cert"
            } else {
                "service.tls_key"
            }
            .into(),
            message: "service.tls_cert and service.tls_key go together: set both for HTTPS, or neither".into(),
        });
    }
    let nats_sign_ins = [&v.nats_user, &v.nats_nkey_file, &v.nats_creds_file];
    if nats_sign_ins.iter().filter(|s| !s.is_empty()).count() > 1 {
        return Err(ConfigError::Invalid {
            key: "service.nats_user".into(),
            message: "choose one way to sign in to NATS: nats_user (with nats_password_file), nats_nkey_file or nats_creds_file".into(),
        });
    }
    if !v.nats_password_file.is_empty() && v.nats_user.is_empty() {
        return Err(ConfigError::Invalid {
            key: "service.nats_password_file".into(),
            message: "a NATS password needs service.nats_user".into(),
        });
    }
    check("service.ack_wait_s", v.ack_wait_s, 1.0, 86_400.0)?;
    check("service.max_deliver", v.max_deliver as f64, 1.0, 1000.0)?;
    if !(v.nats_url.is_empty() || v.nats_url.starts_with("nats://") || v.nats_url.starts_with("tls://")) {
        return Err(ConfigError::OutOfRange {
            key: "service.nats_url".into(),
            value: v.nats_url.clone(),
            range: "expected empty (sled) or a nats:// or tls:// URL".into(),
        });
    }
    if v.listen.parse::<std::net::SocketAddr>().is_err() {
        return Err(ConfigError::OutOfRange {
            key: "service.listen".into(),
            value: v.listen.clone(),
            range: "expected an address and port, e.g. 127.0.0.1:8650".into(),
        });
    }
    check("eval.pixels", e.pixels as f64, 16.0, 4096.0)?;
    check("eval.outside_samples", e.outside_samples as f64, 0.0, 10_000_000.0)?;
    Ok(())
}

fn is_zero(value: &f64) -> bool {
    *value == 0.0
}

fn check(key: &str, value: f64, lo: f64, hi: f64) -> Result<(), ConfigError> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(())
    } else {
        Err(ConfigError::OutOfRange {
            key: key.to_string(),
            value: value.to_string(),
            range: format!("expected {lo} to {hi}"),
        })
    }
}
