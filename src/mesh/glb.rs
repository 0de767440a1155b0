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

/// Serializes the parts as a GLB. `extras` lands on the node, where tools show it. Empty parts
/// are left out; with none left, the scene has one node and no mesh, which is still valid glTF.
pub fn write(parts: &[Part], extras: Value) -> Vec<u8> {
    let mut bin: Vec<u8> = Vec::new();
    let (mut views, mut accessors, mut materials, mut primitives) = (vec![], vec![], vec![], vec![]);
    for part in parts.iter().filter(|p| !p.mesh.triangles.is_empty()) {
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
        primitives.push(json!({ "attributes": { "POSITION": accessor }, "indices": accessor + 1,
            "material": materials.len(), "mode": 4 }));
        materials.push(json!({ "name": part.name, "doubleSided": part.double_sided }));
    }
    let mut node = json!({ "name": "occluder", "extras": extras });
    let mut doc = json!({
        "asset": { "version": "2.0", "generator": concat!("occluder-cook ", env!("CARGO_PKG_VERSION")) },
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
    });
    if !primitives.is_empty() {
        node["mesh"] = json!(0);
        doc["buffers"] = json!([{ "byteLength": bin.len() }]);
        doc["bufferViews"] = json!(views);
        doc["accessors"] = json!(accessors);
        doc["materials"] = json!(materials);
        doc["meshes"] = json!([{ "name": "occluder", "primitives": primitives }]);
    }
    doc["nodes"] = json!([node]);
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

fn pad(bytes: &mut Vec<u8>, fill: u8) {
    while !bytes.len().is_multiple_of(4) {
        bytes.push(fill);
    }
}
