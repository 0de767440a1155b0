//! Sub-voxel refinement: a box made of inner voxels stops up to a voxel short of the surface.
//! Each face is pushed outwards, at most one voxel, until the grown slab would touch a triangle.
//! The slab may only enter voxels whose centres are inside the solid and that no other box
//! claims, so it can neither slip out through a hole nor cover another box.

use super::{WorldBox, boxes::VoxelBox};
use crate::mesh::Mesh;
use crate::voxel::{Grid, surface::triangle_box_overlap, winding::WindingField};
use glam::DVec3;

/// Binary-search steps: the face ends within voxel_size / 2^16 of the surface.
const STEPS: usize = 16;

pub struct RefineInput<'a> {
    pub mesh: &'a Mesh,
    pub grid: &'a Grid,
    /// Finds the triangles near a slab.
    pub field: &'a WindingField<'a>,
    pub solid: &'a [bool],
    /// Box id per voxel, `u32::MAX` where none.
    pub owner: &'a [u32],
}

/// `b` (box number `id`) in world space, its faces pushed out towards the surface.
pub fn refine(input: &RefineInput, id: u32, b: &VoxelBox) -> WorldBox {
    let grid = input.grid;
    let to_world = |v: [usize; 3]| grid.to_world(DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64));
    let (mut lo, mut hi) = (to_world(b.lo), to_world(b.hi));
    for axis in 0..3 {
        for positive in [false, true] {
            let push = max_push(input, id, lo, hi, axis, positive);
            if positive {
                hi[axis] += push;
            } else {
                lo[axis] -= push;
            }
        }
    }
    WorldBox {
        lo: lo.to_array(),
        hi: hi.to_array(),
    }
}

/// How far the face (axis, side) of box [lo, hi] can move outwards.
fn max_push(input: &RefineInput, id: u32, lo: DVec3, hi: DVec3, axis: usize, positive: bool) -> f64 {
    let h = input.grid.voxel_size;
    let slab = |t: f64| {
        let (mut a, mut b) = (lo, hi);
        if positive {
            a[axis] = hi[axis];
            b[axis] = hi[axis] + t;
        } else {
            a[axis] = lo[axis] - t;
            b[axis] = lo[axis];
        }
        (a, b)
    };
    // The voxels the largest slab would enter, shrunk a little so that neighbours that the
    // slab only touches at a face do not count.
    let (a, b) = slab(h);
    let inset = h * 1e-6;
    let origin = input.grid.origin();
    let first = ((a + inset - origin) / h).floor();
    let last = ((b - inset - origin) / h).floor();
    let dims = input.grid.dims;
    for x in first.x as i64..=last.x as i64 {
        for y in first.y as i64..=last.y as i64 {
            for z in first.z as i64..=last.z as i64 {
                if x < 0 || y < 0 || z < 0 || x >= dims[0] as i64 || y >= dims[1] as i64 || z >= dims[2] as i64 {
                    return 0.0;
                }
                let index = input.grid.index(x as usize, y as usize, z as usize);
                let owner = input.owner[index];
                if !input.solid[index] || (owner != u32::MAX && owner != id) {
                    return 0.0;
                }
            }
        }
    }
    // Every slab tried lies within the largest one, so only triangles whose bounds meet it
    // can block.
    let corners: Vec<[[f64; 3]; 3]> = input
        .field
        .triangles_over(a.truncate(), b.truncate())
        .into_iter()
        .map(|t| input.mesh.corners(t as usize).map(|p| p.as_dvec3()))
        .filter(|tri| {
            let lo = tri[0].min(tri[1]).min(tri[2]);
            let hi = tri[0].max(tri[1]).max(tri[2]);
            lo.cmple(b).all() && hi.cmpge(a).all()
        })
        .map(|tri| tri.map(|p| p.to_array()))
        .collect();
    let touches = |t: f64| {
        let (a, b) = slab(t);
        let (center, half) = ((a + b) * 0.5, (b - a) * 0.5);
        corners
            .iter()
            .any(|tri| triangle_box_overlap(center.to_array(), half.to_array(), tri))
    };
    if !touches(h) {
        return h;
    }
    let (mut free, mut blocked) = (0.0, h);
    for _ in 0..STEPS {
        let mid = 0.5 * (free + blocked);
        if touches(mid) {
            blocked = mid;
        } else {
            free = mid;
        }
    }
    free
}
