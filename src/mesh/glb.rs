//! GLB export of an occluder: one mesh of positions and indices, with metadata in `extras`.

use super::Mesh;
use serde_json::{Value, json};

const MAGIC: u32 = 0x4654_6C67; // "glTF"
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;

/// Serializes `mesh` as a GLB. `extras` lands on the mesh node and the asset, where tools show it.
/// An empty mesh gives a scene with one node and no mesh, which is still valid glTF.
pub fn write(mesh: &Mesh, extras: Value) -> Vec<u8> {
    let mut bin = Vec::with_capacity(mesh.positions.len() * 12 + mesh.triangles.len() * 12);
    for p in &mesh.positions {
        for c in p.to_array() {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    let positions_len = bin.len();
    for t in &mesh.triangles {
        for i in t {
            bin.extend_from_slice(&i.to_le_bytes());
        }
    }
    let mut node = json!({ "name": "occluder", "extras": extras });
    let mut doc = json!({
        "asset": { "version": "2.0", "generator": concat!("occluder-cook ", env!("CARGO_PKG_VERSION")) },
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
    });
    if !mesh.triangles.is_empty() {
        let (lo, hi) = mesh.bounds();
        node["mesh"] = json!(0);
        doc["buffers"] = json!([{ "byteLength": bin.len() }]);
        doc["bufferViews"] = json!([
            { "buffer": 0, "byteOffset": 0, "byteLength": positions_len, "target": 34962 },
            { "buffer": 0, "byteOffset": positions_len, "byteLength": bin.len() - positions_len, "target": 34963 },
        ]);
        doc["accessors"] = json!([
            { "bufferView": 0, "componentType": 5126, "count": mesh.positions.len(), "type": "VEC3",
              "min": lo.to_array(), "max": hi.to_array() },
            { "bufferView": 1, "componentType": 5125, "count": mesh.triangles.len() * 3, "type": "SCALAR" },
        ]);
        doc["materials"] = json!([{ "name": "occluder", "doubleSided": false }]);
        doc["meshes"] = json!([{ "name": "occluder",
            "primitives": [{ "attributes": { "POSITION": 0 }, "indices": 1, "material": 0, "mode": 4 }] }]);
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
