//! A sparse bricked voxel grid (seed 004): blocks of 8³ voxels, allocated only where a triangle
//! touches, so that memory grows with the surface and not with the volume. Each voxel keeps
//! which ways the surface in it faces, for the questions a map asks of its free space: where a
//! floor is, and whether a wall seen from a point shows its front.
//!
//! The work runs brick by brick, in two steps. [`plan`] finds the bricks each triangle comes
//! near, by the separating-axis test at the bricks' scale, visiting only the bricks near the
//! triangle's plane (a map's large slanted faces would otherwise visit their whole bounding
//! boxes). [`fill`] then tests each pair's 512 voxels with the dense surface stage's test in
//! f32; its twin `shaders/bricks.wgsl` does the same with a workgroup per pair ([`gpu::fill`]).
//! The inside stage ([`super::brick_inside`]) then runs on the same bricks.

pub mod gpu;

use super::brick_inside::{self, Inside};
use super::surface::triangle_box_overlap;
use crate::gpu::Gpu;
use crate::mesh::Mesh;
use glam::{DVec3, IVec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// Voxels along each side of a brick.
pub const BRICK: i32 = 8;
pub const BRICK_VOXELS: usize = (BRICK * BRICK * BRICK) as usize;

/// Half a voxel plus this, in voxel units. The test runs in f32 on coordinates of up to
/// [`MAX_SIDE`] voxels, where a corner rounds by up to 5e-4 voxels: more slack than the dense
/// stage's, so that rounding never misses a touch.
const SLACK: f32 = 2e-3;
/// Most voxels along one side of a grid.
pub const MAX_SIDE: f64 = 8192.0;
/// A brick's half side plus margin, in bricks, for [`plan`]'s coarse test in f64: wider than
/// the voxels' slack, so that no pair the fine test would mark is left out.
const BRICK_HALF: f64 = 0.5 + 1e-2;

/// A voxel's bit when the surface in it faces +x, -x, +y, -y, +z or -z (the normal's component
/// along that way is over `FACING`); [`TOUCHED`] marks any surface at all.
pub const FACES: [u8; 6] = [1, 2, 4, 8, 16, 32];
pub const TOUCHED: u8 = 64;
const FACING: f64 = 0.3;

/// Most bricks one grid may hold (each is 512 bytes): 2 GiB.
pub const MAX_BRICKS: usize = 1 << 22;

#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub struct BrickStats {
    pub bricks: usize,
    /// The bricks' voxels and the index that finds them.
    pub bytes: usize,
    pub voxel_size: f64,
    /// Voxels along each axis of the bounds: the dense grid this one stands for.
    pub effective_resolution: [i32; 3],
    pub surface_voxels: usize,
    /// Voxels of the bricks that the inside stage finds inside the map (absent from reports
    /// cached before the stage existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inside_voxels: Option<usize>,
}

pub struct BrickGrid {
    origin: DVec3,
    voxel_size: f64,
    /// Voxels along each axis.
    dims: IVec3,
    index: HashMap<IVec3, u32>,
    bricks: Vec<[u8; BRICK_VOXELS]>,
    inside: Inside,
}

impl BrickGrid {
    /// The surface voxels of `mesh` at `voxel_size`, with a voxel of padding around its bounds,
    /// and which voxels lie inside the map, on `gpu` when one is given. Refuses a size that
    /// would need more than [`MAX_BRICKS`] bricks, estimated from the surface's area before
    /// anything is allocated, or more than [`MAX_SIDE`] voxels along a side.
    pub fn voxelize(mesh: &Mesh, voxel_size: f64, gpu: Option<&Gpu>) -> Result<BrickGrid, String> {
        let (lo, hi) = mesh.bounds();
        let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
        if !(voxel_size > 0.0 && voxel_size.is_finite()) {
            return Err(format!("voxel size {voxel_size} is not a positive number"));
        }
        let span = (hi - lo) / voxel_size + 3.0;
        if span.max_element() > MAX_SIDE {
            return Err(format!(
                "voxel size {voxel_size} is too small for bounds {lo} to {hi}: over {MAX_SIDE} voxels along a side"
            ));
        }
        let area: f64 = mesh
            .triangles_f64()
            .map(|[a, b, c]| 0.5 * (b - a).cross(c - a).length())
            .sum();
        // A flat face of area A touches about 3 A / s² voxels; a brick holds at least 64 of them.
        let estimate = 3.0 * area / (voxel_size * voxel_size) / 64.0 + mesh.triangles.len() as f64 / 64.0;
        if estimate > MAX_BRICKS as f64 {
            return Err(format!(
                "voxel size {voxel_size} needs about {estimate:.0} bricks for this surface, over the {MAX_BRICKS} allowed"
            ));
        }
        let origin = lo - voxel_size;
        let work = plan(mesh, origin, voxel_size);
        let filled = match gpu {
            Some(gpu) => gpu::fill(gpu, &work).map_err(|e| e.to_string())?,
            None => fill(&work),
        };
        // The coarse test's margin leaves some bricks with no voxel touched.
        let (coords, bricks): (Vec<IVec3>, Vec<[u8; BRICK_VOXELS]>) = work
            .bricks
            .iter()
            .zip(filled)
            .filter(|(_, voxels)| voxels.iter().any(|&v| v != 0))
            .map(|(&brick, voxels)| (brick, voxels))
            .unzip();
        let inside = brick_inside::build(&coords, &bricks, gpu).map_err(|e| e.to_string())?;
        Ok(BrickGrid {
            origin,
            voxel_size,
            dims: span.as_ivec3(),
            index: coords.into_iter().enumerate().map(|(b, c)| (c, b as u32)).collect(),
            bricks,
            inside,
        })
    }

    /// The surface bits of voxel `v`: 0 where no surface is, and off the grid.
    pub fn get(&self, v: IVec3) -> u8 {
        self.index
            .get(&v.div_euclid(IVec3::splat(BRICK)))
            .map_or(0, |&b| self.bricks[b as usize][offset(v)])
    }

    /// Whether voxel `v` lies inside the map: along each of ±x and ±z, the first surface met
    /// faces back towards it. Off the grid, no way meets a surface.
    pub fn inside(&self, v: IVec3) -> bool {
        self.contains(v)
            && self
                .inside
                .holds(v, self.index.get(&v.div_euclid(IVec3::splat(BRICK))).copied())
    }

    pub fn dims(&self) -> IVec3 {
        self.dims
    }

    pub fn voxel_size(&self) -> f64 {
        self.voxel_size
    }

    pub fn contains(&self, v: IVec3) -> bool {
        v.cmpge(IVec3::ZERO).all() && v.cmplt(self.dims).all()
    }

    /// The voxel holding `p` (possibly off the grid).
    pub fn voxel_of(&self, p: DVec3) -> IVec3 {
        ((p - self.origin) / self.voxel_size).floor().as_ivec3()
    }

    /// The world position of a point in voxel units: voxel v spans [v, v + 1].
    pub fn to_world(&self, v: DVec3) -> DVec3 {
        self.origin + v * self.voxel_size
    }

    /// Every voxel the surface touches, with its bits.
    pub fn surface_voxels(&self) -> impl Iterator<Item = (IVec3, u8)> + '_ {
        self.index.iter().flat_map(move |(&brick, &b)| {
            self.bricks[b as usize]
                .iter()
                .enumerate()
                .filter(|&(_, &bits)| bits != 0)
                .map(move |(i, &bits)| (brick * BRICK + local_voxel(i), bits))
        })
    }

    pub fn stats(&self) -> BrickStats {
        let entry = std::mem::size_of::<(IVec3, u32)>() + 1;
        BrickStats {
            bricks: self.bricks.len(),
            bytes: self.bricks.len() * BRICK_VOXELS + self.index.capacity() * entry + self.inside.bytes(),
            voxel_size: self.voxel_size,
            effective_resolution: (self.dims - 2).max(IVec3::ONE).to_array(),
            surface_voxels: self.bricks.iter().flatten().filter(|&&b| b != 0).count(),
            inside_voxels: Some(self.inside.voxels_in_bricks()),
        }
    }
}

/// Voxel `v`'s place in its brick: x fastest, then y, then z (as the shader writes them).
pub(super) fn offset(v: IVec3) -> usize {
    let l = v.rem_euclid(IVec3::splat(BRICK));
    (l.x + BRICK * (l.y + BRICK * l.z)) as usize
}

/// The voxel at place `i` of a brick, from the brick's first voxel.
fn local_voxel(i: usize) -> IVec3 {
    let i = i as i32;
    IVec3::new(i % BRICK, (i / BRICK) % BRICK, i / (BRICK * BRICK))
}

/// The facing bits of a triangle with unit normal `n`.
fn facing_bits(n: DVec3) -> u8 {
    let mut bits = TOUCHED;
    for axis in 0..3 {
        if n[axis] > FACING {
            bits |= FACES[2 * axis];
        } else if n[axis] < -FACING {
            bits |= FACES[2 * axis + 1];
        }
    }
    bits
}

/// What both twins of [`fill`] work from: the triangles in the grid's voxel units with their
/// facing bits, and for each brick touched, the triangles near it.
pub struct Work {
    pub triangles: Vec<[[f32; 3]; 3]>,
    pub facing: Vec<u8>,
    /// Each brick's coordinates, in bricks.
    pub bricks: Vec<IVec3>,
    /// `pairs[starts[b]..starts[b + 1]]` are the triangles near brick `b`.
    pub starts: Vec<usize>,
    pub pairs: Vec<u32>,
}

impl Work {
    pub fn near(&self, brick: usize) -> &[u32] {
        &self.pairs[self.starts[brick]..self.starts[brick + 1]]
    }
}

/// The bricks each triangle of `mesh` comes near, in a grid from `origin`, in order.
pub fn plan(mesh: &Mesh, origin: DVec3, voxel_size: f64) -> Work {
    let local: Vec<[DVec3; 3]> = mesh
        .triangles_f64()
        .map(|t| t.map(|p| (p - origin) / voxel_size))
        .collect();
    let facing: Vec<u8> = local
        .iter()
        .map(|[a, b, c]| (*b - *a).cross(*c - *a).try_normalize().map_or(0, facing_bits))
        .collect();
    let brick_size = f64::from(BRICK);
    let mut pairs: Vec<(IVec3, u32)> = local
        .par_iter()
        .enumerate()
        .filter(|&(t, _)| facing[t] != 0)
        .flat_map_iter(|(t, tri)| {
            let in_bricks = tri.map(|p| p / brick_size);
            touched_cells(&in_bricks, BRICK_HALF)
                .into_iter()
                .map(move |b| (b, t as u32))
        })
        .collect();
    pairs.par_sort_unstable_by_key(|&(b, t)| (b.x, b.y, b.z, t));
    let mut work = Work {
        triangles: local.iter().map(|t| t.map(|p| p.as_vec3().to_array())).collect(),
        facing,
        bricks: Vec::new(),
        starts: Vec::new(),
        pairs: pairs.iter().map(|&(_, t)| t).collect(),
    };
    for (i, &(brick, _)) in pairs.iter().enumerate() {
        if work.bricks.last() != Some(&brick) {
            work.bricks.push(brick);
            work.starts.push(i);
        }
    }
    work.starts.push(pairs.len());
    work
}

/// Each brick's voxels: the facing bits of every triangle near it that touches the voxel.
pub fn fill(work: &Work) -> Vec<[u8; BRICK_VOXELS]> {
    let half = [0.5 + SLACK; 3];
    (0..work.bricks.len())
        .into_par_iter()
        .map(|b| {
            let first = work.bricks[b] * BRICK;
            let mut voxels = [0; BRICK_VOXELS];
            for &t in work.near(b) {
                let tri = &work.triangles[t as usize];
                for (i, voxel) in voxels.iter_mut().enumerate() {
                    let v = first + local_voxel(i);
                    let centre = v.as_vec3().to_array().map(|c| c + 0.5);
                    if triangle_box_overlap(centre, half, tri) {
                        *voxel |= work.facing[t as usize];
                    }
                }
            }
            voxels
        })
        .collect()
}

/// The cells of unit size a triangle touches, by the separating-axis test with half side
/// `half`: for each column along the normal's largest axis, only the cells between the
/// plane's heights over that column.
fn touched_cells(tri: &[DVec3; 3], half: f64) -> Vec<IVec3> {
    let [a, b, c] = *tri;
    let Some(n) = (b - a).cross(c - a).try_normalize() else {
        return Vec::new();
    };
    let margin = half - 0.5;
    let first = (a.min(b).min(c) - margin).floor().as_ivec3();
    let last = (a.max(b).max(c) + margin).floor().as_ivec3();
    let d = n.abs().max_position();
    let (u, v) = ((d + 1) % 3, (d + 2) % 3);
    let corners = [a, b, c].map(|p| p.to_array());
    let mut out = Vec::new();
    for iu in first[u]..=last[u] {
        for iv in first[v]..=last[v] {
            // The plane's height along d over the column's four corners.
            let height = |pu: f64, pv: f64| (n.dot(a) - n[u] * pu - n[v] * pv) / n[d];
            let h = [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(du, dv)| height(f64::from(iu + du), f64::from(iv + dv)));
            let (h_lo, h_hi) = (
                h.iter().copied().fold(f64::INFINITY, f64::min),
                h.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            );
            let start = ((h_lo - half).floor() as i32).max(first[d]);
            let end = ((h_hi + half).floor() as i32).min(last[d]);
            for id in start..=end {
                let mut cell = IVec3::ZERO;
                cell[u] = iu;
                cell[v] = iv;
                cell[d] = id;
                let centre = (cell.as_dvec3() + 0.5).to_array();
                if triangle_box_overlap(centre, [half; 3], &corners) {
                    out.push(cell);
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::occluder::{WorldBox, merge::merge};

    #[test]
    fn a_box_touches_its_shell_and_faces_out() {
        let mesh = merge(&[WorldBox {
            lo: [0.0; 3],
            hi: [10.0, 10.0, 10.0],
        }]);
        let grid = BrickGrid::voxelize(&mesh, 1.0, None).expect("small grid");
        // The padded grid holds the box from voxel 1; the faces at 0 and 10 sit on voxel
        // boundaries, so each touches the two layers beside it.
        assert_eq!(grid.get(IVec3::new(5, 5, 5)), 0, "the inside is empty");
        let top = grid.get(IVec3::new(5, 11, 5));
        assert_ne!(top & FACES[2], 0, "the top faces +y: {top:b}");
        assert_eq!(top & FACES[3], 0);
        let side = grid.get(IVec3::new(0, 5, 5));
        assert_ne!(side & FACES[1], 0, "the -x side faces -x: {side:b}");
        let stats = grid.stats();
        // 12³ voxels of the padded box's shell at 1 voxel thick on each side of each face.
        assert!(
            stats.surface_voxels > 6 * 100 && stats.surface_voxels < 6 * 2 * 144,
            "{stats:?}"
        );
        assert!(stats.bricks <= 8, "{stats:?}");
    }

    #[test]
    fn a_slanted_triangle_touches_what_the_dense_test_does() {
        let mesh = Mesh {
            positions: vec![
                glam::Vec3::new(0.3, 0.2, 0.1),
                glam::Vec3::new(17.5, 3.1, 9.0),
                glam::Vec3::new(4.0, 15.2, 12.7),
            ],
            triangles: vec![[0, 1, 2]],
        };
        let grid = BrickGrid::voxelize(&mesh, 0.7, None).expect("small grid");
        let tri = mesh
            .corners(0)
            .map(|p| ((p.as_dvec3() - grid.origin) / 0.7).as_vec3().to_array());
        let half = 0.5 + SLACK;
        let mut dense = 0;
        for x in 0..grid.dims.x {
            for y in 0..grid.dims.y {
                for z in 0..grid.dims.z {
                    let v = IVec3::new(x, y, z);
                    let hit = triangle_box_overlap((v.as_vec3() + 0.5).to_array(), [half; 3], &tri);
                    assert_eq!(hit, grid.get(v) != 0, "voxel {v}");
                    dense += usize::from(hit);
                }
            }
        }
        assert_eq!(dense, grid.stats().surface_voxels);
    }

    #[test]
    fn a_voxel_too_small_for_the_surface_is_refused() {
        let mesh = merge(&[WorldBox {
            lo: [0.0; 3],
            hi: [1000.0, 1000.0, 1000.0],
        }]);
        let err = BrickGrid::voxelize(&mesh, 0.2, None).err().expect("refused");
        assert!(err.contains("bricks"), "{err}");
    }
}
