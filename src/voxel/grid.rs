//! A cubic-voxel grid fitted around a mesh, padded by one voxel on every side.

use crate::mesh::Mesh;
use glam::{DVec3, Vec3};
use serde::Serialize;
use std::ops::Range;

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Grid {
    /// The minimum corner of voxel (0, 0, 0).
    pub origin: [f64; 3],
    /// Edge length of one voxel.
    pub voxel_size: f64,
    /// Voxels along x, y and z.
    pub dims: [usize; 3],
}

impl Grid {
    /// `resolution` voxels along the longest axis of the bounds, plus one voxel of padding.
    pub fn fit(lo: Vec3, hi: Vec3, resolution: usize) -> Grid {
        let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
        let extent = hi - lo;
        let longest = extent.max_element();
        let voxel_size = if longest > 0.0 {
            longest / resolution as f64
        } else {
            1.0
        };
        let dims = extent.to_array().map(|e| ((e / voxel_size).ceil() as usize).max(1) + 2);
        // Centre the mesh in the padded grid.
        let span = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64) * voxel_size;
        let origin = (lo + hi) * 0.5 - span * 0.5;
        Grid {
            origin: origin.to_array(),
            voxel_size,
            dims,
        }
    }

    pub fn len(&self) -> usize {
        self.dims.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Flat index; z varies fastest so that a column along z is contiguous.
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        (x * self.dims[1] + y) * self.dims[2] + z
    }

    pub fn coords(&self, index: usize) -> [usize; 3] {
        let z = index % self.dims[2];
        let xy = index / self.dims[2];
        [xy / self.dims[1], xy % self.dims[1], z]
    }

    pub fn origin(&self) -> DVec3 {
        DVec3::from_array(self.origin)
    }

    /// World position of a point given in voxel units (voxel (i, j, k) spans [i, i + 1]).
    pub fn to_world(&self, v: DVec3) -> DVec3 {
        self.origin() + v * self.voxel_size
    }

    /// [`crate::geom::f32_slack`] over the grid.
    pub fn f32_slack(&self) -> f64 {
        let far = self.to_world(DVec3::from_array(self.dims.map(|n| n as f64)));
        crate::geom::f32_slack(self.origin(), far)
    }

    pub fn center(&self, x: usize, y: usize, z: usize) -> DVec3 {
        self.to_world(DVec3::new(x as f64, y as f64, z as f64) + 0.5)
    }

    /// The index of the voxel holding `p`, if it is on the grid.
    pub fn containing(&self, p: DVec3) -> Option<usize> {
        let v = (p - self.origin()) / self.voxel_size;
        let inside = (0..3).all(|k| v[k] >= 0.0 && (v[k] as usize) < self.dims[k]);
        inside.then(|| self.index(v.x as usize, v.y as usize, v.z as usize))
    }

    /// The voxels whose closed extent meets the box [lo, hi], clamped to the grid.
    pub fn voxel_range(&self, lo: DVec3, hi: DVec3) -> [Range<usize>; 3] {
        let a = (lo - self.origin()) / self.voxel_size;
        let b = (hi - self.origin()) / self.voxel_size;
        std::array::from_fn(|k| {
            let start = (a[k].floor() as i64 - 1).clamp(0, self.dims[k] as i64) as usize;
            let end = (b[k].floor() as i64 + 2).clamp(0, self.dims[k] as i64) as usize;
            start..end
        })
    }

    /// Each triangle's corners in voxel units (voxel (i, j, k) spans [i, i + 1]): what the GPU
    /// voxel stages and their CPU twins read.
    pub fn local_triangles(&self, mesh: &Mesh) -> Vec<[[f32; 3]; 3]> {
        (0..mesh.triangles.len())
            .map(|t| mesh.corners(t).map(|p| self.local(p.as_dvec3())))
            .collect()
    }

    /// `p` in voxel units, rounded once to f32.
    pub fn local(&self, p: DVec3) -> [f32; 3] {
        ((p - self.origin()) / self.voxel_size).as_vec3().to_array()
    }

    /// The voxels whose closed extent meets a triangle's bounds, in voxel units: as
    /// [`Grid::voxel_range`], in the shaders' f32 arithmetic (`voxel_span` in common.wgsl).
    pub fn local_spans(tri: &[[f32; 3]; 3], dims: [usize; 3]) -> [Range<usize>; 3] {
        std::array::from_fn(|k| {
            let lo = tri[0][k].min(tri[1][k]).min(tri[2][k]);
            let hi = tri[0][k].max(tri[1][k]).max(tri[2][k]);
            let n = dims[k] as i32;
            let start = (lo.floor() as i32 - 1).clamp(0, n) as usize;
            let end = (hi.floor() as i32 + 2).clamp(0, n) as usize;
            start..end
        })
    }
}
