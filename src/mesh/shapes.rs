//! Meshes made in code: the built-in sample of `demo`, and shapes whose inside is known.

use super::Mesh;
use glam::Vec3;

/// A torus around the y axis with outward-facing triangles.
pub fn torus(major: f32, minor: f32, segments: u32, sides: u32) -> Mesh {
    let mut mesh = Mesh::default();
    for i in 0..segments {
        let u = i as f32 / segments as f32 * std::f32::consts::TAU;
        for j in 0..sides {
            let v = j as f32 / sides as f32 * std::f32::consts::TAU;
            let r = major + minor * v.cos();
            mesh.positions
                .push(Vec3::new(r * u.cos(), minor * v.sin(), r * u.sin()));
        }
    }
    let at = |i: u32, j: u32| (i % segments) * sides + (j % sides);
    for i in 0..segments {
        for j in 0..sides {
            let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
            mesh.triangles.push([a, c, b]);
            mesh.triangles.push([a, d, c]);
        }
    }
    mesh
}
