//! glTF 2.0 (.gltf and .glb): every triangle primitive of the default scene, in world space.

use super::{IngestError, RawMesh};
use base64::Engine;
use glam::{Mat4, Vec3};
use gltf::mesh::Mode;
use std::path::Path;

const FORMAT: &str = "glTF";
/// Compressed geometry with no dependable Rust decoder; gltf-transform writes it out plain.
const DRACO: &str = "KHR_draco_mesh_compression";

pub fn read(bytes: &[u8], base_dir: Option<&Path>) -> Result<RawMesh, IngestError> {
    let invalid = match parse(bytes)? {
        Ok(gltf) => return read_scene(&gltf, base_dir),
        Err(invalid) => invalid,
    };
    // The reader may panic on an invalid document, so it runs guarded.
    let lenient = gltf::Gltf::from_slice_without_validation(bytes).ok();
    let read_guarded = |gltf: &gltf::Gltf| std::panic::catch_unwind(|| read_scene(gltf, base_dir)).ok();
    if let Some(gltf) = &lenient
        && let Some(warning) = appearance_ignored(&invalid, gltf)
        && let Some(read) = read_guarded(gltf)
    {
        let mut raw = read?;
        raw.warnings.push(warning);
        return Ok(raw);
    }
    // Say what is really wrong where the geometry can still be read (infinite coordinates make
    // min/max invalid, for one).
    let geometry = lenient
        .as_ref()
        .and_then(read_guarded)
        .map(|read| read.and_then(super::weld));
    Err(match geometry {
        Some(Err(
            e @ (IngestError::NonFinite(..) | IngestError::IndexOutOfRange { .. } | IngestError::NodeCycle(_)),
        )) => e,
        _ => IngestError::malformed(FORMAT, first_problem(&invalid)),
    })
}

/// Where every problem of `gltf` (its unvalidated document) lies in textures, images, samplers
/// or materials, or is a required extension that touches only those, a warning naming those
/// extensions: the geometry reads as if they were absent.
fn appearance_ignored(invalid: &gltf::Error, gltf: &gltf::Gltf) -> Option<String> {
    let gltf::Error::Validation(problems) = invalid else {
        return None;
    };
    let required: Vec<&str> = gltf.extensions_required().collect();
    let mut ignored = Vec::new();
    for (path, _) in problems {
        let path = path.as_str();
        // "extensionsRequired[0] = \"NAME\"".
        if let Some((index, _)) = path
            .strip_prefix("extensionsRequired[")
            .and_then(|rest| rest.split_once(']'))
        {
            let name = required.get(index.parse::<usize>().ok()?)?;
            if !(name.contains("_texture_") || name.contains("_materials_")) {
                return None;
            }
            ignored.push(name.to_string());
        } else if !["textures", "images", "samplers", "materials"]
            .iter()
            .any(|appearance| path.starts_with(appearance))
        {
            return None;
        }
    }
    (!ignored.is_empty()).then(|| {
        format!(
            "ignored {}: it touches only textures or materials, which an occluder does not use",
            ignored.join(", ")
        )
    })
}

/// The document parsed and validated. The validator indexes arrays a malformed file declares,
/// and may panic on one: that is an error in the file, not a crash.
pub(super) fn parse(bytes: &[u8]) -> Result<Result<gltf::Gltf, gltf::Error>, IngestError> {
    std::panic::catch_unwind(|| gltf::Gltf::from_slice(bytes))
        .map_err(|_| IngestError::malformed(FORMAT, "an index or count in the document points outside it"))
}

/// A validation failure as its first problem and how many more there are. A required extension
/// we cannot read comes first: it is why the rest fails (accessors with no data, for one).
pub(super) fn first_problem(error: &gltf::Error) -> String {
    let gltf::Error::Validation(problems) = error else {
        return error.to_string();
    };
    let required = problems
        .iter()
        .find(|(path, _)| path.as_str().starts_with("extensionsRequired"));
    let Some((path, problem)) = required.or(problems.first()) else {
        return error.to_string();
    };
    let first = match path.as_str().contains(DRACO) {
        true => format!("requires {DRACO}, which is not decoded: run `gltf-transform decompress` on it first"),
        false => format!("{path}: {problem}"),
    };
    match problems.len() {
        1 => first,
        n => format!("{first} (and {} more problems)", n - 1),
    }
}

fn read_scene(gltf: &gltf::Gltf, base_dir: Option<&Path>) -> Result<RawMesh, IngestError> {
    let buffers = load_buffers(gltf, base_dir)?;
    let mut raw = RawMesh::default();
    walk_scene(gltf, &mut |mesh, world| read_mesh(&mesh, world, &buffers, &mut raw))?;
    Ok(raw)
}

/// A glTF scene as a level: each mesh once, in its own space, with its name, and each node that
/// places a mesh as (mesh index, world transform).
pub fn read_instances(bytes: &[u8], base_dir: Option<&Path>) -> Result<Instances, IngestError> {
    let gltf = match parse(bytes)? {
        Ok(gltf) => gltf,
        Err(invalid) => {
            // As in `read`: an invalid appearance does not block the geometry.
            let lenient = gltf::Gltf::from_slice_without_validation(bytes).ok();
            match lenient.and_then(|gltf| Some((appearance_ignored(&invalid, &gltf)?, gltf))) {
                Some((warning, gltf)) => {
                    tracing::warn!("{warning}");
                    gltf
                }
                None => return Err(IngestError::malformed(FORMAT, first_problem(&invalid))),
            }
        }
    };
    let buffers = load_buffers(&gltf, base_dir)?;
    let mut placements = Vec::new();
    walk_scene(&gltf, &mut |mesh, world| {
        placements.push((mesh.index(), world));
        Ok(())
    })?;
    let meshes = gltf
        .meshes()
        .map(|mesh| {
            let mut raw = RawMesh::default();
            read_mesh(&mesh, Mat4::IDENTITY, &buffers, &mut raw)?;
            let name = mesh
                .name()
                .map_or_else(|| format!("mesh {}", mesh.index()), str::to_string);
            Ok((name, raw))
        })
        .collect::<Result<_, IngestError>>()?;
    Ok(Instances { meshes, placements })
}

/// What [`read_instances`] finds.
pub struct Instances {
    pub meshes: Vec<(String, RawMesh)>,
    pub placements: Vec<(usize, Mat4)>,
}

/// Calls `found(mesh, world transform)` for every node of the default scene that has a mesh.
fn walk_scene(
    gltf: &gltf::Gltf,
    found: &mut dyn FnMut(gltf::Mesh, Mat4) -> Result<(), IngestError>,
) -> Result<(), IngestError> {
    let scene = gltf
        .default_scene()
        .or_else(|| gltf.scenes().next())
        .ok_or_else(|| IngestError::malformed(FORMAT, "the file has no scene"))?;
    let mut path = Vec::new();
    for node in scene.nodes() {
        visit(&node, Mat4::IDENTITY, &mut path, found)?;
    }
    Ok(())
}

fn load_buffers(gltf: &gltf::Gltf, base_dir: Option<&Path>) -> Result<Vec<Vec<u8>>, IngestError> {
    gltf.buffers()
        .map(|buffer| {
            let data = match buffer.source() {
                gltf::buffer::Source::Bin => gltf
                    .blob
                    .clone()
                    .ok_or_else(|| IngestError::malformed(FORMAT, "the GLB has no binary chunk"))?,
                gltf::buffer::Source::Uri(uri) => read_uri(uri, base_dir)?,
            };
            if data.len() < buffer.length() {
                return Err(IngestError::malformed(
                    FORMAT,
                    format!(
                        "buffer {} holds {} bytes but declares {} (truncated file?)",
                        buffer.index(),
                        data.len(),
                        buffer.length()
                    ),
                ));
            }
            Ok(data)
        })
        .collect()
}

fn read_uri(uri: &str, base_dir: Option<&Path>) -> Result<Vec<u8>, IngestError> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (_, payload) = rest
            .split_once(";base64,")
            .ok_or_else(|| IngestError::malformed(FORMAT, "data URI is not base64"))?;
        return base64::engine::general_purpose::STANDARD
            .decode(payload)
            .map_err(|e| IngestError::malformed(FORMAT, format!("bad base64 in data URI: {e}")));
    }
    let dir = base_dir.ok_or_else(|| {
        IngestError::malformed(
            FORMAT,
            format!("external buffer '{uri}' cannot be resolved: send a .glb or embed buffers as data URIs"),
        )
    })?;
    let decoded =
        urlencoding::decode(uri).map_err(|e| IngestError::malformed(FORMAT, format!("bad buffer URI '{uri}': {e}")))?;
    let relative = Path::new(decoded.as_ref());
    if relative.is_absolute() || relative.components().any(|c| c == std::path::Component::ParentDir) {
        return Err(IngestError::malformed(
            FORMAT,
            format!("buffer URI '{uri}' leaves the file's folder"),
        ));
    }
    let path = dir.join(relative);
    std::fs::read(&path).map_err(|source| IngestError::Io {
        path: path.display().to_string(),
        source,
    })
}

fn visit(
    node: &gltf::Node,
    parent: Mat4,
    path: &mut Vec<usize>,
    found: &mut dyn FnMut(gltf::Mesh, Mat4) -> Result<(), IngestError>,
) -> Result<(), IngestError> {
    if path.contains(&node.index()) {
        return Err(IngestError::NodeCycle(node.index()));
    }
    let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
    if let Some(mesh) = node.mesh() {
        found(mesh, world)?;
    }
    path.push(node.index());
    for child in node.children() {
        visit(&child, world, path, found)?;
    }
    path.pop();
    Ok(())
}

fn read_mesh(mesh: &gltf::Mesh, world: Mat4, buffers: &[Vec<u8>], raw: &mut RawMesh) -> Result<(), IngestError> {
    for primitive in mesh.primitives() {
        read_primitive(&primitive, world, buffers, raw)?;
    }
    Ok(())
}

fn read_primitive(
    primitive: &gltf::Primitive,
    world: Mat4,
    buffers: &[Vec<u8>],
    raw: &mut RawMesh,
) -> Result<(), IngestError> {
    let mode = primitive.mode();
    if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
        raw.skipped_primitives += 1;
        raw.warnings
            .push(format!("skipped a {mode:?} primitive: only triangles have a surface"));
        return Ok(());
    }
    let reader = primitive.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
    let out_of_buffer = || IngestError::malformed(FORMAT, "an accessor reaches past the end of its buffer");
    let positions: Vec<Vec3> = reader
        .read_positions()
        .ok_or_else(out_of_buffer)?
        .map(|p| world.transform_point3(Vec3::from(p)))
        .collect();
    let indices: Vec<u64> = match reader.read_indices() {
        Some(indices) => indices.into_u32().map(u64::from).collect(),
        None if primitive.indices().is_some() => return Err(out_of_buffer()),
        None => (0..positions.len() as u64).collect(),
    };
    // A mirroring transform flips the winding; keep faces facing the way they were authored.
    let flip = world.determinant() < 0.0;
    let ordered = |[a, b, c]: [u64; 3]| if flip { [a, c, b] } else { [a, b, c] };
    let triangles: Vec<[u64; 3]> = match mode {
        Mode::Triangles => indices.chunks_exact(3).map(|t| ordered([t[0], t[1], t[2]])).collect(),
        Mode::TriangleStrip => (2..indices.len())
            .map(|i| {
                let (a, b, c) = (indices[i - 2], indices[i - 1], indices[i]);
                ordered(if i % 2 == 0 { [a, b, c] } else { [b, a, c] })
            })
            .collect(),
        _ => (2..indices.len())
            .map(|i| ordered([indices[0], indices[i - 1], indices[i]]))
            .collect(),
    };
    raw.append(&positions, triangles)
}
