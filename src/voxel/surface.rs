//! Conservative surface voxelization: every voxel that a triangle touches, by the
//! separating-axis triangle/box test of Akenine-Möller. The CPU twin of `shaders/surface.wgsl`:
//! the same f32 arithmetic in voxel units, term by term, so both mark the same voxels.

pub mod gpu;

use super::Grid;
use crate::mesh::Mesh;
use num_traits::Float;
use rayon::prelude::*;
use std::ops::Range;

/// Half a voxel plus this, in voxel units, so that rounding never misses a touch: extra
/// surface voxels only make the inner set smaller, which stays conservative.
pub const SLACK: f32 = 1e-4;

/// Which voxels some triangle touches.
pub fn voxelize(mesh: &Mesh, grid: &Grid) -> Vec<bool> {
    let triangles = grid.local_triangles(mesh);
    let [nx, ny, nz] = grid.dims;
    let half = 0.5 + SLACK;
    // Each thread's hits in one list, set in any order.
    let hits: Vec<Vec<usize>> = triangles
        .par_iter()
        .fold(Vec::new, |mut out, tri| {
            let spans = Grid::local_spans(tri, [nx, ny, nz]);
            let [xs, ys, zs]: [Range<usize>; 3] = std::array::from_fn(|k| facing(tri, k, spans[k].clone(), half));
            for x in xs {
                for y in ys.clone() {
                    for z in zs.clone() {
                        let centre = [x as f32 + 0.5, y as f32 + 0.5, z as f32 + 0.5];
                        if triangle_box_overlap(centre, [half; 3], tri) {
                            out.push((x * ny + y) * nz + z);
                        }
                    }
                }
            }
            out
        })
        .collect();
    let mut voxels = vec![false; grid.len()];
    for &v in hits.iter().flatten() {
        voxels[v] = true;
    }
    voxels
}

/// The voxels of `span` along axis k, less those at either end that the box's faces along k
/// separate from the triangle: [`triangle_box_overlap`] rejects them first thing, by the same
/// test, so only voxels that can pass are tested.
fn facing(tri: &[[f32; 3]; 3], k: usize, span: Range<usize>, half: f32) -> Range<usize> {
    let apart = |x: usize| faces_apart(tri, k, x as f32 + 0.5, half);
    let (mut start, mut end) = (span.start, span.end);
    while start < end && apart(start) {
        start += 1;
    }
    while end > start && apart(end - 1) {
        end -= 1;
    }
    start..end
}

fn separated<F: Float>(p: [F; 3], r: F) -> bool {
    let lo = p[0].min(p[1]).min(p[2]);
    let hi = p[0].max(p[1]).max(p[2]);
    lo > r || hi < -r
}

/// Whether the faces along axis k of a box `center ± half` there separate it from `tri`.
fn faces_apart<F: Float>(tri: &[[F; 3]; 3], k: usize, center: F, half: F) -> bool {
    separated(tri.map(|p| p[k] - center), half)
}

fn sub<F: Float>(a: [F; 3], b: [F; 3]) -> [F; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Whether triangle `tri` meets the closed box `center ± half` (Akenine-Möller 2001), at any
/// float precision. The order of every operation matches the shader's.
pub fn triangle_box_overlap<F: Float>(center: [F; 3], half: [F; 3], tri: &[[F; 3]; 3]) -> bool {
    // The box's face normals.
    if (0..3).any(|k| faces_apart(tri, k, center[k], half[k])) {
        return false;
    }
    let [a, b, d] = tri.map(|p| sub(p, center));
    let edges = [sub(b, a), sub(d, b), sub(a, d)];
    let (e0, e1) = (edges[0], edges[1]);
    // The triangle's plane.
    let n = [
        e0[1] * e1[2] - e0[2] * e1[1],
        e0[2] * e1[0] - e0[0] * e1[2],
        e0[0] * e1[1] - e0[1] * e1[0],
    ];
    let r = half[0] * n[0].abs() + half[1] * n[1].abs() + half[2] * n[2].abs();
    if (n[0] * a[0] + n[1] * a[1] + n[2] * a[2]).abs() > r {
        return false;
    }
    // The nine cross products of box axes and triangle edges.
    for e in edges {
        let project = |i: usize, j: usize| [a, b, d].map(|q| e[i] * q[j] - e[j] * q[i]);
        let rx = half[2] * e[1].abs() + half[1] * e[2].abs();
        let ry = half[0] * e[2].abs() + half[2] * e[0].abs();
        let rz = half[1] * e[0].abs() + half[0] * e[1].abs();
        if separated(project(1, 2), rx) || separated(project(2, 0), ry) || separated(project(0, 1), rz) {
            return false;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// Every voxel of the grid tested against every triangle: what `voxelize` must mark.
    fn touched_one_by_one(mesh: &Mesh, grid: &Grid) -> Vec<bool> {
        let half = [0.5 + SLACK; 3];
        let mut voxels = vec![false; grid.len()];
        for tri in grid.local_triangles(mesh) {
            for (v, voxel) in voxels.iter_mut().enumerate() {
                let centre = grid.coords(v).map(|c| c as f32 + 0.5);
                *voxel |= triangle_box_overlap(centre, half, &tri);
            }
        }
        voxels
    }

    #[test]
    fn voxels_left_out_of_each_triangles_span_are_those_no_test_would_mark() {
        let mut rng = fastrand::Rng::with_seed(5);
        let grid = Grid {
            origin: [0.0; 3],
            voxel_size: 1.0,
            dims: [9, 8, 7],
        };
        // Corners on voxel faces, just off them and anywhere: the ends of a span are decided
        // by a hair's breadth.
        let coordinate = |rng: &mut fastrand::Rng, n: usize| match rng.usize(0..3) {
            0 => rng.usize(0..=n) as f32,
            1 => rng.usize(0..=n) as f32 + [-1.0, 1.0][rng.usize(0..2)] * SLACK * rng.f32() * 2.0,
            _ => rng.f32() * n as f32,
        };
        let corner = |rng: &mut fastrand::Rng| Vec3::new(coordinate(rng, 9), coordinate(rng, 8), coordinate(rng, 7));
        for _ in 0..300 {
            let mut positions = Vec::new();
            for _ in 0..3 {
                let a = corner(&mut rng);
                // Small triangles too, within a voxel or two.
                let (b, c) = match rng.bool() {
                    true => (corner(&mut rng), corner(&mut rng)),
                    false => (a + Vec3::splat(0.3), a + Vec3::new(0.0, 0.9, -0.2)),
                };
                positions.extend([a, b, c]);
            }
            let mesh = Mesh {
                positions,
                triangles: vec![[0, 1, 2], [3, 4, 5], [6, 7, 8]],
            };
            assert_eq!(voxelize(&mesh, &grid), touched_one_by_one(&mesh, &grid));
        }
    }
}
