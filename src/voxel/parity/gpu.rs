//! Host code for shaders/parity.wgsl; the twin is [`super::classify`].

use crate::gpu::{Gpu, GpuError};
use crate::mesh::Mesh;
use crate::voxel::Grid;
use crate::voxel::gpu::{Units, bit_stage, voxel_shader};

const SHADER: &str = voxel_shader!("parity.wgsl");

/// Built when a cook opens the device, like the surface stage's.
pub const ENTRY_POINTS: [(&str, &str); 1] = [(SHADER, "parity")];

/// Twin of [`super::classify`].
pub fn classify(gpu: &Gpu, mesh: &Mesh, grid: &Grid) -> Result<Vec<bool>, GpuError> {
    bit_stage(gpu, (SHADER, "parity"), Units::Columns, mesh, grid)
}
