//! glTF 2.0 (.gltf and .glb): every triangle primitive of the default scene, in world space.

use super::gltf_meshopt as meshopt;
use super::{IngestError, IngestLimits, Instances, RawMesh};
use base64::Engine;
use glam::{Mat4, Vec3};
use gltf::mesh::Mode;
use std::path::Path;

const FORMAT: &str = "glTF";
/// Compressed geometry with no dependable Rust decoder; gltf-transform writes it out plain.
const DRACO: &str = "KHR_draco_mesh_compression";

pub fn read(bytes: &[u8], base_dir: Option<&Path>, limits: &IngestLimits) -> Result<RawMesh, IngestError> {
    let (invalid, lenient) = match document(bytes)? {
        Document::Readable(gltf, warning) => {
            let mut raw = read_guarded(&gltf, base_dir, limits)?;
            raw.warnings.extend(warning);
            return Ok(raw);
        }
        Document::Invalid(invalid, lenient) => (invalid, lenient),
    };
    // Say what is really wrong where the geometry can still be read (infinite coordinates make
    // min/max invalid, for one).
    let geometry = lenient
        .as_ref()
        .map(|gltf| read_guarded(gltf, base_dir, limits).and_then(super::weld));
    Err(match geometry {
        Some(Err(
            e @ (IngestError::NonFinite(..)
            | IngestError::FarVertex(..)
            | IngestError::TooSmall(_)
            | IngestError::IndexOutOfRange { .. }
            | IngestError::NodeCycle(_)
            | IngestError::TooLarge(_)),
        )) => e,
        _ => IngestError::malformed(FORMAT, first_problem(&invalid)),
    })
}

/// A document as the readers take it.
enum Document {
    /// Valid, or with problems only where [`ignorable`] looks past them; with the warning that
    /// names the extensions ignored.
    Readable(gltf::Gltf, Option<String>),
    /// Why it is invalid, and the document parsed without validation where it parses.
    Invalid(gltf::Error, Option<gltf::Gltf>),
}

/// The document validated, or parsed without validation where every problem can be read past.
fn document(bytes: &[u8]) -> Result<Document, IngestError> {
    let invalid = match parse(bytes)? {
        Ok(gltf) => return Ok(Document::Readable(gltf, None)),
        Err(invalid) => invalid,
    };
    Ok(match gltf::Gltf::from_slice_without_validation(bytes).ok() {
        Some(gltf) => match ignorable(&invalid, &gltf) {
            Some(ignored) => Document::Readable(gltf, ignored_warning(&ignored)),
            None => Document::Invalid(invalid, Some(gltf)),
        },
        None => Document::Invalid(invalid, None),
    })
}

const QUANTIZATION: &str = "KHR_mesh_quantization";
/// Geometry extensions this reader decodes, which the validator does not know.
const DECODED: [&str; 2] = [QUANTIZATION, meshopt::EXTENSION];

/// Where every problem of `gltf` (its unvalidated document) lies in textures, images, samplers
/// or materials, or is a required extension that touches only those or that we decode, the
/// extensions ignored: the geometry reads as if they were absent.
fn ignorable(invalid: &gltf::Error, gltf: &gltf::Gltf) -> Option<Vec<String>> {
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
            let name = *required.get(index.parse::<usize>().ok()?)?;
            if DECODED.contains(&name) {
                continue;
            }
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
    Some(ignored)
}

/// The warning that names the extensions ignored, if any were.
fn ignored_warning(ignored: &[String]) -> Option<String> {
    (!ignored.is_empty()).then(|| {
        format!(
            "ignored {}: it touches only textures or materials, which an occluder does not use",
            ignored.join(", ")
        )
    })
}

/// The reader indexes what a document declares, and may panic on an unvalidated one: that is an
/// error in the file, not a crash.
fn guarded<T>(read: impl FnOnce() -> Result<T, IngestError>) -> Result<T, IngestError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(read)).unwrap_or_else(|_| {
        Err(IngestError::malformed(
            FORMAT,
            "an accessor or view points outside its data",
        ))
    })
}

fn read_guarded(gltf: &gltf::Gltf, base_dir: Option<&Path>, limits: &IngestLimits) -> Result<RawMesh, IngestError> {
    guarded(|| read_scene(gltf, base_dir, limits))
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

fn read_scene(gltf: &gltf::Gltf, base_dir: Option<&Path>, limits: &IngestLimits) -> Result<RawMesh, IngestError> {
    let source = Source::open(gltf, base_dir, limits)?;
    let mut raw = RawMesh::default();
    walk_scene(&source.document, limits, &mut |mesh, world| {
        source.read_mesh(&mesh, world, &mut raw)
    })?;
    Ok(raw)
}

/// What primitives are read from: the document with its compressed views decoded, the buffers'
/// bytes, and how.
struct Source<'a> {
    /// Borrowed from the file, or rewritten where compressed views were decoded.
    document: std::borrow::Cow<'a, gltf::Document>,
    buffers: Vec<Vec<u8>>,
    limits: &'a IngestLimits,
    /// KHR_mesh_quantization: positions may be integers.
    quantized: bool,
}

impl<'a> Source<'a> {
    fn open(
        gltf: &'a gltf::Gltf,
        base_dir: Option<&Path>,
        limits: &'a IngestLimits,
    ) -> Result<Source<'a>, IngestError> {
        use std::borrow::Cow;
        let mut buffers = load_buffers(gltf, base_dir)?;
        let uses = |name: &str| gltf.extensions_used().any(|e| e == name);
        let document = match uses(meshopt::EXTENSION) {
            true => Cow::Owned(meshopt::decode(gltf.document.clone(), &mut buffers, limits)?),
            false => Cow::Borrowed(&gltf.document),
        };
        Ok(Source {
            quantized: uses(QUANTIZATION),
            document,
            buffers,
            limits,
        })
    }
}

/// A glTF scene as a level: each mesh once, in its own space, with its name, and each node that
/// places a mesh as (mesh index, world transform).
pub fn read_instances(bytes: &[u8], base_dir: Option<&Path>, limits: &IngestLimits) -> Result<Instances, IngestError> {
    let (gltf, warning) = match document(bytes)? {
        Document::Readable(gltf, warning) => (gltf, warning),
        Document::Invalid(invalid, _) => return Err(IngestError::malformed(FORMAT, first_problem(&invalid))),
    };
    if let Some(warning) = warning {
        tracing::warn!("{warning}");
    }
    guarded(|| placed_meshes(&gltf, base_dir, limits))
}

/// Each mesh the scene places, read once in its own space, and the placements.
fn placed_meshes(gltf: &gltf::Gltf, base_dir: Option<&Path>, limits: &IngestLimits) -> Result<Instances, IngestError> {
    let source = Source::open(gltf, base_dir, limits)?;
    // Meshes are numbered in the order the scene first places them; unplaced ones are not read.
    let mut slots = vec![None; source.document.meshes().len()];
    let mut placed = Vec::new();
    let mut placements = Vec::new();
    walk_scene(&source.document, limits, &mut |mesh, world| {
        let slot = slots[mesh.index()].get_or_insert_with(|| {
            placed.push(mesh.index());
            placed.len() - 1
        });
        placements.push((*slot, world));
        Ok(())
    })?;
    let all: Vec<gltf::Mesh> = source.document.meshes().collect();
    let meshes = placed
        .iter()
        .map(|&index| {
            let mesh = &all[index];
            let mut raw = RawMesh::default();
            source.read_mesh(mesh, Mat4::IDENTITY, &mut raw)?;
            let name = mesh
                .name()
                .map_or_else(|| format!("mesh {}", mesh.index()), str::to_string);
            Ok((name, raw))
        })
        .collect::<Result<_, IngestError>>()?;
    Ok(Instances { meshes, placements })
}

/// Calls `found(mesh, world transform)` for every node of the default scene that has a mesh,
/// once the scene is known to be acyclic and to place no more than `limits` allow.
fn walk_scene(
    gltf: &gltf::Document,
    limits: &IngestLimits,
    found: &mut dyn FnMut(gltf::Mesh, Mat4) -> Result<(), IngestError>,
) -> Result<(), IngestError> {
    let scene = gltf
        .default_scene()
        .or_else(|| gltf.scenes().next())
        .ok_or_else(|| IngestError::malformed(FORMAT, "the file has no scene"))?;
    let nodes: Vec<gltf::Node> = gltf.nodes().collect();
    let roots: Vec<usize> = scene.nodes().map(|n| n.index()).collect();
    let (visits, triangles) = placed_counts(&nodes, &roots)?;
    limits.check_placed(triangles, "triangles")?;
    // Each visit multiplies a matrix: a graph of empty nodes reused many times costs time too.
    limits.check_placed(visits, "node visits")?;
    // Depth first with an explicit stack: a chain of nodes deeper than the thread's stack is valid.
    let mut stack: Vec<(usize, Mat4)> = roots.iter().rev().map(|&n| (n, Mat4::IDENTITY)).collect();
    while let Some((index, parent)) = stack.pop() {
        let node = &nodes[index];
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        if let Some(mesh) = node.mesh() {
            found(mesh, world)?;
        }
        stack.extend(
            node.children()
                .collect::<Vec<_>>()
                .iter()
                .rev()
                .map(|c| (c.index(), world)),
        );
    }
    Ok(())
}

/// The nodes a scene visits and the triangles it places, from each node's own counts and its
/// children's, without expanding the graph: a node with several parents, or one listed many
/// times, multiplies both. Fails on a cycle.
fn placed_counts(nodes: &[gltf::Node], roots: &[usize]) -> Result<(u64, u64), IngestError> {
    let mut counts: Vec<Option<(u64, u64)>> = vec![None; nodes.len()];
    let mut on_path = vec![false; nodes.len()];
    // (node, whether its children are counted): post-order with an explicit stack.
    let mut stack: Vec<(usize, bool)> = roots.iter().map(|&n| (n, false)).collect();
    while let Some((index, children_done)) = stack.pop() {
        let node = &nodes[index];
        if children_done {
            on_path[index] = false;
            let own = node.mesh().map_or(0, |mesh| mesh_triangles(&mesh));
            let (visits, triangles) = node
                .children()
                .filter_map(|c| counts[c.index()])
                .fold((1u64, own), |(v, t), (cv, ct)| {
                    (v.saturating_add(cv), t.saturating_add(ct))
                });
            counts[index] = Some((visits, triangles));
            continue;
        }
        if counts[index].is_some() {
            continue;
        }
        if on_path[index] {
            return Err(IngestError::NodeCycle(index));
        }
        on_path[index] = true;
        stack.push((index, true));
        stack.extend(node.children().map(|c| (c.index(), false)));
    }
    Ok(roots
        .iter()
        .filter_map(|&r| counts[r])
        .fold((0, 0), |(v, t), (rv, rt)| (v.saturating_add(rv), t.saturating_add(rt))))
}

/// The triangles a mesh declares, from its accessors' counts, before anything is read.
fn mesh_triangles(mesh: &gltf::Mesh) -> u64 {
    mesh.primitives()
        .map(|primitive| {
            let corners = primitive
                .indices()
                .or_else(|| primitive.get(&gltf::Semantic::Positions))
                .map_or(0, |a| a.count() as u64);
            match primitive.mode() {
                Mode::Triangles => corners / 3,
                Mode::TriangleStrip | Mode::TriangleFan => corners.saturating_sub(2),
                _ => 0,
            }
        })
        .fold(0, u64::saturating_add)
}

fn load_buffers(gltf: &gltf::Gltf, base_dir: Option<&Path>) -> Result<Vec<Vec<u8>>, IngestError> {
    gltf.buffers()
        .map(|buffer| {
            if meshopt::is_fallback(&buffer) {
                return Ok(Vec::new());
            }
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
    std::fs::read(&path).map_err(|reason| IngestError::Io {
        path: path.display().to_string(),
        reason,
    })
}

impl Source<'_> {
    fn read_mesh(&self, mesh: &gltf::Mesh, world: Mat4, raw: &mut RawMesh) -> Result<(), IngestError> {
        for primitive in mesh.primitives() {
            self.read_primitive(&primitive, world, raw)?;
        }
        Ok(())
    }

    /// Whether a triangle primitive has anything to read, after refusing accessors the reader
    /// would misread or panic on: positions that are not float VEC3 (or, with
    /// KHR_mesh_quantization, 8- or 16-bit integer VEC3), indices that are not unsigned integer
    /// scalars, and items that no bytes back (sparse, with no bufferView: every item not
    /// substituted is zero) past what the limits allow.
    fn has_readable_accessors(&self, primitive: &gltf::Primitive) -> Result<bool, IngestError> {
        use gltf::accessor::{DataType, Dimensions};
        let malformed = |message: String| IngestError::malformed(FORMAT, message);
        let positions = primitive
            .get(&gltf::Semantic::Positions)
            .ok_or_else(|| malformed("a triangle primitive has no POSITION".into()))?;
        let float = positions.data_type() == DataType::F32;
        let integer = self.quantized && positions.data_type() != DataType::U32;
        if positions.dimensions() != Dimensions::Vec3 || !(float || integer) {
            let allowed = match self.quantized {
                true => "float or 8- and 16-bit integer VEC3",
                false => "float VEC3 (integers need KHR_mesh_quantization)",
            };
            return Err(malformed(format!(
                "accessor {}: positions are {:?} {:?}, not {allowed}",
                positions.index(),
                positions.data_type(),
                positions.dimensions(),
            )));
        }
        let indices = primitive.indices();
        if let Some(indices) = &indices
            && (!matches!(indices.data_type(), DataType::U8 | DataType::U16 | DataType::U32)
                || indices.dimensions() != Dimensions::Scalar)
        {
            return Err(malformed(format!(
                "accessor {}: indices are {:?} {:?}, not unsigned integer scalars",
                indices.index(),
                indices.data_type(),
                indices.dimensions()
            )));
        }
        let limit = self.limits.max_unbacked_items();
        for accessor in [Some(positions), indices].into_iter().flatten() {
            if accessor.view().is_none() && accessor.count() as u64 > limit {
                return Err(IngestError::TooLarge(format!(
                    "accessor {} declares {} items that no bufferView backs, over 3 × cook.max_placed_triangles ({limit})",
                    accessor.index(),
                    accessor.count(),
                )));
            }
            if accessor.count() == 0 {
                return Ok(false);
            }
        }
        Ok(true)
    }

    /// A position accessor's points: floats as they are; with KHR_mesh_quantization, integers
    /// as they are, or mapped to [-1, 1] (signed) or [0, 1] (unsigned) when normalized.
    fn positions(&self, accessor: gltf::Accessor) -> Option<Vec<Vec3>> {
        use gltf::accessor::DataType;
        match accessor.data_type() {
            DataType::F32 => self.points::<f32>(accessor, None),
            DataType::I8 => self.points::<i8>(accessor, Some(127.0)),
            DataType::U8 => self.points::<u8>(accessor, Some(255.0)),
            DataType::I16 => self.points::<i16>(accessor, Some(32767.0)),
            DataType::U16 => self.points::<u16>(accessor, Some(65535.0)),
            DataType::U32 => None,
        }
    }

    /// Points of components `C`; integers are divided by their `max` when normalized.
    fn points<C: Copy + Into<f32>>(&self, accessor: gltf::Accessor, max: Option<f32>) -> Option<Vec<Vec3>>
    where
        [C; 3]: gltf::accessor::Item,
    {
        let max = max.filter(|_| accessor.normalized());
        let value = |c: C| match max {
            Some(max) => (c.into() / max).max(-1.0),
            None => c.into(),
        };
        let data = |b: gltf::Buffer| self.buffers.get(b.index()).map(Vec::as_slice);
        let points = gltf::accessor::Iter::<[C; 3]>::new(accessor, data)?;
        Some(points.map(|p| Vec3::from(p.map(value))).collect())
    }

    fn read_primitive(&self, primitive: &gltf::Primitive, world: Mat4, raw: &mut RawMesh) -> Result<(), IngestError> {
        let mode = primitive.mode();
        if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
            raw.skipped_primitives += 1;
            raw.warnings
                .push(format!("skipped a {mode:?} primitive: only triangles have a surface"));
            return Ok(());
        }
        if !self.has_readable_accessors(primitive)? {
            return Ok(());
        }
        let out_of_buffer = || IngestError::malformed(FORMAT, "an accessor reaches past the end of its buffer");
        let positions: Vec<Vec3> = primitive
            .get(&gltf::Semantic::Positions)
            .and_then(|accessor| self.positions(accessor))
            .ok_or_else(out_of_buffer)?
            .into_iter()
            .map(|p| world.transform_point3(p))
            .collect();
        let reader = primitive.reader(|b| self.buffers.get(b.index()).map(Vec::as_slice));
        let indices: Vec<u64> = match reader.read_indices() {
            Some(indices) => indices.into_u32().map(u64::from).collect(),
            None if primitive.indices().is_some() => return Err(out_of_buffer()),
            None => (0..positions.len() as u64).collect(),
        };
        raw.append(&positions, triangles_of(mode, &indices, world.determinant() < 0.0))
    }
}

/// The triangles a list, strip or fan of `indices` makes; `flip` reverses their winding, as a
/// mirroring transform needs to keep faces facing the way they were authored.
fn triangles_of(mode: Mode, indices: &[u64], flip: bool) -> Vec<[u64; 3]> {
    let ordered = |[a, b, c]: [u64; 3]| if flip { [a, c, b] } else { [a, b, c] };
    match mode {
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
    }
}
