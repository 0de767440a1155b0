//! Voxelization: the grid, the surface voxels, and the inside/outside classification.
//!
//! Each stage works on flat `Vec<bool>` grids indexed by [`Grid::index`], so that the GPU twins
//! of a later stage can share the layout.

pub mod columns;
pub mod grid;
pub mod parity;
pub mod surface;
pub mod winding;

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

/// Which voxel centres lie inside the solid.
pub fn classify(method: InsideMethod, mesh: &Mesh, topology: &Topology, grid: &Grid) -> Vec<bool> {
    let crossings = columns::ColumnCrossings::build(mesh, grid);
    match method {
        InsideMethod::Winding => winding::classify(&crossings, mesh, &topology.boundary, grid),
        InsideMethod::Parity => parity::classify(&crossings, grid),
    }
}
