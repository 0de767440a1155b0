//! GLB export of an occluder: one glTF mesh with a primitive per part (the watertight solid,
//! the double-sided panels), with metadata in `extras`.

use super::Mesh;
use serde_json::{Value, json};

const MAGIC: u32 = 0x4654_6C67; // "glTF"
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;

/// One primitive of the occluder, with its own material.
pub struct Part<'a> {
    pub name: &'a str,
    pub mesh: &'a Mesh,
    /// Seen from both sides (panels), which glTF states in the material.
    pub double_sided: bool,
}

/// One node of the scene with its own mesh of parts.
pub struct Node<'a> {
    pub name: String,
    pub parts: Vec<Part<'a>>,
    /// Lands on the node, where tools show it.
    pub extras: Value,
}

/// Serializes the parts as a GLB of one node named "occluder". Empty parts are left out; with
/// none left, the node has no mesh, which is still valid glTF.
pub fn write(parts: &[Part], extras: Value) -> Vec<u8> {
    let node = Node {
        name: "occluder".into(),
        parts: parts
            .iter()
            .map(|p| Part {
                name: p.name,
                mesh: p.mesh,
                double_sided: p.double_sided,
            })
            .collect(),
        extras,
    };
    write_scene(&[node])
}

/// Serializes a scene of nodes, each with its own mesh, as a GLB. Materials are shared by name.
pub fn write_scene(nodes: &[Node]) -> Vec<u8> {
    let mut bin: Vec<u8> = Vec::new();
    let (mut views, mut accessors, mut materials, mut meshes, mut gltf_nodes) =
        (vec![], vec![], vec![], vec![], vec![]);
    let mut material_names: Vec<&str> = Vec::new();
    for node in nodes {
        let mut primitives = Vec::new();
        for part in node.parts.iter().filter(|p| !p.mesh.triangles.is_empty()) {
            let mesh = part.mesh;
            let start = bin.len();
            for c in mesh.positions.iter().flat_map(|p| p.to_array()) {
                bin.extend_from_slice(&c.to_le_bytes());
            }
            let middle = bin.len();
            for i in mesh.triangles.iter().flatten() {
                bin.extend_from_slice(&i.to_le_bytes());
            }
            let (lo, hi) = mesh.bounds();
            let view = views.len();
            views.push(json!({ "buffer": 0, "byteOffset": start, "byteLength": middle - start, "target": 34962 }));
            views.push(json!({ "buffer": 0, "byteOffset": middle, "byteLength": bin.len() - middle, "target": 34963 }));
            let accessor = accessors.len();
            accessors.push(
                json!({ "bufferView": view, "componentType": 5126, "count": mesh.positions.len(),
                "type": "VEC3", "min": lo.to_array(), "max": hi.to_array() }),
            );
            accessors.push(json!({ "bufferView": view + 1, "componentType": 5125,
                "count": mesh.triangles.len() * 3, "type": "SCALAR" }));
            let material = match material_names.iter().position(|n| *n == part.name) {
                Some(m) => m,
                None => {
                    material_names.push(part.name);
                    materials.push(json!({ "name": part.name, "doubleSided": part.double_sided }));
                    materials.len() - 1
                }
            };
            primitives.push(json!({ "attributes": { "POSITION": accessor }, "indices": accessor + 1,
                "material": material, "mode": 4 }));
        }
        let mut gltf_node = json!({ "name": node.name, "extras": node.extras });
        if !primitives.is_empty() {
            gltf_node["mesh"] = json!(meshes.len());
            meshes.push(json!({ "name": node.name, "primitives": primitives }));
        }
        gltf_nodes.push(gltf_node);
    }
    let mut doc = json!({
        "asset": { "version": "2.0", "generator": concat!("occluder-cook ", env!("CARGO_PKG_VERSION")) },
        "scene": 0,
        "scenes": [{ "nodes": (0..gltf_nodes.len()).collect::<Vec<_>>() }],
        "nodes": gltf_nodes,
    });
    if !meshes.is_empty() {
        doc["buffers"] = json!([{ "byteLength": bin.len() }]);
        doc["bufferViews"] = json!(views);
        doc["accessors"] = json!(accessors);
        doc["materials"] = json!(materials);
        doc["meshes"] = json!(meshes);
    }
    let mut json_bytes = serde_json::to_vec(&doc).expect("JSON serializes");
    pad(&mut json_bytes, b' ');
    pad(&mut bin, 0);
    let total = 12 + 8 + json_bytes.len() + if bin.is_empty() { 0 } else { 8 + bin.len() };
    let mut out = Vec::with_capacity(total);
    for word in [MAGIC, 2, total as u32, json_bytes.len() as u32, CHUNK_JSON] {
        out.extend_from_slice(&word.to_le_bytes());
    }
    out.extend_from_slice(&json_bytes);
    if !bin.is_empty() {
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(&CHUNK_BIN.to_le_bytes());
        out.extend_from_slice(&bin);
    }
    out
}

/// The parts of a GLB this module wrote, by material name: (name, mesh), in order. Used to
/// read cached occluders back.
pub fn read_parts(bytes: &[u8]) -> Result<Vec<(String, Mesh)>, super::IngestError> {
    let gltf = super::gltf_in::parse(bytes)?
        .map_err(|e| super::IngestError::malformed("glTF", super::gltf_in::first_problem(&e)))?;
    // Our GLBs keep everything in the one binary chunk.
    let blob = gltf.blob.as_deref();
    let mut parts = Vec::new();
    for mesh in gltf.document.meshes() {
        for primitive in mesh.primitives() {
            let name = primitive.material().name().unwrap_or("").to_string();
            let reader = primitive.reader(|b| if b.index() == 0 { blob } else { None });
            let positions: Vec<glam::Vec3> = reader
                .read_positions()
                .map(|p| p.map(glam::Vec3::from_array).collect())
                .unwrap_or_default();
            let indices: Vec<u32> = reader
                .read_indices()
                .map(|i| i.into_u32().collect())
                .unwrap_or_default();
            let triangles = indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
            parts.push((name, Mesh { positions, triangles }));
        }
    }
    Ok(parts)
}

fn pad(bytes: &mut Vec<u8>, fill: u8) {
    while !bytes.len().is_multiple_of(4) {
        bytes.push(fill);
    }
}
