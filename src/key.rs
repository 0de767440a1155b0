//! Cache keys: BLAKE3 over the canonical welded geometry, the effective cook settings and the
//! pipeline version. The same geometry sent as OBJ or GLB, with vertices and triangles in any
//! order, gets the same key; a changed setting or pipeline gets another.

use crate::config::CookSettings;
use crate::mesh::Mesh;
use rayon::slice::ParallelSliceMut;

/// Bumped whenever the pipeline's output for the same input and settings can change.
pub const PIPELINE_VERSION: &str = "occluder-cook/pipeline/8";

pub fn cache_key(mesh: &Mesh, settings: &CookSettings) -> String {
    let bits = |t: usize| mesh.corners(t).map(|p| p.to_array().map(f32::to_bits));
    // Rotate each triangle to start at its smallest corner (winding kept), then sort.
    let mut triangles: Vec<[[u32; 3]; 3]> = (0..mesh.triangles.len())
        .map(|t| {
            let c = bits(t);
            let first = (0..3).min_by_key(|&k| c[k]).expect("three corners");
            [c[first], c[(first + 1) % 3], c[(first + 2) % 3]]
        })
        .collect();
    triangles.par_sort_unstable();
    let mut hasher = blake3::Hasher::new();
    hasher.update(PIPELINE_VERSION.as_bytes());
    hasher.update(&[0]);
    // A limit on what ingest reads refuses inputs but never changes an occluder.
    let mut settings = serde_json::to_value(settings).expect("settings serialize");
    settings
        .as_object_mut()
        .expect("settings are a table")
        .remove("max_placed_triangles");
    hasher.update(settings.to_string().as_bytes());
    hasher.update(&[0]);
    hasher.update(&(triangles.len() as u64).to_le_bytes());
    // In one update: fed four bytes at a time, the hasher's own overhead was most of this stage.
    let bytes: Vec<u8> = triangles
        .iter()
        .flatten()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    hasher.update(&bytes);
    hasher.finalize().to_hex().to_string()
}
