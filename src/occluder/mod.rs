//! From inner voxels to an occluder: box expansion, sub-voxel refinement, selection by
//! silhouette, and the merge into one watertight mesh.

pub mod boxes;
pub mod distance;
pub mod exposure;
pub mod merge;
pub mod refine;
pub mod select;

use glam::DVec3;
use serde::Serialize;

/// The six faces of a box over its corners (corner i has bit 0 for x, 1 for y, 2 for z set at
/// the maximum), each a counter-clockwise quad seen from outside: -x, +x, -y, +y, -z, +z.
pub const BOX_FACES: [[usize; 4]; 6] = [
    [0, 4, 6, 2],
    [1, 3, 7, 5],
    [0, 1, 5, 4],
    [2, 6, 7, 3],
    [0, 2, 3, 1],
    [4, 5, 7, 6],
];

/// An axis-aligned box in world space.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct WorldBox {
    pub lo: [f64; 3],
    pub hi: [f64; 3],
}

impl WorldBox {
    /// The world-space extent of a box of voxels.
    pub fn from_voxels(grid: &crate::voxel::Grid, b: &boxes::VoxelBox) -> WorldBox {
        let at = |v: [usize; 3]| grid.to_world(DVec3::from_array(v.map(|c| c as f64))).to_array();
        WorldBox {
            lo: at(b.lo),
            hi: at(b.hi),
        }
    }

    pub fn lo(&self) -> DVec3 {
        DVec3::from_array(self.lo)
    }

    pub fn hi(&self) -> DVec3 {
        DVec3::from_array(self.hi)
    }

    pub fn volume(&self) -> f64 {
        (self.hi() - self.lo()).max(DVec3::ZERO).element_product()
    }

    pub fn corners(&self) -> [DVec3; 8] {
        std::array::from_fn(|i| {
            DVec3::new(
                if i & 1 == 0 { self.lo[0] } else { self.hi[0] },
                if i & 2 == 0 { self.lo[1] } else { self.hi[1] },
                if i & 4 == 0 { self.lo[2] } else { self.hi[2] },
            )
        })
    }

    /// The 12 outward-facing triangles of the box.
    pub fn triangles(&self) -> [[DVec3; 3]; 12] {
        let c = self.corners();
        let mut out = [[DVec3::ZERO; 3]; 12];
        for (f, q) in BOX_FACES.iter().enumerate() {
            out[2 * f] = [c[q[0]], c[q[1]], c[q[2]]];
            out[2 * f + 1] = [c[q[0]], c[q[2]], c[q[3]]];
        }
        out
    }
}
