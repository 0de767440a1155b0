//! Host code for shaders/bricks.wgsl; the twin is [`super::fill`]. Bricks go to the device in
//! chunks whose voxels, pairs and triangles each fit one storage binding.

use super::{BRICK, BRICK_VOXELS, SLACK, Work};
use crate::gpu::{Gpu, GpuError};
use crate::voxel::gpu::voxel_shader;
use std::collections::HashMap;
use std::ops::Range;

/// The surface stage's test (shaders/surface.wgsl) is the bricks' test.
const SHADER: &str = concat!(
    voxel_shader!("surface.wgsl"),
    include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/shaders/bricks.wgsl"))
);

/// Bytes on the device per pair (an item) and per triangle (its corners).
const ITEM_BYTES: u64 = 16;
const TRIANGLE_BYTES: u64 = 36;

/// Twin of [`super::fill`].
pub fn fill(gpu: &Gpu, work: &Work) -> Result<Vec<[u8; BRICK_VOXELS]>, GpuError> {
    gpu.run(|gpu| {
        let mut filled = Vec::with_capacity(work.bricks.len());
        for bricks in chunks(gpu, work)? {
            filled.extend(fill_chunk(gpu, work, bricks)?);
        }
        Ok(filled)
    })
}

/// Runs of bricks whose voxels, items and triangles each fit one binding.
fn chunks(gpu: &Gpu, work: &Work) -> Result<Vec<Range<usize>>, GpuError> {
    let fits = |bricks: u64, pairs: u64| {
        bricks * BRICK_VOXELS as u64 <= gpu.max_binding
            && pairs * ITEM_BYTES <= gpu.max_binding
            && pairs * TRIANGLE_BYTES <= gpu.max_binding
    };
    let mut chunks = Vec::new();
    let mut start = 0;
    for b in 0..work.bricks.len() {
        let pairs = (work.starts[b + 1] - work.starts[start]) as u64;
        if !fits((b + 1 - start) as u64, pairs) {
            if b == start {
                return Err(GpuError::OutOfMemory(format!(
                    "one brick's {pairs} triangles exceed the adapter's largest storage binding ({} bytes)",
                    gpu.max_binding
                )));
            }
            chunks.push(start..b);
            start = b;
        }
    }
    if start < work.bricks.len() {
        chunks.push(start..work.bricks.len());
    }
    Ok(chunks)
}

fn fill_chunk(gpu: &Gpu, work: &Work, bricks: Range<usize>) -> Result<Vec<[u8; BRICK_VOXELS]>, GpuError> {
    // The chunk's own numbering of the triangles it needs.
    let mut numbers: HashMap<u32, u32> = HashMap::new();
    let mut corners: Vec<[[f32; 3]; 3]> = Vec::new();
    let mut items: Vec<[u32; 4]> = Vec::new();
    let mut origins: Vec<[u32; 4]> = Vec::with_capacity(bricks.len());
    for (slot, b) in bricks.clone().enumerate() {
        let first = (work.bricks[b] * BRICK).as_uvec3();
        origins.push([first.x, first.y, first.z, 0]);
        for &t in work.near(b) {
            let local = *numbers.entry(t).or_insert_with(|| {
                corners.push(work.triangles[t as usize]);
                corners.len() as u32 - 1
            });
            items.push([local, slot as u32, 0, u32::from(work.facing[t as usize])]);
        }
    }
    // `Params` in shaders/common.wgsl: the bricks stage reads only `items` and `half`.
    let params: [u32; 9] = [0, 0, 0, 0, 0, items.len() as u32, 0, (0.5 + SLACK).to_bits(), 0];
    let voxels = gpu.zeroed((bricks.len() * BRICK_VOXELS) as u64);
    gpu.dispatch(
        SHADER,
        "bricks",
        &[
            (0, &gpu.upload(&params)),
            (1, &gpu.upload(&corners)),
            (4, &gpu.upload(&items)),
            (5, &gpu.upload(&origins)),
            (6, &voxels),
        ],
        items.len() as u32,
    );
    let bytes: Vec<u8> = gpu.read(&voxels)?;
    Ok(bytes
        .chunks_exact(BRICK_VOXELS)
        .map(|b| b.try_into().expect("a brick's bytes"))
        .collect())
}
