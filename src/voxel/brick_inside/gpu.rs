//! Host code for shaders/brick_inside.wgsl; the twins are [`super::entries`] and
//! [`super::classify`]. Bricks go to the device in chunks whose surface bytes fit one binding.

use super::{Bits, ROWS, Rows, WAYS};
use crate::gpu::{Gpu, GpuError};
use crate::voxel::bricks::BRICK_VOXELS;
use crate::voxel::gpu::voxel_shader;

const SHADER: &str = voxel_shader!("brick_inside.wgsl");

/// Twin of [`super::entries`].
pub fn entries(gpu: &Gpu, surface: &[[u8; BRICK_VOXELS]]) -> Result<Vec<Rows>, GpuError> {
    let mut out = Vec::with_capacity(surface.len());
    for chunk in surface.chunks(bricks_per_chunk(gpu)?) {
        let rows = gpu.zeroed((chunk.len() * ROWS * WAYS) as u64);
        gpu.run(|gpu| {
            dispatch(gpu, "entries", chunk, &rows, None);
            out.extend(gpu.read::<Rows>(&rows)?);
            Ok(())
        })?;
    }
    Ok(out)
}

/// Twin of [`super::classify`].
pub fn classify(gpu: &Gpu, surface: &[[u8; BRICK_VOXELS]], beyond: &[Rows]) -> Result<Vec<Bits>, GpuError> {
    let per_chunk = bricks_per_chunk(gpu)?;
    let mut out = Vec::with_capacity(surface.len());
    for (chunk, beyond) in surface.chunks(per_chunk).zip(beyond.chunks(per_chunk)) {
        let rows = gpu.upload(beyond);
        let inside = gpu.zeroed((chunk.len() * BRICK_VOXELS / 8) as u64);
        gpu.run(|gpu| {
            dispatch(gpu, "classify", chunk, &rows, Some(&inside));
            out.extend(gpu.read::<Bits>(&inside)?);
            Ok(())
        })?;
    }
    Ok(out)
}

/// Bricks whose surface bytes fit one binding.
fn bricks_per_chunk(gpu: &Gpu) -> Result<usize, GpuError> {
    match (gpu.max_binding / BRICK_VOXELS as u64) as usize {
        0 => Err(GpuError::OutOfMemory(format!(
            "one brick's voxels exceed the adapter's largest storage binding ({} bytes)",
            gpu.max_binding
        ))),
        n => Ok(n),
    }
}

fn dispatch(
    gpu: &Gpu,
    entry: &'static str,
    surface: &[[u8; BRICK_VOXELS]],
    rows: &wgpu::Buffer,
    inside: Option<&wgpu::Buffer>,
) {
    // `Params` in shaders/common.wgsl: this stage reads only `items`, the bricks.
    let bricks = surface.len() as u32;
    let params = gpu.upload(&[0, 0, 0, 0, 0, bricks, 0, 0, 0u32]);
    let surface = gpu.upload(surface);
    let mut buffers = vec![(0, &params), (5, &surface), (6, rows)];
    buffers.extend(inside.map(|b| (7, b)));
    gpu.dispatch(SHADER, entry, &buffers, bricks);
}
