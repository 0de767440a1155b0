//! FBX, binary and ASCII (versions 6 and 7), through ufbx: every mesh node in world space, with
//! its geometric transform and pivots, converted to glTF's frame (metres, +Y up).

use super::{IngestError, IngestLimits, Instances, RawMesh, SourceFrame};
use glam::{DMat4, DVec4, Vec3};

const FORMAT: &str = "FBX";
/// Every allocation ufbx makes stays under this plus [`MEMORY_PER_INPUT_BYTE`] times the file
/// size: compressed arrays inflate, but not without bound.
const MEMORY_BASE: usize = 256 << 20;
const MEMORY_PER_INPUT_BYTE: usize = 64;

/// Every mesh node's triangles in world space.
pub fn read(bytes: &[u8], limits: &IngestLimits) -> Result<RawMesh, IngestError> {
    let scene = load(bytes, limits)?;
    // Meshes are stored once and may be placed by many nodes.
    let placed = scene
        .nodes
        .iter()
        .filter_map(|node| node.mesh.as_ref())
        .map(|mesh| mesh.num_triangles as u64);
    limits.check_placed(placed.fold(0, u64::saturating_add), "triangles")?;
    let mut raw = RawMesh {
        source_frame: Some(source_frame(&scene)),
        ..RawMesh::default()
    };
    for node in scene.nodes.iter() {
        if let Some(mesh) = &node.mesh {
            append_mesh(mesh, world(node), &mut raw)?;
        }
    }
    Ok(raw)
}

/// An FBX scene as a level: each mesh once, in its own space, and each node that places one as
/// (mesh index, world transform).
pub fn read_instances(bytes: &[u8], limits: &IngestLimits) -> Result<Instances, IngestError> {
    let scene = load(bytes, limits)?;
    let mut used = vec![None; scene.meshes.len()];
    let mut meshes = Vec::new();
    let mut placements = Vec::new();
    for node in scene.nodes.iter() {
        let Some(mesh) = &node.mesh else { continue };
        let slot = &mut used[mesh.element.typed_id as usize];
        let index = match *slot {
            Some(index) => index,
            None => {
                let mut raw = RawMesh::default();
                append_mesh(mesh, DMat4::IDENTITY, &mut raw)?;
                let name = match mesh.element.name.as_ref() {
                    "" => node.element.name.to_string(),
                    name => name.to_string(),
                };
                meshes.push((name, raw));
                *slot = Some(meshes.len() - 1);
                meshes.len() - 1
            }
        };
        placements.push((index, world(node).as_mat4()));
    }
    Ok(Instances { meshes, placements })
}

fn load(bytes: &[u8], limits: &IngestLimits) -> Result<ufbx::SceneRoot, IngestError> {
    let limit = MEMORY_BASE
        .saturating_add(bytes.len().saturating_mul(MEMORY_PER_INPUT_BYTE))
        .min(usize::try_from(limits.max_parse_bytes).unwrap_or(usize::MAX));
    let allocator = || ufbx::AllocatorOpts {
        memory_limit: limit,
        ..Default::default()
    };
    let options = ufbx::LoadOpts {
        temp_allocator: allocator(),
        result_allocator: allocator(),
        ignore_animation: true,
        ignore_embedded: true,
        target_axes: ufbx::CoordinateAxes {
            right: ufbx::CoordinateAxis::PositiveX,
            up: ufbx::CoordinateAxis::PositiveY,
            front: ufbx::CoordinateAxis::PositiveZ,
        },
        target_unit_meters: 1.0,
        space_conversion: ufbx::SpaceConversion::ModifyGeometry,
        // The file's own content decides: a .fbx name is not asked of a byte slice.
        file_format: ufbx::FileFormat::Fbx,
        ..Default::default()
    };
    ufbx::load_memory(bytes, options).map_err(|e| {
        let info = e.info();
        let message = match info.is_empty() {
            true => e.description.to_string(),
            false => format!("{}: {info}", e.description),
        };
        IngestError::malformed(FORMAT, message)
    })
}

/// The unit and up axis the file was authored in.
fn source_frame(scene: &ufbx::Scene) -> SourceFrame {
    // `axes` and `unit_meters` keep the file's own values whatever the load converted to.
    let up = match scene.settings.axes.up {
        ufbx::CoordinateAxis::PositiveX => "+X",
        ufbx::CoordinateAxis::NegativeX => "-X",
        ufbx::CoordinateAxis::PositiveY => "+Y",
        ufbx::CoordinateAxis::NegativeY => "-Y",
        ufbx::CoordinateAxis::PositiveZ => "+Z",
        ufbx::CoordinateAxis::NegativeZ => "-Z",
        ufbx::CoordinateAxis::Unknown => "unknown",
    };
    SourceFrame {
        unit_meters: scene.settings.unit_meters,
        up_axis: up,
        converted_to: super::GLTF_FRAME,
    }
}

/// A node's geometry-to-world matrix: its transforms, geometric offsets and pivots.
fn world(node: &ufbx::Node) -> DMat4 {
    let m = &node.geometry_to_world;
    DMat4::from_cols(
        DVec4::new(m.m00, m.m10, m.m20, 0.0),
        DVec4::new(m.m01, m.m11, m.m21, 0.0),
        DVec4::new(m.m02, m.m12, m.m22, 0.0),
        DVec4::new(m.m03, m.m13, m.m23, 1.0),
    )
}

/// Appends a mesh's faces, fan-triangulated by ufbx (concave polygons too), placed by `world`.
/// Hole faces bound no surface and are left out.
fn append_mesh(mesh: &ufbx::Mesh, world: DMat4, raw: &mut RawMesh) -> Result<(), IngestError> {
    let positions: Vec<Vec3> = mesh
        .vertices
        .iter()
        .map(|p| world.transform_point3(glam::DVec3::new(p.x, p.y, p.z)).as_vec3())
        .collect();
    // A mirroring transform flips the winding; keep faces facing the way they were authored.
    let flip = world.determinant() < 0.0;
    let mut corners = vec![0u32; mesh.max_face_triangles * 3];
    let mut triangles = Vec::with_capacity(mesh.num_triangles);
    for (f, &face) in mesh.faces.iter().enumerate() {
        if mesh.face_hole.get(f).copied().unwrap_or(false) {
            continue;
        }
        let count = mesh.triangulate_face(&mut corners, face) as usize;
        for t in corners[..count * 3].chunks_exact(3) {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| u64::from(mesh.vertex_indices[i as usize]));
            triangles.push(if flip { [a, c, b] } else { [a, b, c] });
        }
    }
    raw.append(&positions, triangles)
}
