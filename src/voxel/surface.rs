//! Conservative surface voxelization: every voxel that a triangle touches, by the
//! separating-axis triangle/box test of Akenine-Möller.

use super::Grid;
use crate::mesh::Mesh;
use glam::DVec3;
use rayon::prelude::*;

/// Surface voxels, and which triangles touch each of them.
pub struct Surface {
    pub voxels: Vec<bool>,
    /// (voxel index, triangle index), sorted.
    pub touches: Vec<(u32, u32)>,
}

impl Surface {
    /// The triangles that touch voxel `index`.
    pub fn triangles_in(&self, index: usize) -> impl Iterator<Item = u32> + '_ {
        let start = self.touches.partition_point(|&(v, _)| (v as usize) < index);
        self.touches[start..]
            .iter()
            .take_while(move |&&(v, _)| v as usize == index)
            .map(|&(_, t)| t)
    }
}

pub fn voxelize(mesh: &Mesh, grid: &Grid) -> Surface {
    // A hair of slack so that rounding never misses a touch: extra surface voxels only make
    // the inner set smaller, which stays conservative.
    let half = DVec3::splat(grid.voxel_size * (0.5 + 1e-6));
    let mut touches: Vec<(u32, u32)> = (0..mesh.triangles.len())
        .into_par_iter()
        .flat_map_iter(|t| {
            let tri = mesh.corners(t).map(|p| p.as_dvec3());
            let lo = tri[0].min(tri[1]).min(tri[2]);
            let hi = tri[0].max(tri[1]).max(tri[2]);
            let [rx, ry, rz] = grid.voxel_range(lo, hi);
            let mut hits = Vec::new();
            for x in rx {
                for y in ry.clone() {
                    for z in rz.clone() {
                        if triangle_box_overlap(grid.center(x, y, z), half, &tri) {
                            hits.push((grid.index(x, y, z) as u32, t as u32));
                        }
                    }
                }
            }
            hits
        })
        .collect();
    touches.par_sort_unstable();
    let mut voxels = vec![false; grid.len()];
    for &(v, _) in &touches {
        voxels[v as usize] = true;
    }
    Surface { voxels, touches }
}

/// Whether triangle `tri` meets the closed box `center ± half` (Akenine-Möller 2001).
pub fn triangle_box_overlap(center: DVec3, half: DVec3, tri: &[DVec3; 3]) -> bool {
    let v = tri.map(|p| p - center);
    // The box's face normals.
    for k in 0..3 {
        let (lo, hi) = (v[0][k].min(v[1][k]).min(v[2][k]), v[0][k].max(v[1][k]).max(v[2][k]));
        if lo > half[k] || hi < -half[k] {
            return false;
        }
    }
    let edges = [v[1] - v[0], v[2] - v[1], v[0] - v[2]];
    // The triangle's plane.
    let normal = edges[0].cross(edges[1]);
    let radius = half.dot(normal.abs());
    if normal.dot(v[0]).abs() > radius {
        return false;
    }
    // The nine cross products of box axes and triangle edges.
    for e in edges {
        for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
            let a = axis.cross(e);
            let p = v.map(|q| a.dot(q));
            let r = half.dot(a.abs());
            if p[0].min(p[1]).min(p[2]) > r || p[0].max(p[1]).max(p[2]) < -r {
                return false;
            }
        }
    }
    true
}
