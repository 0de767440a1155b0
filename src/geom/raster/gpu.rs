//! Host code for shaders/raster.wgsl: depth images of a mesh from orthographic views, rasterized
//! in compute, read back in one go. The twin is [`super::depth_image`].

use crate::geom::camera::View;
use crate::gpu::{Gpu, GpuError, WORKGROUP, units_per_item};
use crate::mesh::Mesh;
use rayon::prelude::*;

const SHADER: &str = include_str!("../../../shaders/raster.wgsl");

/// Built when a cook opens the device, like the voxel stages' entry points.
pub const ENTRY_POINTS: [(&str, &str); 1] = [(SHADER, "depth_min")];

/// Pixel tests one thread may make over its views: under llvmpipe's 65535 loop iterations.
const THREAD_PIXELS: usize = 49152;
/// Pixel tests a thread makes on a hardware GPU, which runs many threads at once, so that a
/// large triangle's rows spread over many (unless the items would be more than `MAX_ITEMS`).
const HARDWARE_THREAD_PIXELS: usize = 1024;
/// The shader's `nearness` key of an empty pixel.
const EMPTY: u32 = 0;
/// The most views one dispatch draws: the shader's uniform array holds three rows each.
const MAX_VIEWS: usize = 256;

/// The nearest depth per pixel of `mesh` in each view (orthographic, all the same size), rows
/// from the bottom as [`View::project`] counts them, `f32::INFINITY` where nothing is drawn.
/// `Unsupported` for perspective views and for meshes larger than one storage binding.
pub fn depth_images(gpu: &Gpu, mesh: &Mesh, views: &[View]) -> Result<Vec<Vec<f32>>, GpuError> {
    let Some(pixels) = views.first().map(|v| v.pixels) else {
        return Ok(Vec::new());
    };
    let (origin, positions) = crate::gpu::centred_positions(mesh);
    let mut rows: Vec<[f32; 4]> = Vec::with_capacity(3 * views.len());
    let mut scale = 0f64;
    for view in views {
        let (Some(view_rows), Some(view_scale)) = (view.ortho_rows(origin), view.ortho_scale()) else {
            return Err(GpuError::Unsupported("GPU depth images are orthographic only".into()));
        };
        rows.extend(view_rows.map(|r| r.map(|v| v as f32)));
        scale = scale.max(view_scale);
    }
    // On a software adapter a thread draws its item in as many views as fit its budget with a
    // row of the image each: llvmpipe spends more setting a thread up than drawing a tiny
    // triangle. A hardware GPU runs a thread per item and view at once, items of few pixels (on
    // an H200, spider's 160 sky views took 11.8 ms of device time drawn 160 to a thread).
    let (views_per_thread, least_pixels) = match gpu.info.device_type {
        wgpu::DeviceType::Cpu => ((THREAD_PIXELS / pixels).clamp(1, views.len()), THREAD_PIXELS),
        _ => (1, HARDWARE_THREAD_PIXELS),
    };
    let most_pixels = THREAD_PIXELS / views_per_thread;
    let items = work_items(mesh, scale, pixels, [least_pixels.min(most_pixels), most_pixels]);
    let image_bytes = (pixels * pixels * 4) as u64;
    let per_dispatch = views_per_dispatch((gpu.max_binding / image_bytes) as usize, items.len(), views_per_thread);
    let largest_input = [mesh.positions.len() * 12, mesh.triangles.len() * 12, items.len() * 16];
    if per_dispatch == 0 || largest_input.into_iter().any(|bytes| bytes as u64 > gpu.max_binding) {
        return Err(GpuError::Unsupported(
            "the mesh or one depth image exceeds the adapter's largest storage binding".into(),
        ));
    }
    if items.is_empty() {
        return Ok(vec![vec![f32::INFINITY; pixels * pixels]; views.len()]);
    }
    gpu.run(|gpu| {
        let positions = gpu.upload(&positions);
        let triangles = gpu.upload(&mesh.triangles);
        let item_buffer = gpu.upload(&items);
        let mut images = Vec::with_capacity(views.len());
        for (chunk, chunk_rows) in views.chunks(per_dispatch).zip(rows.chunks(3 * per_dispatch)) {
            let params = gpu.upload(&[
                pixels as u32,
                chunk.len() as u32,
                items.len() as u32,
                views_per_thread as u32,
            ]);
            let view_buffer = gpu.uniform(chunk_rows, 3 * MAX_VIEWS);
            let depth = gpu.zeroed((pixels * pixels * chunk.len() * 4) as u64);
            let threads = items.len() as u64 * chunk.len().div_ceil(views_per_thread) as u64;
            let groups = u32::try_from(threads.div_ceil(u64::from(WORKGROUP)))
                .map_err(|_| GpuError::Unsupported("too many triangles for one dispatch".into()))?;
            gpu.dispatch(
                SHADER,
                "depth_min",
                &[
                    (0, &params),
                    (1, &positions),
                    (2, &triangles),
                    (3, &item_buffer),
                    (4, &view_buffer),
                    (5, &depth),
                ],
                groups,
            );
            gpu.read_with(&depth, |keys: &[u32]| {
                images.par_extend(
                    keys.par_chunks(pixels * pixels)
                        .map(|image| image.iter().map(|&k| depth_of(k)).collect::<Vec<f32>>()),
                );
            })?;
        }
        Ok(images)
    })
}

/// The depth a shader key stands for (`nearness` in shaders/raster.wgsl, undone).
fn depth_of(key: u32) -> f32 {
    match key {
        EMPTY => f32::INFINITY,
        k if k & 0x8000_0000 != 0 => f32::from_bits(k),
        k => f32::from_bits(!k & 0x7fff_ffff),
    }
}

/// Views one dispatch draws: no more than a binding holds the images of (`binding_views`) or the
/// shader's array, and few enough that its threads, `items` for each group of
/// `views_per_thread` views, are numbered in a u32 as the shader numbers them.
fn views_per_dispatch(binding_views: usize, items: usize, views_per_thread: usize) -> usize {
    let numbered = u32::MAX as usize / items.max(1) * views_per_thread;
    binding_views.min(MAX_VIEWS).min(numbered)
}

/// (triangle, first row, rows, 0) per run of rows: a triangle's projected bounds are at most its
/// diameter times `scale` pixels across in any view, and at most the image, split so that a
/// thread tests the fewest pixels in one view from `[least, most]` that keeps the bounds'
/// pixels over [`MAX_ITEMS`](crate::gpu::MAX_ITEMS) threads (whole rows a thread make the
/// items at most twice as many).
fn work_items(mesh: &Mesh, scale: f64, pixels: usize, [least, most]: [usize; 2]) -> Vec<[u32; 4]> {
    let sides: Vec<usize> = mesh
        .triangles
        .iter()
        .map(|tri| {
            let corners = tri.map(|v| mesh.positions[v as usize].as_dvec3());
            let centre = (corners[0] + corners[1] + corners[2]) / 3.0;
            let reach = corners.iter().map(|c| c.distance(centre)).fold(0.0, f64::max);
            ((2.0 * reach * scale).ceil() as usize + 2).min(pixels)
        })
        .collect();
    let bounds: usize = sides.iter().map(|side| side * side).sum();
    let thread_pixels = units_per_item(bounds, [least, most]);
    let mut items = Vec::with_capacity(sides.len());
    for (t, side) in sides.into_iter().enumerate() {
        let rows = (thread_pixels / side).max(1);
        for first in (0..side).step_by(rows) {
            items.push([t as u32, first as u32, rows as u32, 0]);
        }
    }
    items
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::MAX_ITEMS;
    use glam::Vec3;

    /// `n` copies of a triangle whose bounds fill a 512-pixel image at a scale of 512 a unit.
    fn large_triangles(n: usize) -> Mesh {
        Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            triangles: vec![[0, 1, 2]; n],
        }
    }

    #[test]
    fn a_hardware_gpus_items_are_small_until_there_would_be_too_many() {
        let (pixels, scale) = (512, 512.0);
        let few = work_items(
            &large_triangles(2),
            scale,
            pixels,
            [HARDWARE_THREAD_PIXELS, THREAD_PIXELS],
        );
        let rows = (HARDWARE_THREAD_PIXELS / pixels) as u32;
        assert_eq!(few.len(), 2 * pixels / rows as usize);
        assert!(few.iter().all(|&[_, first, r, _]| r == rows && first % rows == 0));
        // On lavapipe, one item per a thread's whole budget.
        let software = work_items(&large_triangles(2), scale, pixels, [THREAD_PIXELS; 2]);
        assert_eq!(software.len(), 2 * pixels.div_ceil(THREAD_PIXELS / pixels));
        // 20,000 of them at 1,024 pixels a thread would be 5 million items.
        let many = work_items(
            &large_triangles(20_000),
            scale,
            pixels,
            [HARDWARE_THREAD_PIXELS, THREAD_PIXELS],
        );
        assert!(many.len() <= 2 * MAX_ITEMS + 20_000, "{} items", many.len());
    }

    #[test]
    fn a_dispatch_holds_no_more_views_than_its_threads_can_be_numbered_for() {
        assert_eq!(views_per_dispatch(1000, 10_000, 1), MAX_VIEWS);
        assert_eq!(views_per_dispatch(40, 10_000, 1), 40);
        // 20 million items, a thread each per view: 214 views make 4.28 billion threads.
        let views = views_per_dispatch(1000, 20_000_000, 1);
        assert_eq!(views, 214);
        assert!(20_000_000 * views as u64 <= u64::from(u32::MAX));
        assert_eq!(views_per_dispatch(1000, 20_000_000, 96), MAX_VIEWS);
    }

    #[test]
    fn depth_keys_grow_nearer_and_come_back_unchanged() {
        // `nearness` in the shader, written out for the test.
        let nearness = |d: f32| {
            let bits = d.to_bits();
            if bits & 0x8000_0000 != 0 {
                bits
            } else {
                !(bits | 0x8000_0000)
            }
        };
        let depths = [-f32::MAX, -3.5f32, -0.0, 0.0, 1e-30, 0.25, 7.0, f32::MAX];
        for pair in depths.windows(2) {
            assert!(nearness(pair[0]) >= nearness(pair[1]), "{pair:?}");
        }
        for d in depths {
            assert_ne!(nearness(d), super::EMPTY);
            assert_eq!(super::depth_of(nearness(d)).to_bits(), d.to_bits());
        }
    }
}
