//! Open meshes (holes, open bottoms, gaps between parts) can show their inside. Whatever a camera
//! that is not below the object sees through such an opening must stay empty: open-bottomed game
//! art is never seen from below, but it is seen from every other side.
//!
//! The test renders the original's depth from many directions above the horizon. Voxels with a
//! corner in front of that depth are removed before boxes grow, and each finished box is checked
//! face by face, so a box that slips through between voxel corners is still caught. Each pixel
//! takes the farthest depth of its 3×3 neighbourhood, so that an opening seen from a direction
//! between the sampled ones, or between pixel centres, still counts.

use crate::eval::raster::{View, depth_image, rasterize};
use crate::eval::views::fibonacci_sphere;
use crate::mesh::Mesh;
use crate::voxel::Grid;
use glam::DVec3;
use rayon::prelude::*;

/// Directions on the whole sphere; those not below the object are used.
const DIRECTIONS: usize = 256;
const PIXELS: usize = 256;

pub struct OpenViews {
    views: Vec<View>,
    depths: Vec<Vec<f32>>,
}

impl OpenViews {
    pub fn new(mesh: &Mesh) -> OpenViews {
        let (center, radius) = mesh.bounding_sphere();
        let views: Vec<View> = fibonacci_sphere(DIRECTIONS)
            .into_iter()
            .filter(|d| d.y >= 0.0)
            .map(|d| View::new(d, center, radius, PIXELS))
            .collect();
        let depths = views
            .par_iter()
            .map(|v| farthest_nearby(&depth_image(v, mesh.triangles_f64()), v.pixels))
            .collect();
        OpenViews { views, depths }
    }

    /// Whether some view sees point `p` in front of the original's surface.
    fn sees(&self, view: usize, p: DVec3) -> bool {
        let v = &self.views[view];
        let q = v.project(p);
        let n = v.pixels as f64;
        if q.x < 0.0 || q.y < 0.0 || q.x >= n || q.y >= n {
            return true;
        }
        let depth = self.depths[view][q.y as usize * v.pixels + q.x as usize];
        q.z < f64::from(depth) - v.depth_tolerance()
    }

    /// Clears the voxels of `inner` that a view sees at one of their corners.
    pub fn remove_exposed(&self, grid: &Grid, inner: &mut [bool]) -> usize {
        let exposed: Vec<usize> = (0..inner.len())
            .into_par_iter()
            .filter(|&i| inner[i])
            .filter(|&i| {
                let [x, y, z] = grid.coords(i);
                let corners = (0..8).map(|c| {
                    grid.to_world(DVec3::new(
                        (x + (c & 1)) as f64,
                        (y + ((c >> 1) & 1)) as f64,
                        (z + ((c >> 2) & 1)) as f64,
                    ))
                });
                let corners: Vec<DVec3> = corners.collect();
                (0..self.views.len()).any(|v| corners.iter().any(|&p| self.sees(v, p)))
            })
            .collect();
        for &i in &exposed {
            inner[i] = false;
        }
        exposed.len()
    }

    /// Whether no view sees any pixel of these triangles (a box, a quad) in front of the original.
    pub fn hides(&self, triangles: &[[DVec3; 3]]) -> bool {
        self.views.iter().zip(&self.depths).all(|(view, depth)| {
            let tolerance = view.depth_tolerance();
            let mut hidden = true;
            for tri in triangles {
                rasterize(view, tri, |i, d| hidden &= d >= f64::from(depth[i]) - tolerance);
            }
            hidden
        })
    }
}

/// Each pixel's farthest depth over its 3×3 neighbourhood (infinite where any is empty).
fn farthest_nearby(depth: &[f32], n: usize) -> Vec<f32> {
    let mut out = vec![0f32; depth.len()];
    for y in 0..n {
        for x in 0..n {
            let mut far = 0f32;
            for ny in y.saturating_sub(1)..=(y + 1).min(n - 1) {
                for nx in x.saturating_sub(1)..=(x + 1).min(n - 1) {
                    far = far.max(depth[ny * n + nx]);
                }
            }
            out[y * n + x] = far;
        }
    }
    out
}
