//! Host code for shaders/surface.wgsl; the twin is [`super::voxelize`].

use crate::gpu::{Gpu, GpuError};
use crate::mesh::Mesh;
use crate::voxel::Grid;
use crate::voxel::gpu::{Units, bit_stage, voxel_shader};

const SHADER: &str = voxel_shader!("surface.wgsl");

/// Built when a cook opens the device, so that no cook pays for shader compilation.
pub const ENTRY_POINTS: [(&str, &str); 1] = [(SHADER, "surface")];

/// Twin of [`super::voxelize`].
pub fn voxelize(gpu: &Gpu, mesh: &Mesh, grid: &Grid) -> Result<Vec<bool>, GpuError> {
    bit_stage(gpu, (SHADER, "surface"), Units::Voxels, mesh, grid)
}
