//! Whole levels: a manifest of placed meshes becomes a few merged occluder batches.
//!
//! Unique meshes are cooked once each, by key, through the same sled cache as the service, so a
//! rebake, or a level that shares meshes with one baked before, reuses them. Instances are then
//! placed and clustered spatially into batches ([`batch`]), and each batch is one glTF mesh.

pub mod batch;
pub mod cull;
pub mod free_space;
pub mod hidden;
pub mod preview;
pub mod soup;

use crate::config::Settings;
use crate::cook::cook_with_progress;
use crate::key::cache_key;
use crate::mesh::{Format, Mesh, glb, load_bytes, point_bounds};
use crate::store::{Input, ResultMeta, Store, StoreError, job::now_ms, patiently};
use batch::Placed;
use glam::{DMat4, DVec3, Vec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    #[serde(default)]
    pub name: String,
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub source: String,
    pub instances: Vec<InstanceSpec>,
}

#[derive(Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct InstanceSpec {
    /// A path relative to the manifest, or the key of a mesh cooked before.
    pub mesh: String,
    /// 4×4, column-major (glTF's convention).
    pub transform: Vec<f64>,
}

#[derive(Debug, thiserror::Error)]
pub enum LevelError {
    #[error("cannot read manifest {path}: {message}")]
    Read { path: String, message: String },
    #[error("manifest {path}: {message}")]
    Malformed { path: String, message: String },
    #[error("the level has no instances")]
    Empty,
    #[error(
        "instance {index}: mesh `{mesh}` not found (not a file next to the manifest, an uploaded part or a cached key)"
    )]
    MissingMesh { index: usize, mesh: String },
    #[error("instance {index}: bad transform: {why}")]
    BadTransform { index: usize, why: String },
    #[error("mesh {mesh}: {message}")]
    BadMesh { mesh: String, message: String },
    /// A cached result that cannot be read as an occluder.
    #[error("cache: {0}")]
    Cache(String),
    /// The store did not answer, within [`crate::store::PATIENCE`] where that is retried.
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error(transparent)]
    Cook(#[from] crate::cook::CookError),
}

/// A level with every instance checked: its mesh source and its matrix.
pub struct Level {
    pub name: String,
    pub instances: Vec<(MeshRef, DMat4)>,
    /// The meshes inside the level file itself (OBJ groups, glTF meshes), for [`MeshRef::Part`].
    pub parts: Vec<crate::mesh::Part>,
}

#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum MeshRef {
    File(PathBuf),
    Key(String),
    /// A mesh inside the level file itself: an OBJ group or a glTF mesh.
    Part(usize),
}

impl MeshRef {
    fn label(&self) -> String {
        match self {
            MeshRef::File(p) => p.display().to_string(),
            MeshRef::Key(k) => k.clone(),
            MeshRef::Part(p) => format!("part {p:06}"),
        }
    }
}

/// A level from a JSON manifest, an OBJ file whose groups are the instances, or a glTF or FBX
/// scene whose mesh nodes are the instances (a mesh placed by many nodes is one unique mesh).
pub fn load(path: &Path, limits: &crate::mesh::IngestLimits) -> Result<Level, LevelError> {
    let format = crate::mesh::Format::from_extension(path).ok();
    let Some(format) = format.filter(|f| matches!(f, Format::Obj | Format::Gltf | Format::Fbx)) else {
        return load_manifest(path);
    };
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| LevelError::Read {
        path: name.clone(),
        message: e.to_string(),
    })?;
    let bad = |e: crate::mesh::IngestError| LevelError::BadMesh {
        mesh: name.clone(),
        message: e.to_string(),
    };
    let (parts, instances) = if format == Format::Obj {
        let groups = crate::mesh::load_obj_groups(&bytes).map_err(bad)?;
        let instances = (0..groups.len()).map(|g| (MeshRef::Part(g), DMat4::IDENTITY)).collect();
        (groups, instances)
    } else {
        let (meshes, placements) = crate::mesh::load_instances(&bytes, format, path.parent(), limits).map_err(bad)?;
        let instances = placements
            .into_iter()
            .map(|(m, world)| (MeshRef::Part(m), world))
            .collect();
        (meshes, instances)
    };
    let level = Level {
        name: path.file_stem().unwrap_or_default().to_string_lossy().into_owned(),
        instances,
        parts,
    };
    if level.instances.is_empty() {
        return Err(LevelError::Empty);
    }
    for (index, (_, matrix)) in level.instances.iter().enumerate() {
        check_transform(matrix).map_err(|why| LevelError::BadTransform {
            index,
            why: why.to_string(),
        })?;
    }
    Ok(level)
}

/// Why a placement cannot be used, if it cannot.
fn check_transform(matrix: &DMat4) -> Result<(), &'static str> {
    if !matrix.is_finite() {
        return Err("not finite (NaN or infinity)");
    }
    if glam::DMat3::from_mat4(*matrix).determinant().abs() < 1e-12 {
        return Err("singular (it flattens the mesh)");
    }
    Ok(())
}

pub fn is_key(s: &str) -> bool {
    s.len() == 64 && s.bytes().all(|b| b.is_ascii_hexdigit())
}

/// Reads and checks a manifest: every mesh exists, every transform is finite and invertible.
/// A mesh is a file next to the manifest or, failing that, the key of a mesh cooked before.
pub fn load_manifest(path: &Path) -> Result<Level, LevelError> {
    let name = path.display().to_string();
    let text = std::fs::read(path).map_err(|e| LevelError::Read {
        path: name.clone(),
        message: e.to_string(),
    })?;
    let manifest = parse_manifest(&name, &text)?;
    let base = path.parent().unwrap_or(Path::new("."));
    Level::from_manifest(manifest, |mesh| {
        let file = base.join(mesh);
        if file.is_file() {
            Some(MeshRef::File(file))
        } else {
            is_key(mesh).then(|| MeshRef::Key(mesh.to_ascii_lowercase()))
        }
    })
}

/// A manifest from JSON; `name` says where it came from, for errors.
pub fn parse_manifest(name: &str, json: &[u8]) -> Result<Manifest, LevelError> {
    serde_json::from_slice(json).map_err(|e| LevelError::Malformed {
        path: name.to_string(),
        message: e.to_string(),
    })
}

impl Level {
    /// Checks every instance of `manifest`: `resolve` finds its mesh (or not), and its transform
    /// must be 16 finite numbers of an invertible matrix.
    pub fn from_manifest(manifest: Manifest, resolve: impl Fn(&str) -> Option<MeshRef>) -> Result<Level, LevelError> {
        if manifest.instances.is_empty() {
            return Err(LevelError::Empty);
        }
        let mut instances = Vec::with_capacity(manifest.instances.len());
        for (index, spec) in manifest.instances.iter().enumerate() {
            let mesh = resolve(&spec.mesh).ok_or_else(|| LevelError::MissingMesh {
                index,
                mesh: spec.mesh.clone(),
            })?;
            let bad = |why: &str| LevelError::BadTransform {
                index,
                why: why.to_string(),
            };
            let columns: [f64; 16] = spec
                .transform
                .as_slice()
                .try_into()
                .map_err(|_| bad(&format!("expected 16 numbers, got {}", spec.transform.len())))?;
            let matrix = DMat4::from_cols_array(&columns);
            check_transform(&matrix).map_err(bad)?;
            instances.push((mesh, matrix));
        }
        Ok(Level {
            name: manifest.name,
            instances,
            parts: Vec::new(),
        })
    }
}

/// The occluder of one unique mesh: its watertight solid and its double-sided panels.
struct Occluder {
    solid: Mesh,
    panels: Mesh,
    source_triangles: usize,
    source_primitives: usize,
}

impl Occluder {
    fn triangles(&self) -> usize {
        self.solid.triangles.len() + self.panels.triangles.len()
    }
}

#[derive(Debug, Serialize, Deserialize)]
pub struct BatchInfo {
    pub name: String,
    pub lo: [f64; 3],
    pub hi: [f64; 3],
    pub triangles: usize,
    /// Indices into the manifest's instances.
    pub instances: Vec<usize>,
}

#[derive(Debug, Serialize)]
pub struct LevelReport {
    pub name: String,
    pub instances: usize,
    pub unique_meshes: usize,
    pub cache_hits: usize,
    pub batches: usize,
    /// Placed source triangles.
    pub triangles_before: usize,
    /// Occluder triangles over all batches.
    pub triangles_after: usize,
    /// Triangles dropped where placed occluders meet face to face (counted out of `triangles_after`).
    pub hidden_triangles_removed: usize,
    /// One per primitive of each placed mesh.
    pub draw_calls_before: usize,
    pub draw_calls_after: usize,
    /// The bake's cull test of its own occluder (`level.cull_cameras`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cull: Option<cull::CullReport>,
    /// How a map cooked as one soup was cooked.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub soup: Option<soup::SoupInfo>,
    pub timings_ms: crate::cook::Timings,
    /// What was left out, and why.
    pub notes: Vec<String>,
}

pub struct Baked {
    pub glb: Vec<u8>,
    /// Meshes cooked and filed in the store by this bake: (key, bytes).
    pub stored: Vec<(String, u64)>,
    pub batches: Vec<BatchInfo>,
    pub report: LevelReport,
}

/// Cooks (or finds in `store`) every unique mesh, places the instances and merges them into
/// batches. `progress(done, total)` is told as unique meshes are ready; `halt` is asked before
/// each stage of each mesh's cook, and an error from it stops the bake (its meshes then end as
/// [`crate::cook::CookError::Stopped`]).
pub async fn bake(
    level: &Level,
    settings: &Settings,
    store: &dyn Store,
    progress: &(dyn Fn(usize, usize) + Sync),
    halt: crate::cook::Progress<'_>,
) -> Result<Baked, LevelError> {
    let mut timings = crate::cook::Timings::default();
    let started = Instant::now();
    let mut unique: Vec<&MeshRef> = level.instances.iter().map(|(m, _)| m).collect();
    unique.sort_by_key(|m| m.label());
    unique.dedup();
    let keyed = key_meshes(level, &unique, settings)?;
    timings
        .0
        .push(("read+key".into(), started.elapsed().as_secs_f64() * 1e3));

    let lookup = Instant::now();
    let (mut occluders, misses) = look_up(level, keyed, store, &settings.ingest_limits()).await?;
    let cache_hits = occluders.len();
    timings.0.push(("cache".into(), lookup.elapsed().as_secs_f64() * 1e3));
    progress(cache_hits, unique.len());

    let cooking = Instant::now();
    // Opened before the cooks, which run at once, so that each runs where it would alone in a
    // process that has it open ([`crate::gpu::for_cook`]); the cull test uses it after. A
    // failure to open is each cook's to report.
    if !misses.is_empty() {
        crate::gpu::for_choice(settings.cook.device).ok();
    }
    let done = std::sync::atomic::AtomicUsize::new(cache_hits);
    let cooked: Vec<_> = misses
        .into_par_iter()
        .map(|(m, key, (input, mesh, stats))| {
            let cooked = cook_with_progress(mesh, stats, 0.0, settings, false, halt);
            let finished = done.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1;
            progress(finished, unique.len());
            (m, key, input, cooked)
        })
        .collect();
    let mut stored = Vec::with_capacity(cooked.len());
    for (m, key, input, cooked) in cooked {
        let (occluder, bytes) = file_result(store, &key, &input, &cooked?).await?;
        stored.push((key, bytes));
        occluders.insert(m, occluder);
    }
    timings.0.push(("cook".into(), cooking.elapsed().as_secs_f64() * 1e3));

    let placing = Instant::now();
    let (glb, batches, hidden_triangles_removed) = place_and_batch(level, &occluders, settings);
    timings
        .0
        .push(("place+batch".into(), placing.elapsed().as_secs_f64() * 1e3));
    let mut notes = Vec::new();
    let cull = match settings.level.cull_cameras {
        0 => None,
        cameras => {
            let testing = Instant::now();
            let test = cull_test(level, store, &glb, settings, cameras).await;
            timings.0.push(("cull".into(), testing.elapsed().as_secs_f64() * 1e3));
            test.map_err(|e| notes.push(format!("no cull test: {e}"))).ok()
        }
    };
    let report = LevelReport {
        name: level.name.clone(),
        instances: level.instances.len(),
        unique_meshes: unique.len(),
        cache_hits,
        batches: batches.len(),
        triangles_before: level.instances.iter().map(|(m, _)| occluders[m].source_triangles).sum(),
        triangles_after: batches.iter().map(|b| b.triangles).sum(),
        hidden_triangles_removed,
        draw_calls_before: level
            .instances
            .iter()
            .map(|(m, _)| occluders[m].source_primitives)
            .sum(),
        draw_calls_after: batches.len(),
        cull,
        soup: None,
        timings_ms: timings,
        notes,
    };
    Ok(Baked {
        glb,
        stored,
        batches,
        report,
    })
}

/// The level's cull test of `glb`, its occluder, from `cameras` cameras.
async fn cull_test(
    level: &Level,
    store: &dyn Store,
    glb: &[u8],
    settings: &Settings,
    cameras: usize,
) -> Result<cull::CullReport, String> {
    let meshes = placed_meshes(level, store, &settings.ingest_limits()).await?;
    let occluder = occluder_mesh(glb)?;
    let gpu = crate::gpu::for_choice(settings.cook.device).ok().and_then(|p| p.gpu);
    cull::cull_eval(level, &meshes, &occluder, cameras, preview::CULL_PIXELS, gpu.as_deref())
}

/// Every unique mesh the level places: files read again, parts from the level, and keys from
/// the uploads `store` keeps.
pub async fn placed_meshes<'a>(
    level: &'a Level,
    store: &dyn Store,
    limits: &crate::mesh::IngestLimits,
) -> Result<HashMap<&'a MeshRef, Mesh>, String> {
    let mut keyed = HashMap::new();
    for (m, _) in &level.instances {
        let MeshRef::Key(key) = m else { continue };
        if keyed.contains_key(key) {
            continue;
        }
        let input = store.input(key).await.map_err(|e| e.to_string())?;
        let input = input.ok_or_else(|| format!("the upload of mesh {key} is no longer kept"))?;
        let (mesh, _) = input.load(limits).map_err(|e| format!("mesh {key}: {e}"))?;
        keyed.insert(key.clone(), mesh);
    }
    cull::load_meshes(level, &keyed)
}

/// A level's occluder GLB as one mesh, every batch's solid and panels together.
pub fn occluder_mesh(glb: &[u8]) -> Result<Mesh, String> {
    let parts = glb::read_parts(glb).map_err(|e| format!("the level's occluder: {e}"))?;
    let mut occluder = Mesh::default();
    for (_, mesh) in parts {
        occluder.append(&mesh);
    }
    Ok(occluder)
}

/// What a mesh is cooked from when its result is not cached: its input as stored, the mesh and
/// its ingest figures.
type Source = (Input, Mesh, crate::mesh::IngestStats);

/// Each unique mesh with its key, and its source where the level holds one (files and parts
/// are read and keyed in parallel).
fn key_meshes(
    level: &Level,
    unique: &[&MeshRef],
    settings: &Settings,
) -> Result<Vec<(MeshRef, String, Option<Source>)>, LevelError> {
    unique
        .par_iter()
        .map(|m| match m {
            MeshRef::Key(k) => Ok(((*m).clone(), k.clone(), None)),
            MeshRef::Part(p) => {
                let (_, mesh, stats) = &level.parts[*p];
                // Kept as OBJ text, to cook it again should its result break.
                let input = Input {
                    format: "obj".into(),
                    bytes: obj_text(mesh),
                };
                Ok((
                    (*m).clone(),
                    cache_key(mesh, &settings.cook),
                    Some((input, mesh.clone(), stats.clone())),
                ))
            }
            MeshRef::File(path) => {
                let bad = |message: String| LevelError::BadMesh {
                    mesh: path.display().to_string(),
                    message,
                };
                let format = Format::from_extension(path).map_err(|e| bad(e.to_string()))?;
                let bytes = std::fs::read(path).map_err(|e| bad(e.to_string()))?;
                let (mesh, stats) = load_bytes(&bytes, format, path.parent(), &settings.ingest_limits())
                    .map_err(|e| bad(e.to_string()))?;
                let key = cache_key(&mesh, &settings.cook);
                let input = Input {
                    format: format.name().into(),
                    bytes,
                };
                Ok(((*m).clone(), key, Some((input, mesh, stats))))
            }
        })
        .collect()
}

/// The occluders `store` has already, and the meshes to cook: from the level's own source, or
/// from the upload kept under a key that has no result yet.
async fn look_up(
    level: &Level,
    keyed: Vec<(MeshRef, String, Option<Source>)>,
    store: &dyn Store,
    limits: &crate::mesh::IngestLimits,
) -> Result<(HashMap<MeshRef, Occluder>, Vec<(MeshRef, String, Source)>), LevelError> {
    let mut occluders = HashMap::new();
    let mut misses = Vec::new();
    for (m, key, source) in keyed {
        if let Some(bytes) = patiently("read the cached result", &key, || store.result_glb(&key)).await? {
            let report = patiently("read the cached report", &key, || store.result_report(&key)).await?;
            occluders.insert(m, occluder_from_glb(&key, &bytes, report.as_deref())?);
            continue;
        }
        let source = match source {
            Some(source) => source,
            None => match patiently("read the uploaded mesh", &key, || store.input(&key)).await? {
                Some(input) => {
                    let (mesh, stats) = input.load(limits).map_err(|e| LevelError::BadMesh {
                        mesh: key.clone(),
                        message: e.to_string(),
                    })?;
                    (input, mesh, stats)
                }
                None => {
                    let index = level.instances.iter().position(|(r, _)| *r == m).unwrap_or(0);
                    return Err(LevelError::MissingMesh { index, mesh: key });
                }
            },
        };
        misses.push((m, key, source));
    }
    Ok((occluders, misses))
}

/// Files a cooked mesh's input and result under `key`, as the service would; returns its
/// occluder and the bytes stored.
async fn file_result(
    store: &dyn Store,
    key: &str,
    input: &Input,
    cooked: &crate::cook::Cooked,
) -> Result<(Occluder, u64), LevelError> {
    let glb = cooked.glb();
    let report = serde_json::to_vec_pretty(&cooked.report).expect("reports serialize");
    patiently("store the mesh", key, || store.put_input(key, input)).await?;
    let meta = ResultMeta {
        job: "level".into(),
        bytes: (glb.len() + report.len() + input.encode().len()) as u64,
        created_ms: now_ms(),
    };
    patiently("store the result", key, || store.put_result(key, &glb, &report, &meta)).await?;
    Ok((occluder_from_glb(key, &glb, Some(&report))?, meta.bytes))
}

/// Places every instance's occluder, clusters them into batches and writes the level's GLB, a
/// node per batch. Returns the GLB, the batches and the triangles dropped between touching
/// occluders.
fn place_and_batch(
    level: &Level,
    occluders: &HashMap<MeshRef, Occluder>,
    settings: &Settings,
) -> (Vec<u8>, Vec<BatchInfo>, usize) {
    let placed: Vec<Placed> = level
        .instances
        .iter()
        .map(|(m, matrix)| {
            let o = &occluders[m];
            let (lo, hi) = transformed_bounds(&o.solid, &o.panels, matrix);
            Placed {
                lo,
                hi,
                triangles: o.triangles(),
            }
        })
        .collect();
    // An instance whose occluder is empty draws nothing, so it joins no batch.
    let occluding: Vec<usize> = (0..placed.len()).filter(|&i| placed[i].triangles > 0).collect();
    let subset: Vec<Placed> = occluding.iter().map(|&i| placed[i]).collect();
    let groups: Vec<Vec<usize>> = batch::cluster(
        &subset,
        settings.level.batch_max_triangles,
        settings.level.batch_max_extent,
    )
    .into_iter()
    .map(|group| group.into_iter().map(|j| occluding[j]).collect())
    .collect();
    let merged: Vec<(Mesh, Mesh, usize)> = groups
        .par_iter()
        .map(|group| {
            let (mut solid, mut panels) = (Mesh::default(), Mesh::default());
            for &i in group {
                let (m, matrix) = &level.instances[i];
                let o = &occluders[m];
                solid.append(&transformed(&o.solid, matrix));
                panels.append(&transformed(&o.panels, matrix));
            }
            let hidden = hidden::remove_hidden_faces(&mut solid);
            (solid, panels, hidden)
        })
        .collect();
    let hidden_triangles_removed = merged.iter().map(|m| m.2).sum();
    let mut batches = Vec::with_capacity(groups.len());
    let mut nodes = Vec::with_capacity(groups.len());
    for (b, (group, (solid, panels, _))) in groups.iter().zip(&merged).enumerate() {
        let (lo, hi) = point_bounds(group.iter().flat_map(|&i| [placed[i].lo, placed[i].hi]));
        let info = BatchInfo {
            name: format!("batch-{b}"),
            lo: lo.to_array(),
            hi: hi.to_array(),
            triangles: solid.triangles.len() + panels.triangles.len(),
            instances: group.clone(),
        };
        nodes.push(glb::Node {
            name: info.name.clone(),
            parts: vec![
                glb::Part {
                    name: crate::occluder::SOLID_PART,
                    mesh: solid,
                    double_sided: false,
                },
                glb::Part {
                    name: crate::occluder::PANELS_PART,
                    mesh: panels,
                    double_sided: true,
                },
            ],
            extras: serde_json::json!({ "bounds": { "min": info.lo, "max": info.hi }, "triangles": info.triangles,
                "instances": info.instances.len() }),
        });
        batches.push(info);
    }
    (glb::write_scene(&nodes), batches, hidden_triangles_removed)
}

/// A cached occluder's parts, with the source's size from its report.
fn occluder_from_glb(key: &str, glb: &[u8], report: Option<&[u8]>) -> Result<Occluder, LevelError> {
    let parts = glb::read_parts(glb).map_err(|e| LevelError::Cache(format!("result {key}: {e}")))?;
    let (mut solid, mut panels) = (Mesh::default(), Mesh::default());
    for (name, mesh) in parts {
        if name == crate::occluder::PANELS_PART {
            panels.append(&mesh);
        } else {
            solid.append(&mesh);
        }
    }
    let report: serde_json::Value = report.and_then(|r| serde_json::from_slice(r).ok()).unwrap_or_default();
    Ok(Occluder {
        solid,
        panels,
        source_triangles: report["input"]["triangles"].as_u64().unwrap_or(0) as usize,
        source_primitives: report["input"]["primitives"].as_u64().unwrap_or(1).max(1) as usize,
    })
}

fn obj_text(mesh: &Mesh) -> Vec<u8> {
    use std::fmt::Write;
    let mut text = String::new();
    for p in &mesh.positions {
        let _ = writeln!(text, "v {} {} {}", p.x, p.y, p.z);
    }
    for t in &mesh.triangles {
        let _ = writeln!(text, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    text.into_bytes()
}

fn transformed(mesh: &Mesh, matrix: &DMat4) -> Mesh {
    let flip = glam::DMat3::from_mat4(*matrix).determinant() < 0.0;
    Mesh {
        positions: mesh
            .positions
            .iter()
            .map(|p| matrix.transform_point3(p.as_dvec3()).as_vec3())
            .collect(),
        // A mirroring transform turns faces inside out; swapping two corners turns them back.
        triangles: mesh
            .triangles
            .iter()
            .map(|&[a, b, c]| if flip { [a, c, b] } else { [a, b, c] })
            .collect(),
    }
}

fn transformed_bounds(solid: &Mesh, panels: &Mesh, matrix: &DMat4) -> (DVec3, DVec3) {
    point_bounds(
        solid
            .positions
            .iter()
            .chain(&panels.positions)
            .map(|p: &Vec3| matrix.transform_point3(p.as_dvec3())),
    )
}
