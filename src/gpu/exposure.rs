//! Host code for shaders/exposure.wgsl: which grid corners the exposure test's views see. The
//! twin is [`crate::occluder::exposure::OpenViews::remove_exposed`].

use super::{Gpu, GpuError, WORKGROUP};

const SHADER: &str = include_str!("../../shaders/exposure.wgsl");

/// Built when the device opens, like the voxel stages' entry points.
pub const ENTRY_POINTS: [(&str, &str); 1] = [(SHADER, "seen_corners")];

/// The corners of a grid of `corner_dims` (z fastest) that a view sees, one bit each, testing
/// only those set in `needed`. `rows` holds three rows a view, taking a corner in voxel units to
/// its pixel x, pixel y and depth plus the view's tolerance; `depths` the views' images of
/// `pixels` × `pixels`, one after another. `Unsupported` where an input exceeds a binding.
pub fn seen_corners(
    gpu: &Gpu,
    corner_dims: [usize; 3],
    needed: &[u32],
    rows: &[[f32; 4]],
    depths: &[f32],
    pixels: usize,
) -> Result<Vec<u32>, GpuError> {
    let corners = corner_dims.iter().product::<usize>();
    let too_large = u32::try_from(corners).is_err() || depths.len() as u64 * 4 > gpu.max_binding;
    if too_large {
        return Err(GpuError::Unsupported(
            "the depth images or the grid exceed the adapter's largest storage binding".into(),
        ));
    }
    gpu.run(|gpu| {
        let params = gpu.upload(&[
            corner_dims[1] as u32,
            corner_dims[2] as u32,
            corners as u32,
            (rows.len() / 3) as u32,
            pixels as u32,
        ]);
        let (needed, views, depths) = (gpu.upload(needed), gpu.upload(rows), gpu.upload(depths));
        let seen = gpu.zeroed(corners.div_ceil(32) as u64 * 4);
        gpu.dispatch(
            SHADER,
            "seen_corners",
            &[(0, &params), (1, &needed), (2, &views), (3, &depths), (4, &seen)],
            (corners as u32).div_ceil(WORKGROUP),
        );
        gpu.read(&seen)
    })
}
