//! Faces hidden between touching occluders: where two placed solids meet face to face, the two
//! coincident, opposite triangles are inside the union and are dropped.
//!
//! Occluders sit a few float steps inside their meshes, so faces of touching meshes are apart by
//! about that much: corners match when they agree to within [`weld_tolerance`]. Dropping
//! triangles never hides more than before; the faces dropped could only be seen through the gap
//! between the two solids, at most that tolerance wide.

use crate::mesh::Mesh;
use std::collections::HashMap;

/// Drops from a closed `solid` every pair of coincident triangles facing opposite ways, and every
/// repeat of a triangle facing the same way. Returns how many triangles went.
pub fn remove_hidden_faces(solid: &mut Mesh) -> usize {
    let corner = welded_corners(solid, weld_tolerance(solid));
    // A triangle's corners, rotated so that the smallest comes first; orientation is kept.
    let canonical = |[a, b, c]: [u32; 3]| {
        let m = a.min(b).min(c);
        if m == a {
            [a, b, c]
        } else if m == b {
            [b, c, a]
        } else {
            [c, a, b]
        }
    };
    let mut open: HashMap<[u32; 3], Vec<usize>> = HashMap::new();
    let mut keep = vec![true; solid.triangles.len()];
    for (t, tri) in solid.triangles.iter().enumerate() {
        let [a, b, c] = canonical(tri.map(|i| corner[i as usize]));
        if a == b || b == c || a == c {
            // Smaller than the tolerance: no match is exact enough.
            continue;
        }
        if open.get(&[a, b, c]).is_some_and(|faces| !faces.is_empty()) {
            // The same face twice: once is enough.
            keep[t] = false;
            continue;
        }
        let opposite = canonical([a, c, b]);
        if let Some(faces) = open.get_mut(&opposite)
            && let Some(other) = faces.pop()
        {
            keep[t] = false;
            keep[other] = false;
            continue;
        }
        open.entry([a, b, c]).or_default().push(t);
    }
    let removed = keep.iter().filter(|k| !**k).count();
    if removed > 0 {
        let mut t = 0;
        solid.triangles.retain(|_| {
            t += 1;
            keep[t - 1]
        });
    }
    removed
}

/// A millionth of the mesh's size: far below a pixel at any distance the mesh is seen whole.
pub fn weld_tolerance(mesh: &Mesh) -> f64 {
    let (lo, hi) = crate::mesh::point_bounds(mesh.positions.iter().map(|p| p.as_dvec3()));
    ((hi - lo).max_element() * 1e-6).max(f64::from(f32::EPSILON))
}

/// For each vertex, the first vertex in the same cell of a grid `tolerance` wide.
fn welded_corners(mesh: &Mesh, tolerance: f64) -> Vec<u32> {
    let mut first = HashMap::with_capacity(mesh.positions.len());
    mesh.positions
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let cell = (p.as_dvec3() / tolerance).round().as_i64vec3().to_array();
            *first.entry(cell).or_insert(i as u32)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn quad(mesh: &mut Mesh, corners: [Vec3; 4]) {
        let base = mesh.positions.len() as u32;
        mesh.positions.extend(corners);
        mesh.triangles.push([base, base + 1, base + 2]);
        mesh.triangles.push([base, base + 2, base + 3]);
    }

    #[test]
    fn opposite_coincident_faces_go_and_others_stay() {
        let (a, b, c, d) = (Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y);
        let mut mesh = Mesh::default();
        quad(&mut mesh, [a, b, c, d]);
        quad(&mut mesh, [a, d, c, b]);
        // The same face again, and one only touching along an edge.
        quad(&mut mesh, [a, b, c, d]);
        quad(&mut mesh, [b, Vec3::new(2.0, 0.0, 0.0), Vec3::new(2.0, 1.0, 0.0), c]);
        assert_eq!(remove_hidden_faces(&mut mesh), 4);
        assert_eq!(mesh.triangles.len(), 4);
    }
}
