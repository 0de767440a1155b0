//! Voxelization: the grid, the surface voxels, and the inside/outside classification.
//!
//! Each stage works on flat `Vec<bool>` grids indexed by [`Grid::index`]. The surface, parity,
//! winding and cpsv stages have GPU twins, each in its stage's `gpu` module beside it; given a
//! device, these functions run those.

pub mod brick_inside;
pub mod bricks;
pub mod columns;
pub mod cpsv;
mod gpu;
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
    /// What the empty space sees: cube maps rendered from octree cells, votes between them
    /// (the seed article's Complete Polygonal Scene Voxelization).
    Cpsv,
}

/// Which voxels some triangle touches, on `gpu` when given.
pub fn surface(mesh: &Mesh, grid: &Grid, gpu: Option<&Gpu>) -> Result<Vec<bool>, GpuError> {
    match gpu {
        Some(gpu) => surface::gpu::voxelize(gpu, mesh, grid),
        None => Ok(surface::voxelize(mesh, grid)),
    }
}

/// The inside/outside classification of every voxel.
#[derive(Clone, Debug, Default)]
pub struct Classified {
    pub solid: Vec<bool>,
    /// What `cpsv` found, when it ran.
    pub cpsv: Option<cpsv::CpsvStats>,
}

/// Which voxel centres lie inside the solid, on `gpu` when given. `cpsv` decides whole cells of
/// empty space (the `surface` voxels count as solid).
pub fn classify(
    method: InsideMethod,
    mesh: &Mesh,
    topology: &Topology,
    grid: &Grid,
    surface: &[bool],
    settings: &cpsv::CpsvSettings,
    gpu: Option<&Gpu>,
) -> Result<Classified, GpuError> {
    let solid = |solid| Classified { solid, cpsv: None };
    if method == InsideMethod::Cpsv {
        let (solid, stats) = cpsv::classify(mesh, grid, surface, settings, gpu)?;
        return Ok(Classified {
            solid,
            cpsv: Some(stats),
        });
    }
    if let Some(gpu) = gpu {
        return match method {
            InsideMethod::Parity => parity::gpu::classify(gpu, mesh, grid),
            _ => winding::gpu::classify(gpu, mesh, &topology.boundary, grid),
        }
        .map(solid);
    }
    let crossings = columns::ColumnCrossings::build(mesh, grid);
    Ok(solid(match method {
        InsideMethod::Parity => parity::classify(&crossings, grid),
        _ => winding::classify(&crossings, mesh, &topology.boundary, grid),
    }))
}
