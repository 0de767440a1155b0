//! Meshes in flat arrays: ingest from glTF/GLB, FBX, OBJ, PLY and STL, welding, validation and
//! GLB export; and items grouped by a dense key such as a vertex ([`buckets`]), which the stages
//! above share.

pub mod buckets;
mod fbx;
pub mod glb;
mod gltf_in;
mod gltf_meshopt;
mod obj;
mod ply;
pub mod shapes;
mod stl;
pub mod topology;

use glam::Vec3;
use serde::Serialize;
use std::path::Path;

pub use topology::{BoundaryEdge, Topology};

/// World-space triangles over welded vertices.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// A mesh file's container format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Gltf,
    Fbx,
    Obj,
    Ply,
    Stl,
}

impl Format {
    /// Every format, in the order errors and documents list them.
    pub const ALL: [Format; 5] = [Format::Gltf, Format::Fbx, Format::Obj, Format::Ply, Format::Stl];

    /// `gltf`, `fbx`, `obj`, `ply` or `stl`: how inputs are filed.
    pub fn name(self) -> &'static str {
        match self {
            Format::Gltf => "gltf",
            Format::Fbx => "fbx",
            Format::Obj => "obj",
            Format::Ply => "ply",
            Format::Stl => "stl",
        }
    }

    /// The format of a name or extension: `glb`, `gltf`, `fbx`, `obj`, `ply` or `stl`, in any case.
    pub fn from_name(name: &str) -> Option<Format> {
        match name.to_ascii_lowercase().as_str() {
            "glb" | "gltf" => Some(Format::Gltf),
            "fbx" => Some(Format::Fbx),
            "obj" => Some(Format::Obj),
            "ply" => Some(Format::Ply),
            "stl" => Some(Format::Stl),
            _ => None,
        }
    }

    /// The format named by a file extension (`glb`, `gltf`, `fbx`, `obj`, `ply`, `stl`).
    pub fn from_extension(path: &Path) -> Result<Format, IngestError> {
        path.extension()
            .and_then(|e| e.to_str())
            .and_then(Format::from_name)
            .ok_or_else(|| IngestError::UnknownFormat(path.display().to_string()))
    }
}

/// Why a mesh file was rejected. Each message is one line naming the problem.
#[derive(Debug, thiserror::Error)]
pub enum IngestError {
    // `reason`, not `source`: as a source, the reason would be printed twice in a chain.
    #[error("cannot read {path}: {reason}")]
    Io { path: String, reason: std::io::Error },
    #[error("unknown mesh format for {0}: expected .glb, .gltf, .fbx, .obj, .ply or .stl")]
    UnknownFormat(String),
    #[error("malformed {format} file: {message}")]
    Malformed { format: &'static str, message: String },
    #[error("non-finite vertex coordinate ({0}) in vertex {1}")]
    NonFinite(String, usize),
    #[error("vertex {1} at ({0}) lies past ±{MAX_COORDINATE:e}, where the cook's arithmetic overflows")]
    FarVertex(String, usize),
    #[error("the mesh is {0:.1e} across, smaller than the {MIN_EXTENT:e} the cook resolves: scale it up")]
    TooSmall(f64),
    #[error("vertex index {index} out of range: the primitive has {count} vertices")]
    IndexOutOfRange { index: u64, count: usize },
    #[error("the scene graph has a cycle through node {0}")]
    NodeCycle(usize),
    #[error("the mesh has no triangles{0}")]
    Empty(String),
    #[error("{0}")]
    TooLarge(String),
}

/// What ingest may allocate for one file, past what the file's own bytes hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IngestLimits {
    /// Triangles a scene may place, counted before its node graph is expanded (`cook.max_placed_triangles`).
    pub max_placed_triangles: u64,
    /// Bytes a parse may allocate (`service.max_parse_bytes`).
    pub max_parse_bytes: u64,
}

/// What reading and welding take per placed triangle at most: its corners' positions, indices,
/// the weld's remap and hash map.
const PARSE_BYTES_PER_TRIANGLE: u64 = 160;

impl Default for IngestLimits {
    /// As config/default.toml.
    fn default() -> Self {
        IngestLimits {
            max_placed_triangles: 20_000_000,
            max_parse_bytes: 4 << 30,
        }
    }
}

impl IngestLimits {
    /// Refuses a scene that places more than `max_placed_triangles` (`what`: triangles, or the
    /// node visits that place them), or whose reading would take more than `max_parse_bytes`.
    pub(crate) fn check_placed(&self, placed: u64, what: &str) -> Result<(), IngestError> {
        if placed > self.max_placed_triangles {
            return Err(IngestError::TooLarge(format!(
                "the file places {placed} {what}, over cook.max_placed_triangles ({})",
                self.max_placed_triangles
            )));
        }
        self.check_bytes(
            placed.saturating_mul(PARSE_BYTES_PER_TRIANGLE),
            &format!("reading its {what}"),
        )
    }

    /// Refuses a parse that would allocate `bytes` past `max_parse_bytes`.
    pub(crate) fn check_bytes(&self, bytes: u64, what: &str) -> Result<(), IngestError> {
        match bytes > self.max_parse_bytes {
            true => Err(IngestError::TooLarge(format!(
                "{what} would take {} MB, over service.max_parse_bytes ({} MB)",
                bytes >> 20,
                self.max_parse_bytes >> 20
            ))),
            false => Ok(()),
        }
    }

    /// Items an accessor that no bytes back may declare: the vertices of the triangles allowed.
    pub(crate) fn max_unbacked_items(&self) -> u64 {
        self.max_placed_triangles.saturating_mul(3)
    }
}

/// Longest message a malformed file gets: errors are one line of at most 200 characters.
const MAX_MESSAGE: usize = 160;

impl IngestError {
    /// A parser's complaint, on one line and cut to [`MAX_MESSAGE`] characters.
    pub(crate) fn malformed(format: &'static str, message: impl Into<String>) -> Self {
        let message = message.into().replace(['\n', '\r'], " ");
        let message = match message.char_indices().nth(MAX_MESSAGE) {
            Some((cut, _)) => format!("{}…", &message[..cut]),
            None => message,
        };
        IngestError::Malformed { format, message }
    }
}

/// What ingest saw, for the report.
#[derive(Clone, Debug, Default, Serialize)]
pub struct IngestStats {
    pub input_triangles: usize,
    pub input_vertices: usize,
    pub welded_vertices: usize,
    pub degenerate_triangles: usize,
    /// Points, lines and line strips are not surfaces; they are skipped.
    pub skipped_primitives: usize,
    /// Triangle primitives (glTF) or groups (OBJ) read: the draw calls the mesh costs.
    pub primitives: usize,
    pub warnings: Vec<String>,
    /// The unit and up axis the file was authored in, where the format says (FBX).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub source_frame: Option<SourceFrame>,
}

/// The frame every mesh is read into: glTF's.
pub const GLTF_FRAME: &str = "metres, +Y up";

/// A file's own unit and up axis, and the frame its geometry was converted to.
#[derive(Clone, Debug, Serialize)]
pub struct SourceFrame {
    pub unit_meters: f64,
    pub up_axis: &'static str,
    pub converted_to: &'static str,
}

/// Triangles as read from a file, before welding.
#[derive(Default)]
pub(crate) struct RawMesh {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    pub skipped_primitives: usize,
    pub primitives: usize,
    pub warnings: Vec<String>,
    pub source_frame: Option<SourceFrame>,
}

/// A scene as a level: each mesh once, in its own space, with its name, and each node that
/// places a mesh as (mesh index, world transform).
pub(crate) struct Instances {
    pub meshes: Vec<(String, RawMesh)>,
    pub placements: Vec<(usize, glam::Mat4)>,
}

impl RawMesh {
    /// Appends a primitive whose indices refer to `positions`, checking every index.
    pub fn append(
        &mut self,
        positions: &[Vec3],
        triangles: impl IntoIterator<Item = [u64; 3]>,
    ) -> Result<(), IngestError> {
        let base = self.positions.len() as u64;
        for tri in triangles {
            for &i in &tri {
                if i >= positions.len() as u64 {
                    return Err(IngestError::IndexOutOfRange {
                        index: i,
                        count: positions.len(),
                    });
                }
            }
            self.triangles
                .push(tri.map(|i| u32::try_from(base + i).expect("vertex count fits u32")));
        }
        self.positions.extend_from_slice(positions);
        self.primitives += 1;
        Ok(())
    }
}

/// Reads a mesh file; `.gltf` files may reference buffers beside them.
pub fn load_file(path: &Path, limits: &IngestLimits) -> Result<(Mesh, IngestStats), IngestError> {
    let format = Format::from_extension(path)?;
    let bytes = std::fs::read(path).map_err(|reason| IngestError::Io {
        path: path.display().to_string(),
        reason,
    })?;
    load_bytes(&bytes, format, path.parent(), limits)
}

/// Parses a mesh from memory. `base_dir` resolves external glTF buffers; without it only
/// embedded buffers are allowed.
pub fn load_bytes(
    bytes: &[u8],
    format: Format,
    base_dir: Option<&Path>,
    limits: &IngestLimits,
) -> Result<(Mesh, IngestStats), IngestError> {
    let raw = load_raw(bytes, format, base_dir, limits)?;
    for warning in &raw.warnings {
        tracing::warn!("{warning}");
    }
    weld(raw)
}

/// The triangles as read. Scene formats check the limit before they place anything; the rest
/// hold every triangle in their bytes, and are checked once read.
fn load_raw(
    bytes: &[u8],
    format: Format,
    base_dir: Option<&Path>,
    limits: &IngestLimits,
) -> Result<RawMesh, IngestError> {
    let raw = match format {
        Format::Gltf => gltf_in::read(bytes, base_dir, limits)?,
        Format::Fbx => fbx::read(bytes, limits)?,
        Format::Obj => obj::read(bytes)?,
        Format::Ply => ply::read(bytes)?,
        Format::Stl => stl::read(bytes)?,
    };
    limits.check_placed(raw.triangles.len() as u64, "triangles")?;
    Ok(raw)
}

/// A named mesh inside a level file (an OBJ group, a glTF mesh), welded.
pub type Part = (String, Mesh, IngestStats);

/// Each group of an OBJ file as its own welded mesh, with its name. Groups with no triangle
/// left after welding are skipped.
pub fn load_obj_groups(bytes: &[u8]) -> Result<Vec<Part>, IngestError> {
    Ok(weld_parts(obj::read_groups(bytes)?)?.into_iter().flatten().collect())
}

/// Where a level places its meshes: (index into its parts, world transform).
pub type Placement = (usize, glam::DMat4);

/// A glTF or FBX scene's meshes, each once and in its own space, and the nodes that place them:
/// (index into the meshes, world transform). Meshes that no node places, or with no triangles,
/// are left out, with the nodes that place them. A format without a scene is one placed mesh.
pub fn load_instances(
    bytes: &[u8],
    format: Format,
    base_dir: Option<&Path>,
    limits: &IngestLimits,
) -> Result<(Vec<Part>, Vec<Placement>), IngestError> {
    let scene = match format {
        Format::Gltf => gltf_in::read_instances(bytes, base_dir, limits)?,
        Format::Fbx => fbx::read_instances(bytes, limits)?,
        Format::Obj | Format::Ply | Format::Stl => Instances {
            meshes: vec![(String::from("mesh"), load_raw(bytes, format, base_dir, limits)?)],
            placements: vec![(0, glam::Mat4::IDENTITY)],
        },
    };
    let mut index = Vec::with_capacity(scene.meshes.len());
    let mut parts = Vec::new();
    for part in weld_parts(scene.meshes)? {
        index.push(part.is_some().then_some(parts.len()));
        parts.extend(part);
    }
    let placements = scene
        .placements
        .into_iter()
        .filter_map(|(mesh, world)| Some((index[mesh]?, world.as_dmat4())))
        .collect();
    Ok((parts, placements))
}

/// Welds each named mesh; one that has no triangle left is `None`, with a warning.
fn weld_parts(raws: Vec<(String, RawMesh)>) -> Result<Vec<Option<Part>>, IngestError> {
    raws.into_iter()
        .map(|(name, raw)| match weld(raw) {
            Ok((mesh, stats)) => Ok(Some((name, mesh, stats))),
            Err(IngestError::Empty(_)) => {
                tracing::warn!("{name} has no triangles; skipped");
                Ok(None)
            }
            Err(e) => Err(e),
        })
        .collect()
}

/// Each distinct position once, and for each of `positions` the index of its own among them
/// (-0.0 and 0.0 are the same position).
pub fn weld_positions(positions: &[Vec3]) -> (Vec<Vec3>, Vec<u32>) {
    let key = |p: Vec3| (p + Vec3::ZERO).to_array().map(f32::to_bits);
    let mut remap = Vec::with_capacity(positions.len());
    // Seeded per map, as inputs are untrusted; far quicker than the default hasher.
    let mut index_of = foldhash::HashMap::with_capacity_and_hasher(positions.len(), Default::default());
    let mut distinct = Vec::new();
    for &p in positions {
        let next = distinct.len() as u32;
        let index = *index_of.entry(key(p)).or_insert(next);
        if index == next {
            distinct.push(p);
        }
        remap.push(index);
    }
    (distinct, remap)
}

/// Largest coordinate the cook takes: sums and products of f32 coordinates stay finite well
/// past it (a cube 2e25 across cooks as one 2 across does; one out at 2e38 does not).
pub const MAX_COORDINATE: f32 = 1e30;
/// Smallest mesh the cook takes, along its longest side: framing and rasterizing keep absolute
/// floors below it (a cube 1e-13 across cooks as one 1 across does; one 1e-14 across does not).
pub const MIN_EXTENT: f64 = 1e-12;

/// Welds vertices with identical positions, drops degenerate triangles, and validates.
pub(crate) fn weld(raw: RawMesh) -> Result<(Mesh, IngestStats), IngestError> {
    if let Some((i, p)) = raw.positions.iter().enumerate().find(|(_, p)| !p.is_finite()) {
        return Err(IngestError::NonFinite(format!("{}, {}, {}", p.x, p.y, p.z), i));
    }
    if let Some((i, p)) = raw
        .positions
        .iter()
        .enumerate()
        .find(|(_, p)| p.abs().max_element() > MAX_COORDINATE)
    {
        return Err(IngestError::FarVertex(format!("{:e}, {:e}, {:e}", p.x, p.y, p.z), i));
    }
    let mut stats = IngestStats {
        input_triangles: raw.triangles.len(),
        input_vertices: raw.positions.len(),
        skipped_primitives: raw.skipped_primitives,
        primitives: raw.primitives,
        warnings: raw.warnings,
        source_frame: raw.source_frame,
        ..Default::default()
    };
    let (positions, remap) = weld_positions(&raw.positions);
    let mut triangles = Vec::with_capacity(raw.triangles.len());
    for tri in &raw.triangles {
        let t = tri.map(|i| remap[i as usize]);
        let [a, b, c] = t.map(|i| positions[i as usize].as_dvec3());
        if (b - a).cross(c - a) == glam::DVec3::ZERO {
            stats.degenerate_triangles += 1;
        } else {
            triangles.push(t);
        }
    }
    if triangles.is_empty() {
        let why = if stats.input_triangles == 0 {
            String::new()
        } else {
            format!(": all {} triangles are degenerate", stats.input_triangles)
        };
        return Err(IngestError::Empty(why));
    }
    // Keep only referenced vertices so that vertex counts mean something.
    let mut used = vec![u32::MAX; positions.len()];
    let mut compact = Vec::new();
    for t in &mut triangles {
        for i in t.iter_mut() {
            if used[*i as usize] == u32::MAX {
                used[*i as usize] = compact.len() as u32;
                compact.push(positions[*i as usize]);
            }
            *i = used[*i as usize];
        }
    }
    stats.welded_vertices = compact.len();
    let (lo, hi) = point_bounds(compact.iter().map(|p| p.as_dvec3()));
    let extent = (hi - lo).max_element();
    if extent < MIN_EXTENT {
        return Err(IngestError::TooSmall(extent));
    }
    Ok((
        Mesh {
            positions: compact,
            triangles,
        },
        stats,
    ))
}

/// The bounds (min, max) of points; (+∞, −∞) when there are none.
pub fn point_bounds(points: impl IntoIterator<Item = glam::DVec3>) -> (glam::DVec3, glam::DVec3) {
    points
        .into_iter()
        .fold((glam::DVec3::INFINITY, glam::DVec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p), hi.max(p))
        })
}

impl Mesh {
    /// Adds `other`'s triangles, without welding.
    pub fn append(&mut self, other: &Mesh) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.triangles
            .extend(other.triangles.iter().map(|t| t.map(|i| i + base)));
    }

    /// Axis-aligned bounds (min, max).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.positions
            .iter()
            .fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), &p| {
                (lo.min(p), hi.max(p))
            })
    }

    /// The vertex farthest outside the bounds of the others, where it stretches the mesh's
    /// bounds (and so its voxel grid) to over `STRAY_SPAN` times theirs: the others leaving out
    /// the outermost hundredth, and at least one, on each side along each axis.
    pub fn stray_vertex(&self) -> Option<Vec3> {
        const STRAY_SPAN: f32 = 1e3;
        let outer = (self.positions.len() / 100).max(1);
        let mut along = Vec::with_capacity(self.positions.len());
        let mut inner = (Vec3::ZERO, Vec3::ZERO);
        for k in 0..3 {
            along.clear();
            along.extend(self.positions.iter().map(|p| p[k]));
            if along.len() < 2 * outer + 2 {
                return None;
            }
            let (_, &mut lo, rest) = along.select_nth_unstable_by(outer, f32::total_cmp);
            let last = rest.len() - outer;
            let (_, &mut hi, _) = rest.select_nth_unstable_by(last - 1, f32::total_cmp);
            (inner.0[k], inner.1[k]) = (lo, hi);
        }
        let (lo, hi) = self.bounds();
        let span = (inner.1 - inner.0).max_element();
        let outside = |p: &&Vec3| (p.clamp(inner.0, inner.1) - **p).length();
        ((hi - lo).max_element() > STRAY_SPAN * span && span > 0.0)
            .then(|| self.positions.iter().max_by(|a, b| outside(a).total_cmp(&outside(b))))
            .flatten()
            .copied()
    }

    /// A sphere around the bounds' centre that holds every vertex.
    pub fn bounding_sphere(&self) -> (glam::DVec3, f64) {
        let (lo, hi) = self.bounds();
        let center = ((lo + hi) * 0.5).as_dvec3();
        let radius = self
            .positions
            .iter()
            .map(|p| p.as_dvec3().distance(center))
            .fold(0.0, f64::max);
        (center, radius)
    }

    /// Every triangle's corners in double precision.
    pub fn triangles_f64(&self) -> impl Iterator<Item = [glam::DVec3; 3]> + '_ {
        (0..self.triangles.len()).map(|t| self.corners(t).map(|p| p.as_dvec3()))
    }

    /// The three corners of triangle `t`.
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        self.triangles[t].map(|i| self.positions[i as usize])
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    #[test]
    fn a_vertex_far_outside_the_rest_is_stray_and_a_whole_mesh_has_none() {
        let mut mesh = super::shapes::torus(1.0, 0.45, 32, 16);
        assert_eq!(mesh.stray_vertex(), None);
        // A long thin mesh is not stray: every vertex has neighbours along it.
        let mut long = mesh.clone();
        long.positions.iter_mut().for_each(|p| p.x *= 1e4);
        assert_eq!(long.stray_vertex(), None);
        let far = Vec3::new(1e20, -3.0, 1e20);
        mesh.positions[7] = far;
        assert_eq!(mesh.stray_vertex(), Some(far));
    }
}
