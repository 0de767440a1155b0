//! Parity solid voxelization (Schwarz & Seidel 2010): a voxel is inside when an odd number of
//! surface crossings lie above its centre. Correct only for watertight meshes.

pub mod gpu;

use super::{Grid, columns::ColumnCrossings};

pub fn classify(crossings: &ColumnCrossings, grid: &Grid) -> Vec<bool> {
    let columns = grid.dims[0] * grid.dims[1];
    (0..columns)
        .flat_map(|c| crossings.above(grid, c).map(|(_, count)| count % 2 == 1))
        .collect()
}
