//! From the solid to an occluder: boxes where it is thick (expansion, sub-voxel refinement,
//! the merge into one watertight mesh), quads inside it and patches on its surface where it is
//! thin or flat, the mesh's own flat regions as surface pieces, and the selection of what covers
//! the most silhouette per triangle.

pub mod boxes;
pub mod distance;
pub mod exposure;
pub mod merge;
pub mod patches;
pub mod quads;
pub mod rectangle;
pub mod refine;
pub mod select;
pub mod surface_pieces;

use crate::mesh::Mesh;
use glam::{DVec3, Vec3};
use serde::{Deserialize, Serialize};
pub use surface_pieces::SurfacePiece;

/// The kinds of occluder pieces (`cook.shapes`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Shape {
    /// Boxes of inner voxels, merged into one watertight mesh.
    Boxes,
    /// Rectangles on an axis plane, inside the solid over their whole area.
    Quads,
    /// Rectangles on flat parts of the surface itself.
    Patches,
    /// Flat regions of the surface itself, outlines triangulated again.
    Surface,
}

/// A double-sided rectangle: an in-solid quad or an on-surface patch.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Panel {
    pub shape: Shape,
    /// The corners, in order around the rectangle.
    pub corners: [[f64; 3]; 4],
}

impl Panel {
    pub fn triangles(&self) -> [[DVec3; 3]; 2] {
        let c = self.corners.map(DVec3::from_array);
        [[c[0], c[1], c[2]], [c[0], c[2], c[3]]]
    }

    pub fn area(&self) -> f64 {
        let c = self.corners.map(DVec3::from_array);
        (c[1] - c[0]).length() * (c[3] - c[0]).length()
    }
}

/// A cooked occluder: the watertight union of the chosen boxes, double-sided panels, and surface
/// pieces (double-sided, but for closed parts chosen whole, which face out with the solid).
#[derive(Clone, Debug, Default)]
pub struct Occluder {
    pub solid: Mesh,
    pub panels: Vec<Panel>,
    pub pieces: Vec<SurfacePiece>,
}

impl Occluder {
    /// Everything as one mesh, as a depth test sees it.
    pub fn mesh(&self) -> Mesh {
        let mut mesh = self.single_sided();
        mesh.append(&self.double_sided());
        mesh
    }

    /// The solid and the surface pieces of closed parts chosen whole: the part drawn facing out.
    pub fn single_sided(&self) -> Mesh {
        let mut mesh = self.solid.clone();
        mesh.append(&self.pieces_mesh(false));
        mesh
    }

    /// The panels and the other surface pieces: the part drawn double-sided.
    pub fn double_sided(&self) -> Mesh {
        let mut mesh = panel_mesh(&self.panels);
        mesh.append(&self.pieces_mesh(true));
        mesh
    }

    fn pieces_mesh(&self, double_sided: bool) -> Mesh {
        surface_pieces::pieces_mesh(self.pieces.iter().filter(|p| p.double_sided == double_sided))
    }

    pub fn triangles(&self) -> usize {
        self.solid.triangles.len() + 2 * self.panels.len() + self.piece_triangles()
    }

    /// Vertices of its GLB: the solid's, four a panel and three a surface piece's triangle.
    pub fn vertices(&self) -> usize {
        self.solid.positions.len() + 4 * self.panels.len() + 3 * self.piece_triangles()
    }

    fn piece_triangles(&self) -> usize {
        self.pieces.iter().map(|p| p.triangles.len()).sum()
    }
}

/// The names of an occluder GLB's two primitives: the watertight solid, and the double-sided
/// panels.
pub const SOLID_PART: &str = "occluder-solid";
pub const PANELS_PART: &str = "occluder-panels";

/// The panels as one triangle mesh, two triangles each.
pub fn panel_mesh(panels: &[Panel]) -> Mesh {
    Mesh {
        positions: panels
            .iter()
            .flat_map(|p| p.corners.map(|c| Vec3::from_array(c.map(|x| x as f32))))
            .collect(),
        triangles: (0..panels.len() as u32)
            .flat_map(|i| [[4 * i, 4 * i + 1, 4 * i + 2], [4 * i, 4 * i + 2, 4 * i + 3]])
            .collect(),
    }
}

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

    /// The largest box whose corners f32 holds exactly, so that writing it moves none of them,
    /// within this one with every face moved `by` inwards; none where nothing is left.
    pub fn rounded_inward(&self, by: f64) -> Option<WorldBox> {
        let up = |x: f64| {
            let f = x as f32;
            if f64::from(f) < x { f.next_up() } else { f }
        };
        let down = |x: f64| {
            let f = x as f32;
            if f64::from(f) > x { f.next_down() } else { f }
        };
        let (lo, hi) = (self.lo.map(|x| up(x + by)), self.hi.map(|x| down(x - by)));
        (0..3).all(|k| lo[k] < hi[k]).then(|| WorldBox {
            lo: lo.map(f64::from),
            hi: hi.map(f64::from),
        })
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

#[cfg(test)]
mod tests {
    use super::WorldBox;

    #[test]
    fn a_box_rounded_inward_lies_within_and_f32_holds_its_corners() {
        let b = WorldBox {
            lo: [3e5 + 0.01, -7e5 - 0.013, 0.1],
            hi: [3e5 + 1.37, -7e5 + 0.9, 0.3],
        };
        let exact = |x: f64| f64::from(x as f32) == x;
        for by in [0.0, 0.05] {
            let r = b.rounded_inward(by).expect("room left");
            for k in 0..3 {
                assert!(b.lo[k] + by <= r.lo[k] && r.hi[k] <= b.hi[k] - by, "{r:?}");
                assert!(exact(r.lo[k]) && exact(r.hi[k]), "{r:?}");
                // No f32 between the bound and the rounded corner.
                assert!(f64::from((r.lo[k] as f32).next_down()) < b.lo[k] + by);
            }
        }
        assert_eq!(b.rounded_inward(0.2), None);
    }
}
