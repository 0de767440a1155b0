//! Voxelization: the grid, the surface voxels, and the inside/outside classification.
//!
//! Each stage works on flat `Vec<bool>` grids indexed by [`Grid::index`]. The surface, parity and
//! winding stages have GPU twins in [`crate::gpu::voxel`]; given a device, these functions run
//! those.

pub mod columns;
pub mod grid;
pub mod parity;
pub mod surface;
pub mod winding;

use crate::gpu::{Gpu, GpuError};
use crate::mesh::{Mesh, Topology};
pub use grid::Grid;
use serde::{Deserialize, Serialize};

/// How voxels are classified as inside or outside the mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum InsideMethod {
    /// Generalized winding number ≥ 0.5: exact on closed meshes, robust to holes and soups.
    Winding,
    /// Crossing-count parity along columns: correct only for watertight meshes; the baseline.
    Parity,
}

/// Which voxels some triangle touches, on `gpu` when given.
pub fn surface(mesh: &Mesh, grid: &Grid, gpu: Option<&Gpu>) -> Result<Vec<bool>, GpuError> {
    match gpu {
        Some(gpu) => crate::gpu::voxel::surface(gpu, mesh, grid),
        None => Ok(surface::voxelize(mesh, grid)),
    }
}

/// Which voxel centres lie inside the solid, on `gpu` when given.
pub fn classify(
    method: InsideMethod,
    mesh: &Mesh,
    topology: &Topology,
    grid: &Grid,
    gpu: Option<&Gpu>,
) -> Result<Vec<bool>, GpuError> {
    if let Some(gpu) = gpu {
        return match method {
            InsideMethod::Winding => crate::gpu::voxel::winding(gpu, mesh, &topology.boundary, grid),
            InsideMethod::Parity => crate::gpu::voxel::parity(gpu, mesh, grid),
        };
    }
    let crossings = columns::ColumnCrossings::build(mesh, grid);
    Ok(match method {
        InsideMethod::Winding => winding::classify(&crossings, mesh, &topology.boundary, grid),
        InsideMethod::Parity => parity::classify(&crossings, grid),
    })
}
