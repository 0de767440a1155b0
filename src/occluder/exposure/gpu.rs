//! Host code for shaders/exposure.wgsl: which grid corners the exposure test's views see. The
//! twin is [`super::OpenViews::remove_exposed`].

use super::{MAX_VIEWS, TILE};
use crate::gpu::{Gpu, GpuError};

const SHADER: &str = include_str!("../../../shaders/exposure.wgsl");

/// Built when a cook opens the device, like the voxel stages' entry points.
pub const ENTRY_POINTS: [(&str, &str); 1] = [(SHADER, "seen_corners")];

/// The length of the shader's uniform array of view rows: five a view, for the most views.
const VIEW_ROWS: usize = 1880;
const _: () = assert!(VIEW_ROWS >= 5 * MAX_VIEWS);

/// The corners of a grid of `corner_dims` (z fastest) that a view sees, one bit each, testing
/// only those set in `needed`: (word, its bits) for each word with a bit set. `rows` holds five
/// rows a view as the shader reads them; `depths` the views' images of `pixels` × `pixels`, one
/// after another, and `tiles` the farthest depth of each of their tiles of `TILE` × `TILE`
/// pixels.
/// `Unsupported` where an input exceeds a binding or the shader's arrays.
pub fn seen_corners(
    gpu: &Gpu,
    corner_dims: [usize; 3],
    needed: &[[u32; 2]],
    rows: &[[f32; 4]],
    depths: &[f32],
    tiles: &[f32],
    pixels: usize,
) -> Result<Vec<u32>, GpuError> {
    let corners = corner_dims.iter().product::<usize>();
    let unfit = u32::try_from(corners).is_err()
        || depths.len() as u64 * 4 > gpu.max_binding
        || rows.len() > VIEW_ROWS
        || !pixels.is_multiple_of(TILE);
    if unfit {
        return Err(GpuError::Unsupported(
            "the depth images, views or grid exceed a binding or the shader's arrays".into(),
        ));
    }
    let words = needed.len() as u32;
    gpu.run(|gpu| {
        let params = gpu.upload(&[
            corner_dims[1] as u32,
            corner_dims[2] as u32,
            words,
            (rows.len() / 5) as u32,
            pixels as u32,
        ]);
        let (needed, views) = (gpu.upload(needed), gpu.uniform(rows, VIEW_ROWS));
        let (depths, tiles) = (gpu.upload(depths), gpu.upload(tiles));
        let seen = gpu.zeroed(corners.div_ceil(32) as u64 * 4);
        gpu.dispatch(
            SHADER,
            "seen_corners",
            &[
                (0, &params),
                (1, &needed),
                (2, &views),
                (3, &depths),
                (4, &seen),
                (5, &tiles),
            ],
            words,
        );
        gpu.read(&seen)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shaders_array_of_view_rows_is_as_long_as_the_host_fills() {
        assert!(SHADER.contains(&format!("var<uniform> views: array<vec4<f32>, {VIEW_ROWS}>;")));
    }
}
