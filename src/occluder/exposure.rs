//! Open meshes (holes, open bottoms, gaps between parts) can show their inside. Whatever a camera
//! that is not below the object sees through such an opening must stay empty: open-bottomed game
//! art is never seen from below, but it is seen from every other side.
//!
//! The test renders the original's depth from many directions above the horizon. Voxels with a
//! corner in front of that depth are removed before boxes grow, and each finished box is checked
//! face by face, so a box that slips through between voxel corners is still caught. Each pixel
//! takes the farthest depth of its 3×3 neighbourhood, so that an opening seen from a direction
//! between the sampled ones, or between pixel centres, still counts.
//!
//! A small hole lets a camera see in only from a narrow cone of directions, which can fall
//! between the sampled ones. So cameras are also placed in the openings themselves (a connected
//! run of boundary edges), looking in: whatever shows through an opening from outside is seen
//! from some point of it, near enough. An outside camera not below a point sees it through the
//! opening only past a point of the opening at least as high, so these cameras count only what
//! lies no higher than the opening's highest point.
//!
//! An opening of a part that lies inside another (overlapping shells, a shell inside a shell)
//! shows only along lines that pass an opening of the enclosing part first: too few for the
//! views above or the cameras in that opening to sample. Where those see such an opening along
//! a clear line, it gets cameras of its own; where none does, it lies in a closed part, and
//! nothing reaches it. So does the mouth of a slot inside another part, and the window where
//! two parts' openings cross, where few of the views above see it.
//!
//! A crack between parts that nearly touch is narrower than a pixel, so pixel centres rarely
//! fall in it, yet what lies behind it shows. Along a boundary edge with another part of the
//! surface within a pixel (but not touching), the views draw a pixel only where its whole square
//! lies on the triangle's side: across the crack, they see what lies behind.

pub mod band;
pub mod gpu;

use super::{Panel, rectangle};
use crate::geom::camera::{View, fibonacci_sphere};
use crate::geom::grid_counts::GridCounts;
use crate::geom::meshlets::{Meshlet, line_blocked, meshlets};
use crate::geom::proximity::SurfaceIndex;
use crate::geom::raster::{
    self, DrawBuffers, draw_depth, draw_depth_nearest_first, draw_eroded, rasterize, rasterize_within,
};
use crate::geom::{clamped_index, greater, with_avx2};
use crate::gpu::{Gpu, GpuError};
use crate::mesh::{BoundaryEdge, Mesh, point_bounds};
use crate::voxel::Grid;
use crate::voxel::winding::WindingField;
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::ops::{Range, RangeInclusive};
use std::sync::{Mutex, PoisonError};

/// Directions on the whole sphere; those not below the object are used.
const DIRECTIONS: usize = 256;
/// Directions on the horizon itself, the edge of those used: a slot in the side of a shape lines
/// up with views from there, and the sphere's points come no nearer than half a row to it.
const HORIZON_DIRECTIONS: usize = 32;
/// Parts of the surface nearer each other than this share of the mesh's radius touch: float
/// noise, not a crack.
const TOUCHING: f64 = 1e-6;
const PIXELS: usize = 256;

/// Pixels per side of the tiles whose farthest depth gives a quick "hidden" answer (TILE in
/// shaders/exposure.wgsl).
pub(crate) const TILE: usize = 8;

/// Cameras in one opening: at its centre and at points of its rim spread farthest apart.
const EYES_PER_OPENING: usize = 3;
/// How near a half the winding number at a point of an opening is when nothing fills it.
const OPEN_WINDING: f64 = 0.3;
/// How near a whole number it is at the mouth of an opening inside another part
/// ([`mouth_points`]).
const MOUTH_WINDING: f64 = 0.2;
/// Such a mouth gets a camera only if at most one in so many sky views sees it: through a wider
/// one, they sample the lines already.
const NARROW_WINDOW: usize = 5;
/// Cameras in all openings, the largest openings first: each renders five or six faces of a
/// cube map.
const MAX_EYES: usize = 24;
/// Cameras in openings that lie inside another part, besides `MAX_EYES`
/// ([`OpenViews::add_enclosed_eyes`]).
const MAX_ENCLOSED_EYES: usize = 12;
/// Most views in all: the sky's upper half and horizon, and the six faces of each camera's
/// cube map.
pub(crate) const MAX_VIEWS: usize = DIRECTIONS / 2 + HORIZON_DIRECTIONS + 6 * (MAX_EYES + MAX_ENCLOSED_EYES);
/// Grid corners along each side of a brick tested together, view by view.
const CORNER_BRICK: usize = 8;
/// Views whose depths the bricks go through together: a few, whose depths stay in cache.
const VIEWS_TOGETHER: usize = 8;
/// Most cells along a side of a panel cut down to its hidden part.
const MAX_PART_CELLS: usize = 64;
/// Grid corners a CPU thread tests against the views in about the time the GPU's test spends
/// uploading the depth images and reading its answer back ([`Gpu::pays_for`]). On an H200 host
/// with 16 threads the GPU took 13-31 ms and 20 ms a million corners, the CPU 70-90 ms a million
/// (teapot, bunny-holes and 2cylinder-engine from 64³ to 256³): 240,000 corners is about even.
const CORNERS_A_THREAD: usize = 15_000;

pub struct OpenViews {
    /// The orthographic views from directions above the horizon and on it, then the cameras in
    /// the openings, then those in the openings of parts inside another.
    views: Vec<View>,
    /// How many of `views` are orthographic.
    sky_views: usize,
    /// Per camera in an opening, the height of the highest point of its opening (or its own,
    /// if higher): it counts only what lies no higher.
    horizons: Vec<f64>,
    /// Per view, each pixel's farthest depth over its neighbourhood, one image after another.
    depths: Vec<f32>,
    /// Per view, the farthest depth of each TILE × TILE tile of `depths`.
    tiles: Vec<f32>,
    /// The width of a pixel of the orthographic views.
    pixel: f64,
    /// Boundary edges along a crack.
    cracks: usize,
    /// Where the sky views are drawn only in their bands ([`band`]): what answers the objects
    /// the band's rule cannot.
    band: Option<Band>,
}

/// The sky views drawn in their bands only: every needed grid corner has W″ ≠ 0, and each
/// image is 0 (hidden) outside its band's window.
struct Band {
    walls: Vec<band::Wall>,
    up: band::UpColumns,
}

impl Band {
    /// The band of an open mesh's sky views, with each view's window, where it pays and its rule
    /// holds for every grid corner the voxels test (`grid`'s corners around `inner` voxels).
    fn new(
        mesh: &Mesh,
        boundary: &[BoundaryEdge],
        sky: &[View],
        (grid, inner): (&Grid, &[bool]),
    ) -> Option<(Band, Vec<Vec<bool>>)> {
        // The bands pay where their windows leave most of each image out: judged on a few
        // views first, as a window costs a pass over the walls.
        let walls = band::walls(mesh, boundary);
        let window = |view: &View| band::window(view, &walls, BAND_MARGIN, TILE);
        let sample: Vec<Vec<bool>> = sky
            .par_iter()
            .step_by((sky.len() / WINDOW_SAMPLE).max(1))
            .map(window)
            .collect();
        let share = sample.iter().flatten().filter(|&&w| w).count() as f64 / sample.iter().flatten().count() as f64;
        let needed = needed_corners(grid, inner);
        if !(share <= MOST_WINDOW_SHARE && needed.contains(&true)) {
            return None;
        }
        // The band's rule holds for every corner the voxels test when each has W″ ≠ 0.
        let up = band::UpColumns::new(mesh);
        let [nx, ny, nz] = grid.dims;
        let holds = (0..(nx + 1) * (nz + 1)).into_par_iter().all(|column| {
            // The corners one above another share the surface's crossings.
            let (x, z) = (column / (nz + 1), column % (nz + 1));
            let mut corners = (0..=ny)
                .filter(|&y| needed[corner_index(grid, [x, y, z])])
                .map(|y| corner_point(grid, [x, y, z]))
                .peekable();
            let crossings = corners.peek().map(|&p| up.crossings(p)).unwrap_or_default();
            corners.all(|p| band::net_above(&crossings, p.y) != 0)
        });
        if !holds {
            return None;
        }
        let windows = sky.par_iter().map(window).collect();
        Some((Band { walls, up }, windows))
    }
}

/// Draws the sky views into `out`, their images one after another, and their tiles into
/// `tiles` ([`Images`]): the mesh's triangles (`drawn`, on `gpu` when given) and those along a
/// crack eroded. With `windows`, each image holds only its window (on the CPU, drawn from
/// `meshlets`, `drawn`'s), and is 0 (hidden to every later test) outside it.
fn draw_sky(
    sky: &[View],
    (drawn, split): (&Mesh, &CrackSplit),
    (windows, meshlets): (Option<&[Vec<bool>]>, &[Meshlet]),
    gpu: Option<&Gpu>,
    (out, tiles): Images,
) -> Result<(), GpuError> {
    // Row by row, a tile's run of pixels at a time.
    let mask = |window: &[bool], image: &mut [f32]| {
        for (y, row) in image.chunks_exact_mut(PIXELS).enumerate() {
            let tiles = &window[(y / TILE) * WindowTiles::ACROSS..][..WindowTiles::ACROSS];
            for (pixels, _) in row.chunks_exact_mut(TILE).zip(tiles).filter(|(_, inside)| !**inside) {
                pixels.fill(0.0);
            }
        }
    };
    let finish = |v: usize, view: &View, image: &mut [f32], (out, tiles): Images| {
        draw_eroded(view, &split.soup, &split.eroded, image);
        match windows {
            Some(windows) => {
                mask(&windows[v], image);
                farthest_nearby_in_window(&windows[v], image, out);
            }
            None => farthest_nearby(image, PIXELS, out),
        }
        farthest_per_tile(out, PIXELS, tiles);
    };
    let out = each_image(out, tiles).zip(sky).enumerate();
    match gpu {
        Some(gpu) => {
            let images = raster::depth_images(sky, drawn, Some(gpu))?;
            out.zip(images)
                .for_each(|((v, (out, view)), mut image)| finish(v, view, &mut image, out));
        }
        None => out.for_each_init(
            || (Vec::new(), Kept::default()),
            |(image, kept), (v, (out, view))| {
                match windows {
                    Some(windows) => draw_in_window(view, meshlets, &windows[v], (image, kept)),
                    None => draw_depth(view, drawn, image),
                }
                finish(v, view, image, out);
            },
        ),
    }
    Ok(())
}

/// Views' images and the farthest depth of each of their tiles, one view after another: where
/// an image is written, so that its tiles are found while it is in cache.
type Images<'a> = (&'a mut [f32], &'a mut [f32]);

/// Tiles a view.
const TILES: usize = WindowTiles::ACROSS * WindowTiles::ACROSS;

/// Each view's image and tiles.
fn each_image<'a>(out: &'a mut [f32], tiles: &'a mut [f32]) -> impl IndexedParallelIterator<Item = Images<'a>> {
    out.par_chunks_mut(PIXELS * PIXELS).zip(tiles.par_chunks_mut(TILES))
}

/// How far from a point, in pixels, lie the centres of the pixels whose depths decide whether
/// it shows: its pixel's 3 × 3 neighbours.
const NEARBY_READ: f64 = 1.5 * std::f64::consts::SQRT_2;

/// Pixels around the band that the sky views draw: a point in the band, or a pixel's
/// diagonal from it, reads only pixels within [`NEARBY_READ`] more.
const BAND_MARGIN: f64 = 4.0;

/// Sky views whose windows judge whether the bands pay.
const WINDOW_SAMPLE: usize = 4;

/// The largest share of the sampled views' tiles their windows may hold for the bands to pay:
/// beyond it, drawing in windows saved less than finding them cost (2cylinder-engine, 0.57).
const MOST_WINDOW_SHARE: f64 = 1.0 / 3.0;

/// A rectangle (a panel, a box's face) cut into `n` cells along its sides `u` and `v` from
/// `origin`, each about a pixel of the sky views wide.
struct RectangleCells {
    origin: DVec3,
    u: DVec3,
    v: DVec3,
    n: [usize; 2],
}

impl RectangleCells {
    /// The grid point `i` cells along `u` and `j` along `v`.
    fn at(&self, i: usize, j: usize) -> DVec3 {
        self.origin + self.u * (i as f64 / self.n[0] as f64) + self.v * (j as f64 / self.n[1] as f64)
    }
}

/// A sky view's depth image, in `image`, drawn right in the tiles of its `window`: of the
/// meshlets whose bounds meet the window grown by a pixel, the triangles whose bounds do.
/// Elsewhere it may miss what lies there. `kept` is room for the triangles kept of a meshlet,
/// and for its vertices as the view projects them.
fn draw_in_window(view: &View, meshlets: &[Meshlet], window: &[bool], (image, kept): (&mut Vec<f32>, &mut Kept)) {
    image.clear();
    image.resize(PIXELS * PIXELS, f32::INFINITY);
    let window = WindowTiles::new(window);
    let (triangles_kept, buffers) = kept;
    for meshlet in meshlets {
        // Sky views are orthographic; any other view's meshlets are tested triangle by triangle.
        let meets = view
            .orthographic_box_image(meshlet.lo, meshlet.hi)
            .map_or(Meets::Part, |(lo, hi)| window.meets(lo, hi));
        if meets == Meets::None {
            continue;
        }
        let projected = buffers.project(view, &meshlet.mesh);
        let triangles = &meshlet.mesh.triangles;
        if meets == Meets::Whole {
            raster::draw_depth_of(view, &meshlet.mesh, 0..triangles.len(), image, buffers);
            continue;
        }
        triangles_kept.clear();
        triangles_kept.extend((0..triangles.len() as u32).filter(|&t| {
            let (lo, hi) = point_bounds(triangles[t as usize].map(|i| projected[i as usize]));
            window.meets(lo, hi) != Meets::None
        }));
        let kept = triangles_kept.iter().map(|&t| t as usize);
        raster::draw_depth_of(view, &meshlet.mesh, kept, image, buffers);
    }
}

/// Room [`draw_in_window`] keeps from view to view.
type Kept = (Vec<u32>, DrawBuffers);

/// How much of a window the tiles that a rectangle of the image may fall in hold.
#[derive(Clone, Copy, PartialEq)]
enum Meets {
    None,
    Part,
    Whole,
}

/// A sky view's window ([`band::window`]) as counts of its tiles over rectangles of tiles.
struct WindowTiles(GridCounts);

impl WindowTiles {
    const ACROSS: usize = PIXELS / TILE;

    fn new(window: &[bool]) -> WindowTiles {
        WindowTiles(GridCounts::new(window, Self::ACROSS, Self::ACROSS))
    }

    /// How much of the window holds the tiles that the image points from `lo` to `hi` (in
    /// pixels), grown by a pixel against rounding, may fall in.
    fn meets(&self, lo: DVec3, hi: DVec3) -> Meets {
        let tile = |v: f64| clamped_index(v * (1.0 / TILE as f64), Self::ACROSS);
        let (xs, ys) = (
            tile(lo.x - 1.0)..tile(hi.x + 1.0) + 1,
            tile(lo.y - 1.0)..tile(hi.y + 1.0) + 1,
        );
        let tiles = xs.len() * ys.len();
        match self.0.count(ys, xs) as usize {
            0 => Meets::None,
            held if held == tiles => Meets::Whole,
            _ => Meets::Part,
        }
    }
}

/// A camera in an opening: its point, and the height up to which it counts what it sees.
type Camera = (DVec3, f64);

/// Adds the cube map of each camera to `views`; returns each face's horizon. The face looking up
/// sees only what is higher than the camera: it counts only where the opening reaches higher
/// still.
fn add_cube_maps(views: &mut Vec<View>, eyes: &[Camera], radius: f64) -> Vec<f64> {
    let mut horizons = Vec::new();
    for &(eye, horizon) in eyes {
        for view in View::cube_map(eye, PIXELS, 2e-4 * radius)
            .into_iter()
            .filter(|v| v.dir.y > -0.5 || horizon > eye.y)
        {
            views.push(view);
            horizons.push(horizon);
        }
    }
    horizons
}

/// Draws the cameras' views of `parts` (of the mesh in `sphere`) into `out`, each pixel the
/// farthest depth of its neighbourhood, and their tiles ([`Images`]).
fn draw_eyes(eyes: &[View], horizons: &[f64], (parts, sphere): (&[Meshlet], (DVec3, f64)), (out, tiles): Images) {
    let eyes = each_image(out, tiles).zip(eyes).zip(horizons);
    eyes.for_each_init(Vec::new, |image, (((out, tiles), view), &horizon)| {
        draw_depth_nearest_first(view, &may_hide_counted(parts, sphere, view, horizon), image);
        farthest_nearby(image, PIXELS, out);
        farthest_per_tile(out, PIXELS, tiles);
    });
}

/// The grid corners (z fastest) that one of the voxels around them, up to 8, is inner.
fn needed_corners(grid: &Grid, inner: &[bool]) -> Vec<bool> {
    let [nx, ny, nz] = grid.dims;
    let [ny1, nz1] = [ny + 1, nz + 1];
    (0..(nx + 1) * ny1 * nz1)
        .into_par_iter()
        .map(|c| {
            let (x, y, z) = (c / (ny1 * nz1), (c / nz1) % ny1, c % nz1);
            let around = |v: usize, n: usize| v.saturating_sub(1)..v.min(n - 1) + 1;
            around(x, nx).any(|vx| around(y, ny).any(|vy| around(z, nz).any(|vz| inner[grid.index(vx, vy, vz)])))
        })
        .collect()
}

/// The world point of the grid corner at `corner` (in voxels).
fn corner_point(grid: &Grid, corner: [usize; 3]) -> DVec3 {
    grid.to_world(DVec3::from_array(corner.map(|i| i as f64)))
}

impl OpenViews {
    /// Renders the views' depth images, the orthographic ones on `gpu` when given
    /// (shaders/raster.wgsl). `boundary` is the mesh's open boundary, and `winding_field` gives
    /// its winding number field, built once for this and what else needs it.
    pub fn new<'f>(
        mesh: &Mesh,
        boundary: &[BoundaryEdge],
        winding_field: impl Fn() -> &'f WindingField<'f> + Sync,
        gpu: Option<&Gpu>,
        (grid, inner): (&Grid, &[bool]),
    ) -> Result<OpenViews, GpuError> {
        let (center, radius) = mesh.bounding_sphere();
        let horizon = (0..HORIZON_DIRECTIONS).map(|k| {
            let angle = std::f64::consts::TAU * k as f64 / HORIZON_DIRECTIONS as f64;
            DVec3::new(angle.cos(), 0.0, angle.sin())
        });
        let mut views: Vec<View> = fibonacci_sphere(DIRECTIONS)
            .into_iter()
            .filter(|d| d.y >= 0.0)
            .chain(horizon)
            .map(|d| View::new(d, center, radius, PIXELS))
            .collect();
        let sky_views = views.len();
        let pixel = 2.0 * radius / PIXELS as f64;
        // Each mostly serial: side by side.
        let ((eyes, enclosed, mouths), cracked) = rayon::join(
            || opening_eyes(mesh, boundary, winding_field(), pixel),
            || crack_edges(mesh, boundary, pixel, TOUCHING * radius),
        );
        let horizons = add_cube_maps(&mut views, &eyes, radius);
        let split = CrackSplit::new(mesh, &cracked);
        // Each view's farthest depths over its neighbourhoods, one image after another, as the
        // GPU takes them. On the CPU each view is drawn, eroded and filtered in turn through one
        // image a thread.
        let mut depths = depth_memory(views.len() * PIXELS * PIXELS);
        let mut tiles = vec![0.0; views.len() * TILES];
        let (sky_depths, eye_depths) = depths.split_at_mut(sky_views * PIXELS * PIXELS);
        let (sky_tiles, eye_tiles) = tiles.split_at_mut(sky_views * TILES);
        let (sky, eyes) = views.split_at(sky_views);
        // Triangles along a crack are drawn eroded on the CPU, over the rest.
        let drawn = split.uncracked.as_ref().unwrap_or(mesh);
        let banded = Band::new(mesh, boundary, sky, (grid, inner));
        // What the CPU draws in part, as meshlets: the cameras in the openings all the mesh's
        // triangles (the drawn ones' first, then those along a crack), the sky views in windows
        // the drawn ones'.
        let cameras = !eyes.is_empty() || !enclosed.is_empty() || !mouths.is_empty();
        let mut parts = Vec::new();
        if cameras || (banded.is_some() && gpu.is_none()) {
            parts = meshlets(drawn);
        }
        let drawn_parts = parts.len();
        if cameras && split.uncracked.is_some() {
            parts.extend(meshlets(&split.soup));
        }
        // The GPU rasterizer draws orthographic views only; the CPU draws the cameras in the
        // openings meanwhile.
        let (sky_drawn, ()) = rayon::join(
            || {
                let windows = banded.as_ref().map(|(_, windows)| windows.as_slice());
                draw_sky(
                    sky,
                    (drawn, &split),
                    (windows, &parts[..drawn_parts]),
                    gpu,
                    (sky_depths, sky_tiles),
                )
            },
            || draw_eyes(eyes, &horizons, (&parts, (center, radius)), (eye_depths, eye_tiles)),
        );
        sky_drawn?;
        let mut open_views = OpenViews {
            views,
            sky_views,
            horizons,
            depths,
            tiles,
            pixel,
            cracks: cracked.values().flatten().filter(|&&e| e).count(),
            band: banded.map(|(band, _)| band),
        };
        open_views.add_enclosed_eyes((&enclosed, &mouths), (&parts, (center, radius)));
        Ok(open_views)
    }

    /// Cameras in the openings of parts that lie inside another part, at those of `enclosed`
    /// that the views so far see ([`OpenViews::seen_clearly`]): lines from outside reach them
    /// through an opening of the enclosing part, then go on through theirs, in directions no
    /// other camera sees along. Those no view sees lie in a closed part, where nothing from
    /// outside reaches. Then, up to [`MAX_ENCLOSED_EYES`] in all, cameras at those of `mouths`
    /// ([`mouth_points`]) that are seen so and narrow: few sky views see them.
    fn add_enclosed_eyes(
        &mut self,
        (enclosed, mouths): (&[Camera], &[Camera]),
        (parts, sphere): (&[Meshlet], (DVec3, f64)),
    ) {
        let narrow =
            |p: DVec3| (0..self.sky_views).filter(|&v| self.sees(v, p)).count() <= self.sky_views / NARROW_WINDOW;
        let seen: Vec<Camera> = enclosed
            .iter()
            .filter(|(p, _)| self.seen_clearly(parts, *p))
            .chain(
                mouths
                    .iter()
                    .filter(|(p, _)| narrow(*p) && self.seen_clearly(parts, *p)),
            )
            .take(MAX_ENCLOSED_EYES)
            .copied()
            .collect();
        let first = self.views.len();
        self.horizons.extend(add_cube_maps(&mut self.views, &seen, sphere.1));
        self.depths.resize(self.views.len() * PIXELS * PIXELS, 0.0);
        self.tiles.resize(self.views.len() * TILES, 0.0);
        let horizons = &self.horizons[first - self.sky_views..];
        let out = (
            &mut self.depths[first * PIXELS * PIXELS..],
            &mut self.tiles[first * TILES..],
        );
        draw_eyes(&self.views[first..], horizons, (parts, sphere), out);
    }

    /// Whether a view whose depth image sees `p` sees it along a line that meets no triangle of
    /// `parts` (the mesh's). The images take each pixel's farthest depth over its neighbourhood,
    /// so they see a point that lies just behind the surface near a silhouette: where a part's
    /// opening meets another part's surface (a handle's end in a body), a camera there would
    /// look into a closed part.
    fn seen_clearly(&self, parts: &[Meshlet], p: DVec3) -> bool {
        (0..self.views.len()).filter(|&v| self.sees(v, p)).any(|v| {
            let (towards, reach) = self.views[v].line_to_camera(p);
            !line_blocked(parts, p, towards, reach)
        })
    }

    /// How many boundary edges run along a crack, where another part of the surface lies nearer
    /// than a pixel without touching.
    pub fn cracks(&self) -> usize {
        self.cracks
    }

    /// What rounding may move a depth the rasterizer interpolates, or a point it unprojects: a
    /// billionth of the views' width.
    fn rounding(&self) -> f64 {
        1e-9 * (self.pixel * PIXELS as f64)
    }

    /// For a camera in an opening, the height up to which it counts what it sees.
    fn horizon(&self, view: usize) -> Option<f64> {
        view.checked_sub(self.sky_views).map(|e| self.horizons[e])
    }

    /// Whether view `view` sees point `p` in front of the original's surface.
    fn sees(&self, view: usize, p: DVec3) -> bool {
        let v = &self.views[view];
        let q = v.project(p);
        let n = v.pixels as f64;
        let off_image = !(q.x >= 0.0 && q.y >= 0.0 && q.x < n && q.y < n);
        match self.horizon(view) {
            // What the directions above the horizon do not frame lies outside the mesh.
            None if off_image => return true,
            // A camera in an opening sees only what lies in front of it, in its face, and no
            // higher than its opening.
            Some(horizon) if off_image || q.z <= v.depth_tolerance() || p.y > horizon => return false,
            _ => {}
        }
        let depth = self.depths[(view * PIXELS + q.y as usize) * PIXELS + q.x as usize];
        q.z < f64::from(depth) - v.depth_tolerance()
    }

    /// Clears the voxels of `inner` that a view sees at one of their corners, testing the
    /// corners on `gpu` when given (shaders/exposure.wgsl). Returns how many were cleared.
    /// `Unsupported` where the GPU cannot test them, with `inner` untouched.
    pub fn remove_exposed(&self, grid: &Grid, inner: &mut [bool], gpu: Option<&Gpu>) -> Result<usize, GpuError> {
        // Neighbouring voxels share corners: test each corner once.
        let corners_of = |i: usize| {
            let [x, y, z] = grid.coords(i);
            (0..8).map(move |c| corner_index(grid, [x + (c & 1), y + ((c >> 1) & 1), z + ((c >> 2) & 1)]))
        };
        let needed = needed_corners(grid, inner);
        let to_test = || needed.par_iter().filter(|&&n| n).count();
        // `Unsupported` on the GPU leaves `inner` as it was, for the caller to run this again
        // on the CPU.
        let seen = match gpu.filter(|gpu| gpu.pays_for(to_test(), CORNERS_A_THREAD)) {
            Some(gpu) => self.seen_corners_on(gpu, grid, &needed)?,
            None => self.seen_corners(grid, &needed),
        };
        // Each voxel's answer is its own corners': cleared in place.
        Ok(inner
            .par_iter_mut()
            .enumerate()
            .filter(|(i, inside)| **inside && corners_of(*i).any(|c| seen[c]))
            .map(|(_, inside)| *inside = false)
            .count())
    }

    /// Of the `needed` grid corners (z fastest), those some view sees. The corners go in bricks
    /// through a few views at a time ([`OpenViews::view_blocks`]), whose depths stay in cache
    /// (all views' together are far larger than it); a view with the whole brick behind its
    /// depths skips it, and a brick whose corners are all seen leaves the rest of the views.
    fn seen_corners(&self, grid: &Grid, needed: &[bool]) -> Vec<bool> {
        let bricks = CornerBricks::new(grid, needed);
        let mut seen = vec![false; bricks.corners.len()];
        for block in self.view_blocks() {
            bricks
                .split(&mut seen)
                .into_par_iter()
                .enumerate()
                .with_max_len(1)
                .filter(|(_, seen)| seen.iter().any(|seen| !seen))
                .for_each(|(b, seen)| {
                    let (lo, hi) = bricks.bounds[b];
                    let points = &bricks.points[bricks.starts[b]..bricks.starts[b + 1]];
                    for v in block.clone().filter(|&v| !self.view_hides_box(v, lo, hi)) {
                        for (seen, &p) in seen.iter_mut().zip(points) {
                            *seen = *seen || self.sees(v, p);
                        }
                    }
                });
        }
        let mut all = vec![false; needed.len()];
        for (&c, _) in bricks.corners.iter().zip(&seen).filter(|(_, seen)| **seen) {
            all[c] = true;
        }
        all
    }

    /// The views in blocks of [`VIEWS_TOGETHER`], a block of sky views and a block of cameras in
    /// turn. What one view sees is seen, so the order changes only the work: the inside of a
    /// hollow part shows only to the cameras in its openings, the outside mostly to the sky
    /// views, and taking their blocks in turn reaches either kind early (teapot's corners took
    /// 717,485 tests sky views first and 342,787 in turn; 2cylinder-engine's 54,154 and 63,956).
    fn view_blocks(&self) -> Vec<Range<usize>> {
        let blocks = |views: Range<usize>| {
            views
                .clone()
                .step_by(VIEWS_TOGETHER)
                .map(move |first| first..(first + VIEWS_TOGETHER).min(views.end))
        };
        let (mut sky, mut cameras) = (blocks(0..self.sky_views), blocks(self.sky_views..self.views.len()));
        let mut order = Vec::new();
        loop {
            let (a, b) = (sky.next(), cameras.next());
            if a.is_none() && b.is_none() {
                return order;
            }
            order.extend(a.into_iter().chain(b));
        }
    }

    /// Whether view `v` sees no point of the box [lo, hi]: a camera in an opening, none where
    /// the box lies wholly above the opening or behind the camera; any view, none where the box
    /// lies in front of it, projects onto the image, and lies behind the farthest depth of every
    /// tile under it. Rounding moves the box's points by far less than the margins.
    fn view_hides_box(&self, v: usize, lo: DVec3, hi: DVec3) -> bool {
        let view = &self.views[v];
        let (tolerance, rounding) = (view.depth_tolerance(), self.rounding());
        if self.horizon(v).is_some_and(|horizon| lo.y - rounding > horizon) {
            return true;
        }
        let corners = (0..8).map(|k| {
            let pick = glam::BVec3::new(k & 1 != 0, k & 2 != 0, k & 4 != 0);
            view.project(DVec3::select(pick, hi, lo))
        });
        // Within the corners' bounds: the box's points in front of a camera project into the
        // hull of its corners, and depth is linear.
        let (a, b) = point_bounds(corners);
        if self.horizon(v).is_some() && b.z + rounding <= tolerance {
            return true;
        }
        let (n, margin) = (PIXELS as f64, 1e-6);
        let on_image = a.x - margin >= 0.0 && a.y - margin >= 0.0 && b.x + margin < n && b.y + margin < n;
        a.z - rounding > 0.0 && on_image && a.z - rounding >= f64::from(self.farthest_over(v, a, b)) - tolerance
    }

    /// The farthest depth of view `v`'s tiles under the pixels from `lo` to `hi`, with half a
    /// pixel around.
    fn farthest_over(&self, v: usize, lo: DVec3, hi: DVec3) -> f32 {
        self.farthest_in_tiles(v, tile_range(lo.x, hi.x), tile_range(lo.y, hi.y))
    }

    /// The farthest depth of view `v`'s tiles in `columns` and `rows` of tiles.
    fn farthest_in_tiles(&self, v: usize, columns: RangeInclusive<usize>, rows: RangeInclusive<usize>) -> f32 {
        let far = self.images(v).1;
        rows.flat_map(|ty| columns.clone().map(move |tx| far[ty * WindowTiles::ACROSS + tx]))
            .fold(0f32, f32::max)
    }

    /// View `v`'s image (each pixel's farthest depth nearby) and the farthest depth of each of
    /// its tiles, a row after another.
    fn images(&self, v: usize) -> (&[f32], &[f32]) {
        let pixels = PIXELS * PIXELS;
        (
            &self.depths[v * pixels..(v + 1) * pixels],
            &self.tiles[v * TILES..(v + 1) * TILES],
        )
    }

    /// Whether the images drawn in bands answer for these triangles (a box, a quad): none meets
    /// the curtain, and W″ ≠ 0 at their centre. They cross the surface nowhere, so W″ is the
    /// same all over them.
    fn band_answers(&self, triangles: &[[DVec3; 3]]) -> bool {
        self.band.as_ref().is_none_or(|band| {
            let points = triangles.len() as f64 * 3.0;
            let centre = triangles.iter().flatten().copied().sum::<DVec3>() / points;
            !band.walls.iter().any(|w| w.meets_any(triangles)) && band.up.net_crossings_above(centre) != 0
        })
    }

    /// [`OpenViews::seen_corners`] on the GPU.
    fn seen_corners_on(&self, gpu: &Gpu, grid: &Grid, needed: &[bool]) -> Result<Vec<bool>, GpuError> {
        // From points relative to the grid's origin to corners in voxel units.
        let size = grid.voxel_size;
        let to_corners = |r: [f64; 4]| [r[0] * size, r[1] * size, r[2] * size, r[3]].map(|v| v as f32);
        let mut rows = Vec::with_capacity(5 * self.views.len());
        for (v, view) in self.views.iter().enumerate() {
            let [x, y, w, mut depth] = view.projection_rows(grid.origin());
            // "In front of the depth by more than the tolerance", as one comparison.
            depth[3] += view.depth_tolerance();
            rows.extend([x, y, w, depth].map(to_corners));
            let limits = match self.horizon(v) {
                Some(horizon) => [(horizon - grid.origin().y) / size, 1.0, view.depth_tolerance(), 0.0],
                None => [f64::from(f32::MAX), 0.0, 0.0, 0.0],
            };
            rows.push(limits.map(|l| l as f32));
        }
        let words: Vec<[u32; 2]> = needed
            .par_chunks(32)
            .enumerate()
            .map(|(w, word)| [w as u32, word.iter().rev().fold(0, |bits, &n| bits << 1 | u32::from(n))])
            .filter(|&[_, bits]| bits != 0)
            .collect();
        let corner_dims = grid.dims.map(|d| d + 1);
        let seen = gpu::seen_corners(gpu, corner_dims, &words, &rows, &self.depths, &self.tiles, PIXELS)?;
        Ok((0..needed.len())
            .into_par_iter()
            .map(|c| seen[c / 32] & (1 << (c % 32)) != 0)
            .collect())
    }

    /// Whether no view sees any pixel of a box (its triangles, two a face as in
    /// [`BOX_FACES`](crate::occluder::BOX_FACES)) in front of the original. Faces turned away
    /// from a view are skipped: the faces turned towards it cover them. What the bands cannot
    /// answer for counts as shown.
    pub fn hides_box(&self, triangles: &[[DVec3; 3]; 12]) -> bool {
        triangles
            .chunks_exact(2)
            .all(|face| self.band_answers_rectangle(face[0], face[1][2]))
            && (0..self.views.len()).all(|v| self.hidden_from(v, triangles, true))
    }

    /// Whether no view sees any point of `panel` in front of the original. What the bands
    /// cannot answer for counts as shown.
    pub fn hides_panel(&self, panel: &Panel) -> bool {
        let triangles = panel.triangles();
        self.band_answers_rectangle(triangles[0], triangles[1][2])
            && (0..self.views.len()).all(|v| self.hidden_from(v, &triangles, false))
    }

    /// Whether view `v` sees no pixel of these triangles in front of the original.
    fn hidden_from(&self, v: usize, triangles: &[[DVec3; 3]], closed_convex: bool) -> bool {
        let view = &self.views[v];
        // Cameras in openings are perspective: a face turned away from their axis may still
        // face them.
        let skip_turned_away = closed_convex && self.horizon(v).is_none();
        triangles
            .iter()
            .filter(|t| !skip_turned_away || (t[1] - t[0]).cross(t[2] - t[0]).dot(view.dir) > 0.0)
            .all(|t| self.hides_triangle(v, t))
    }

    /// The largest rectangle of `panel` that no view sees: the panel cut into cells about one
    /// pixel of these views wide, a cell left out where a view sees a point of it or the bands
    /// cannot answer for it. `None` when no rectangle of at least 2 × 2 cells is hidden, or the
    /// rectangle still shows.
    pub fn hidden_part(&self, panel: &Panel) -> Option<Panel> {
        let [t, s] = panel.triangles();
        let cells = self.cells_of(t, s[2]);
        let [nu, nv] = cells.n;
        // The cells a point lies in, both where it lies on the line between two.
        let cells_at = |p: DVec3| {
            let d = p - cells.origin;
            let (a, b) = (
                d.dot(cells.u) / cells.u.length_squared() * nu as f64,
                d.dot(cells.v) / cells.v.length_squared() * nv as f64,
            );
            let around = |x: f64, n: usize| [clamped_index(x - 1e-6, n), clamped_index(x + 1e-6, n)];
            let (ia, ib) = (around(a, nu), around(b, nv));
            ia.into_iter().flat_map(move |i| ib.map(|j| i * nv + j))
        };
        let mut hidden = match self.unanswered_cells(&[t, s], &cells) {
            Some(unanswered) => unanswered.into_iter().map(|u| !u).collect(),
            None => vec![true; nu * nv],
        };
        let mut left = hidden.iter().filter(|&&h| h).count();
        // View after view, until too few cells are left to hold a rectangle of 2 × 2.
        for view in 0..self.views.len() {
            if left < 4 {
                return None;
            }
            for triangle in [t, s] {
                self.visit_seen(view, &triangle, |p| {
                    for cell in cells_at(p) {
                        left -= usize::from(std::mem::replace(&mut hidden[cell], false));
                    }
                });
            }
        }
        let part = rectangle::largest(&hidden, nu, nv, 2)?;
        let [i, j] = [part.u, part.v];
        let corners = [[i[0], j[0]], [i[1], j[0]], [i[1], j[1]], [i[0], j[1]]];
        let part = Panel {
            shape: panel.shape,
            corners: corners.map(|[i, j]| cells.at(i, j).to_array()),
        };
        // Cut along pixel centres, the part is checked again as a whole.
        self.hides_panel(&part).then_some(part)
    }

    /// The rectangle with corners `a`, `b`, `c` (its first triangle) and `d` cut into cells
    /// about one pixel of the sky views wide.
    fn cells_of(&self, [a, b, _]: [DVec3; 3], d: DVec3) -> RectangleCells {
        let (u, v) = (b - a, d - a);
        let cells = |side: DVec3| ((side.length() / self.pixel).ceil() as usize).clamp(1, MAX_PART_CELLS);
        RectangleCells {
            origin: a,
            u,
            v,
            n: [cells(u), cells(v)],
        }
    }

    /// The cells of a rectangle (its two triangles) the bands may answer wrongly for, or `None`
    /// where they answer for all of it ([`OpenViews::band_answers`]). A cell is answered where
    /// W″ ≠ 0 all over it, or where a wall meets it and it is small enough that every pixel it
    /// reads lies in each sky view's window.
    fn unanswered_cells(&self, triangles: &[[DVec3; 3]; 2], cells: &RectangleCells) -> Option<Vec<bool>> {
        let band = self.band.as_ref().filter(|_| !self.band_answers(triangles))?;
        let [nu, nv] = cells.n;
        let diagonal = (cells.u / nu as f64).length().hypot((cells.v / nv as f64).length()) / self.pixel;
        Some(band::unanswered_cells(
            &band.walls,
            &band.up,
            |i, j| cells.at(i, j),
            cells.n,
            diagonal + NEARBY_READ < BAND_MARGIN,
        ))
    }

    /// Whether the bands answer for every point of the rectangle with corners `a`, `b`, `c`
    /// (its first triangle) and `d`.
    fn band_answers_rectangle(&self, triangle: [DVec3; 3], d: DVec3) -> bool {
        let triangles = [triangle, [triangle[0], triangle[2], d]];
        self.unanswered_cells(&triangles, &self.cells_of(triangle, d))
            .is_none_or(|unanswered| !unanswered.contains(&true))
    }

    fn hides_triangle(&self, v: usize, triangle: &[DVec3; 3]) -> bool {
        let mut hidden = true;
        self.visit_seen(v, triangle, |_| hidden = false);
        hidden
    }

    /// Calls `seen` with the point of `triangle` at each pixel where view `v` sees it in front
    /// of the original. A camera in an opening counts only what lies no higher than the opening.
    fn visit_seen(&self, v: usize, triangle: &[DVec3; 3], mut seen: impl FnMut(DVec3)) {
        let (view, (depth, far)) = (&self.views[v], self.images(v));
        let (tolerance, horizon) = (view.depth_tolerance(), self.horizon(v));
        let mut visit = |i: usize, d: f64| {
            if d < f64::from(depth[i]) - tolerance {
                let p = view.unproject(i, d);
                if horizon.is_none_or(|h| p.y <= h) {
                    seen(p);
                }
            }
        };
        if let Some(horizon) = horizon {
            // A triangle wholly above the opening's highest point counts nowhere: its pixels
            // unproject to points of it, give or take rounding.
            let lowest = triangle[0].y.min(triangle[1].y).min(triangle[2].y);
            // The quick answer, as for the sky views below: nothing shows where no pixel the
            // triangle may draw lies nearer than the farthest depth of the tiles they fall in.
            let tiles = |pixels: RangeInclusive<usize>| pixels.start() / TILE..=pixels.end() / TILE;
            let behind = || {
                raster::nearest_drawn(view, triangle).is_some_and(|(nearest, [xs, ys])| {
                    nearest >= f64::from(self.farthest_in_tiles(v, tiles(xs), tiles(ys))) - tolerance
                })
            };
            if lowest - self.rounding() <= horizon && !behind() {
                rasterize(view, triangle, visit);
            }
            return;
        }
        let corners = triangle.map(|p| view.project(p));
        let (lo, hi) = (
            corners[0].min(corners[1]).min(corners[2]),
            corners[0].max(corners[1]).max(corners[2]),
        );
        // The quick answer: a triangle on screen whose nearest corner lies behind the farthest
        // depth of every tile under its screen bounds shows nowhere.
        let farthest = self.farthest_over(v, lo, hi);
        let (columns, rows) = (tile_range(lo.x, hi.x), tile_range(lo.y, hi.y));
        let tiles = WindowTiles::ACROSS;
        let on_screen = lo.x >= 0.0 && lo.y >= 0.0 && hi.x <= PIXELS as f64 && hi.y <= PIXELS as f64;
        if on_screen && lo.z >= f64::from(farthest) - tolerance {
            return;
        }
        // Else only the runs of tiles where the triangle may lie in front of the tile's
        // farthest depth are drawn: elsewhere no pixel of it shows.
        let nearest = NearestDepth::new(corners, self.rounding());
        let hidden = |tx: usize, ty: usize| {
            let centres = |t: usize| [(t * TILE) as f64 + 0.5, ((t + 1) * TILE) as f64 - 0.5];
            nearest.over(centres(tx), centres(ty)) >= f64::from(far[ty * tiles + tx]) - tolerance
        };
        for ty in rows {
            let mut tx = *columns.start();
            while tx <= *columns.end() {
                if hidden(tx, ty) {
                    tx += 1;
                    continue;
                }
                let first = tx;
                while tx < *columns.end() && !hidden(tx + 1, ty) {
                    tx += 1;
                }
                let (xs, ys) = (first * TILE..=(tx + 1) * TILE - 1, ty * TILE..=(ty + 1) * TILE - 1);
                rasterize_within(view, triangle, xs, ys, &mut visit);
                tx += 1;
            }
        }
    }
}

/// A lower bound on the depth of a triangle of an orthographic view over a rectangle of the
/// screen: the lower of its plane's depths at the rectangle's corners, and no lower than its
/// nearest corner.
struct NearestDepth {
    corners: [DVec3; 3],
    /// The depth of the nearest corner: no point of the triangle is nearer.
    nearest_corner: f64,
    /// Depth per pixel along x and y, where the triangle spans an area on screen.
    slope: Option<[f64; 2]>,
    /// What rounding may take off a depth the rasterizer interpolates.
    margin: f64,
}

impl NearestDepth {
    /// `corners` as [`View::project`] gives them; `margin` as [`OpenViews::rounding`] gives it.
    fn new(corners: [DVec3; 3], margin: f64) -> NearestDepth {
        let (a, b) = (corners[1] - corners[0], corners[2] - corners[0]);
        let area = a.x * b.y - a.y * b.x;
        let slope = [(a.z * b.y - b.z * a.y) / area, (b.z * a.x - a.z * b.x) / area];
        NearestDepth {
            corners,
            nearest_corner: corners[0].z.min(corners[1].z).min(corners[2].z),
            slope: slope.iter().all(|s| s.is_finite()).then_some(slope),
            margin,
        }
    }

    /// The lowest depth over x in `xs` and y in `ys` (each [low, high]).
    fn over(&self, xs: [f64; 2], ys: [f64; 2]) -> f64 {
        let c = self.corners;
        let on_plane = self.slope.map_or(f64::NEG_INFINITY, |[sx, sy]| {
            let low = |s: f64, range: [f64; 2], at: f64| (s * (range[0] - at)).min(s * (range[1] - at));
            c[0].z + low(sx, xs, c[0].x) + low(sy, ys, c[0].y)
        });
        on_plane.max(self.nearest_corner) - self.margin
    }
}

/// The triangles of `meshlets` that may hide from `view`, a camera in an opening, a point it
/// counts: one no higher than `horizon` (the opening's highest point, at least the camera's own
/// height). `sphere` is the mesh's bounding sphere.
///
/// A triangle hides what lies behind it along a ray, and the 3×3 farthest depths carry its depth
/// to rays up to 1.5 pixels away (a neighbour's centre, and a point anywhere in the pixel).
/// Behind a triangle's point at depth d, such a ray is lower than that point by at most the
/// tolerance times the steepest rise, plus d times what two such rays' rises differ by; a ray
/// that falls there comes from no higher than the camera. So a triangle whose lowest corner
/// clears the horizon by that much, at its farthest corner's depth, hides nothing counted. Two
/// pixels' spread and twice the tolerance leave room for rounding.
///
/// Triangles wholly beyond a side of the view's frustum are left out too: they draw nothing.
/// Both tests go by meshlet first: a side that all its bounds' corners lie beyond holds all
/// its points, as the region beyond a side is convex, and none of its triangles clears less
/// than its lowest point.
fn may_hide_counted(meshlets: &[Meshlet], sphere: (DVec3, f64), view: &View, horizon: f64) -> Mesh {
    let (rise, spread) = view.ray_rise(2.0);
    let clear = horizon + 2.0 * view.depth_tolerance() * rise;
    // Depth is linear with a unit gradient: no point of the mesh lies deeper.
    let deepest = view.project(sphere.0).z + sphere.1;
    let clears_every_depth = clear + deepest.max(0.0) * spread;
    let may_hide = |corners: [Vec3; 3]| {
        let low = f64::from(corners.iter().map(|p| p.y).fold(f32::INFINITY, f32::min));
        low <= clear
            || low <= clears_every_depth && {
                let farthest = corners.iter().map(|p| view.project(p.as_dvec3()).z).fold(0.0, f64::max);
                low <= clear + farthest * spread
            }
    };
    let mut kept = Mesh::default();
    let mut beyond = Vec::new();
    for meshlet in meshlets {
        let beyond_a_side = meshlet
            .box_corners()
            .iter()
            .fold(0xf, |sides, &c| sides & view.beyond_sides(c))
            != 0;
        if meshlet.lo.y > clears_every_depth || beyond_a_side {
            continue;
        }
        beyond.clear();
        beyond.extend(meshlet.mesh.positions.iter().map(|p| view.beyond_sides(p.as_dvec3())));
        let first = kept.positions.len() as u32;
        let before = kept.triangles.len();
        kept.triangles.extend(
            (0..meshlet.mesh.triangles.len())
                .filter(|&t| {
                    let corners = meshlet.mesh.triangles[t];
                    corners.iter().fold(0xf, |sides, &v| sides & beyond[v as usize]) == 0
                        && may_hide(meshlet.mesh.corners(t))
                })
                .map(|t| meshlet.mesh.triangles[t].map(|i| first + i)),
        );
        if kept.triangles.len() > before {
            kept.positions.extend(&meshlet.mesh.positions);
        }
    }
    kept
}

/// The index of grid corner [x, y, z] (z fastest) among the grid's corners.
fn corner_index(grid: &Grid, [x, y, z]: [usize; 3]) -> usize {
    (x * (grid.dims[1] + 1) + y) * (grid.dims[2] + 1) + z
}

/// The needed grid corners in bricks of `CORNER_BRICK` along each side: brick b's are
/// `corners[starts[b]..starts[b + 1]]`, at `points` in the world, within `bounds[b]`. Bricks
/// with no needed corner are left out.
struct CornerBricks {
    starts: Vec<usize>,
    corners: Vec<usize>,
    points: Vec<DVec3>,
    bounds: Vec<(DVec3, DVec3)>,
}

impl CornerBricks {
    fn new(grid: &Grid, needed: &[bool]) -> CornerBricks {
        let dims = grid.dims.map(|d| d + 1);
        let starts = |k: usize| (0..dims[k]).step_by(CORNER_BRICK);
        let firsts: Vec<[usize; 3]> = starts(0)
            .flat_map(|x| starts(1).flat_map(move |y| starts(2).map(move |z| [x, y, z])))
            .collect();
        let found: Vec<_> = firsts
            .par_iter()
            .map(|&first| -> (Vec<usize>, Vec<DVec3>) {
                let span = |k: usize| first[k]..(first[k] + CORNER_BRICK).min(dims[k]);
                span(0)
                    .flat_map(|x| span(1).flat_map(move |y| span(2).map(move |z| [x, y, z])))
                    .filter_map(|c| {
                        let index = corner_index(grid, c);
                        needed[index].then(|| (index, corner_point(grid, c)))
                    })
                    .unzip()
            })
            .filter(|(corners, _)| !corners.is_empty())
            .collect();
        let mut bricks = CornerBricks {
            starts: vec![0],
            corners: Vec::new(),
            points: Vec::new(),
            bounds: Vec::new(),
        };
        for (corners, points) in found {
            bricks.bounds.push(point_bounds(points.iter().copied()));
            bricks.corners.extend(corners);
            bricks.points.extend(points);
            bricks.starts.push(bricks.corners.len());
        }
        bricks
    }

    /// `flags`, a flag per corner, as each brick's, brick after brick.
    fn split<'a>(&self, mut flags: &'a mut [bool]) -> Vec<&'a mut [bool]> {
        let mut split = Vec::with_capacity(self.bounds.len());
        for run in self.starts.windows(2) {
            let (brick, rest) = flags.split_at_mut(run[1] - run[0]);
            split.push(brick);
            flags = rest;
        }
        split
    }
}

/// Depth image memory a finished cook left for the next in this process: pages faulted in and
/// zeroed by the kernel cost a worker that cooks mesh after mesh more CPU time than some meshes'
/// whole views take to draw. The largest returned: at most 160 sky views and six for each of
/// `MAX_EYES + MAX_ENCLOSED_EYES` cameras, 99 MB.
static SPARE_DEPTHS: Mutex<Vec<f32>> = Mutex::new(Vec::new());

/// Memory for `len` depths, of whatever values: each is written before it is read. Fresh memory
/// has room for the most views, and is left to the kernel to zero where the views first write
/// it, on every thread.
fn depth_memory(len: usize) -> Vec<f32> {
    let mut depths = std::mem::take(&mut *SPARE_DEPTHS.lock().unwrap_or_else(PoisonError::into_inner));
    if depths.capacity() < len {
        let most = MAX_VIEWS * PIXELS * PIXELS;
        depths = vec![0.0; len.max(most)];
    }
    depths.truncate(len);
    depths.resize(len, 0.0);
    depths
}

impl Drop for OpenViews {
    fn drop(&mut self) {
        let mut spare = SPARE_DEPTHS.lock().unwrap_or_else(PoisonError::into_inner);
        if spare.capacity() < self.depths.capacity() {
            *spare = std::mem::take(&mut self.depths);
        }
    }
}

/// The tiles whose pixel centres may lie in [a, b] along one axis of the screen.
fn tile_range(a: f64, b: f64) -> std::ops::RangeInclusive<usize> {
    let last = (WindowTiles::ACROSS - 1) as f64;
    let tile = |x: f64| (x / TILE as f64).floor().clamp(0.0, last) as usize;
    tile(a - 0.5)..=tile(b + 0.5)
}

/// The farthest depth of each TILE × TILE tile, into `out` (zeroed).
fn farthest_per_tile(depth: &[f32], n: usize, out: &mut [f32]) {
    for (y, row) in depth.chunks_exact(n).enumerate() {
        let tiles = &mut out[(y / TILE) * (n / TILE)..(y / TILE + 1) * (n / TILE)];
        for (far, pixels) in tiles.iter_mut().zip(row.chunks_exact(TILE)) {
            *far = pixels.iter().fold(*far, |a, &b| a.max(b));
        }
    }
}

/// [`farthest_nearby`] of a sky view's image that is 0 outside its `window`: only in the rows of
/// tiles that hold some of the window, and a pixel row either side, can the result be other than 0.
fn farthest_nearby_in_window(window: &[bool], depth: &[f32], out: &mut [f32]) {
    out.fill(0.0);
    let held: Vec<bool> = window
        .chunks_exact(WindowTiles::ACROSS)
        .map(|tiles| tiles.contains(&true))
        .collect();
    let mut first = 0;
    for run in held.chunk_by(|a, b| a == b) {
        let tile_rows = first..first + run.len();
        first = tile_rows.end;
        if run[0] {
            // Outside the run the image is 0, which no depth here is below.
            let rows = (tile_rows.start * TILE).saturating_sub(1)..(tile_rows.end * TILE + 1).min(PIXELS);
            let pixels = rows.start * PIXELS..rows.end * PIXELS;
            farthest_nearby(&depth[pixels.clone()], PIXELS, &mut out[pixels]);
        }
    }
}

/// Each pixel's farthest depth over its 3×3 neighbourhood (infinite where any is empty), into
/// `out`: the farthest over each row's neighbours, then over those of the rows around. Rows are
/// `n` wide, `n` at least 2, and there are at least 2 of them. Depths are never NaN.
fn farthest_nearby(depth: &[f32], n: usize, out: &mut [f32]) {
    // Slices zipped, in AVX2's wider lanes where the CPU has them: the same maxima, one
    // instruction each, as no depth is NaN.
    let max3 = |a: f32, b: f32, c: f32| greater(greater(a, b), c);
    with_avx2(|| {
        for (row, far) in depth.chunks_exact(n).zip(out.chunks_exact_mut(n)) {
            far[0] = max3(row[0], row[1], 0.0);
            let around = row.iter().zip(&row[1..]).zip(&row[2..]);
            for (far, ((left, this), right)) in far[1..n - 1].iter_mut().zip(around) {
                *far = greater(max3(*left, *this, *right), 0.0);
            }
            far[n - 1] = max3(row[n - 2], row[n - 1], 0.0);
        }
        // Over the rows around, in place, with the row above and this one as they were kept
        // aside: no image-sized buffer, whose pages a fresh allocation would fault in view
        // after view.
        let rows = out.len() / n;
        let (mut above, mut this) = (out[..n].to_vec(), vec![0f32; n]);
        for y in 0..rows {
            this.copy_from_slice(&out[y * n..(y + 1) * n]);
            let (upto, rest) = out.split_at_mut((y + 1) * n);
            let below = if y + 1 < rows { &rest[..n] } else { &this[..] };
            let around = above.iter().zip(&this).zip(below);
            for (far, ((above, this), below)) in upto[y * n..].iter_mut().zip(around) {
                *far = max3(*above, *this, *below);
            }
            std::mem::swap(&mut above, &mut this);
        }
    })
}

/// A mesh's triangles along a crack, which the views draw eroded, apart from the rest.
struct CrackSplit {
    /// The triangles along no crack, where some lie along one.
    uncracked: Option<Mesh>,
    /// Those along a crack as a soup of their own, so that each view projects their corners in
    /// one pass, and each one's edges along the crack.
    soup: Mesh,
    eroded: Vec<[bool; 3]>,
}

impl CrackSplit {
    /// `cracked` as [`crack_edges`] finds it.
    fn new(mesh: &Mesh, cracked: &BTreeMap<usize, [bool; 3]>) -> CrackSplit {
        let uncracked = (!cracked.is_empty()).then(|| Mesh {
            positions: mesh.positions.clone(),
            triangles: (0..mesh.triangles.len())
                .filter(|t| !cracked.contains_key(t))
                .map(|t| mesh.triangles[t])
                .collect(),
        });
        let soup = Mesh {
            positions: cracked.keys().flat_map(|&t| mesh.corners(t)).collect(),
            triangles: (0..cracked.len() as u32)
                .map(|k| [3 * k, 3 * k + 1, 3 * k + 2])
                .collect(),
        };
        let eroded = cracked.values().copied().collect();
        CrackSplit {
            uncracked,
            soup,
            eroded,
        }
    }
}

/// Where to place cameras in the mesh's openings (connected runs of boundary edges), at most
/// [`MAX_EYES`], the largest openings first. Each opening gives its centre and points of its rim
/// spread farthest apart, drawn a fifth of the way towards the centre. A point where the winding
/// number is near a half lies in a real gap and stays. Where another part fills the middle of an
/// opening (a lid in a rim), a rim point is tried instead two pixels (`pixel`) off the rim, into
/// the gap beside it: towards the centre, or on from the rim's triangles. Failing those, a point
/// is moved along the opening's normal to the nearest point outside the solid, so that it sees
/// in only through a real gap. Each camera comes with the height it counts up to: its opening's
/// highest point, or its own where it moved higher. Cameras whose height is at the very bottom
/// of the mesh are left out: nothing lies lower for them to show.
///
/// Besides, for each of those points, the first of it and the two beside the rim where the
/// winding number is near k + ½ for some k ≥ 1: in a gap of a part that lies inside another, a
/// camera of its own if a view sees it ([`OpenViews::add_enclosed_eyes`]). After them come the
/// points at the mouths of openings inside other parts ([`mouth_points`]), for the same test.
fn opening_eyes(
    mesh: &Mesh,
    boundary: &[BoundaryEdge],
    field: &WindingField,
    pixel: f64,
) -> (Vec<Camera>, Vec<Camera>, Vec<Camera>) {
    let position = |v: u32| mesh.positions[v as usize].as_dvec3();
    let mut openings = openings(mesh, boundary);
    openings.sort_by(|a, b| b.size.total_cmp(&a.size));
    // The way into the opening beside each rim vertex.
    let off = off_rim(mesh, boundary);
    let (lo, hi) = mesh.bounds();
    let size = f64::from((hi - lo).length());
    let bottom = f64::from(lo.y) + 1e-3 * size;
    let (mut eyes, mut enclosed): (Vec<Camera>, _) = (Vec::new(), Vec::new());
    let mut mouths = Vec::new();
    for Rim {
        vertices: rim,
        edges,
        area,
        size: opening_size,
    } in &openings
    {
        let centre = rim.iter().map(|&v| position(v)).sum::<DVec3>() / rim.len() as f64;
        let mut chosen: Vec<Option<u32>> = vec![None];
        while chosen.len() < EYES_PER_OPENING.min(rim.len() + 1) {
            let at = |c: &Option<u32>| c.map_or(centre, position);
            let distance = |v: u32| {
                chosen
                    .iter()
                    .map(|c| at(c).distance(position(v)))
                    .fold(f64::INFINITY, f64::min)
            };
            chosen.extend(
                rim.iter()
                    .max_by(|&&a, &&b| distance(a).total_cmp(&distance(b)))
                    .map(|&v| Some(v)),
            );
        }
        let normal = area.try_normalize().unwrap_or(DVec3::Y);
        let reach = opening_size.max(1e-3 * size);
        let outside_along_normal = |p: DVec3| {
            // Steps of a sixteenth of the opening, both ways, nearest first.
            (1..=16)
                .flat_map(|k| [1.0, -1.0].map(|side| p + normal * (side * reach * k as f64 / 16.0)))
                .find(|&q| field.winding(q) < 0.5)
        };
        let top = rim.iter().map(|&v| position(v).y).fold(f64::NEG_INFINITY, f64::max);
        // A camera at `p` counts up to the opening's top, or its own height where higher.
        let camera = |p: DVec3| Some((p, top.max(p.y))).filter(|&(_, horizon)| horizon > bottom);
        for c in &chosen {
            // The centre or a rim point drawn in, if in a gap; else, for a rim point, two pixels
            // off the rim: towards the centre, then away from the rim's triangles; else moved out.
            // The first of them in a gap of a part inside another is kept as well.
            let first = c.map_or(centre, |v| position(v) + (centre - position(v)) * 0.2);
            let beside = |v: u32, d: DVec3| position(v) + d.normalize_or_zero() * 2.0 * pixel;
            let away = |v: u32| off.get(&v).copied();
            let besides = c.iter().flat_map(|&v| {
                let towards = std::iter::once_with(move || beside(v, centre - position(v)));
                towards.chain(std::iter::once_with(move || beside(v, away(v).unwrap_or_default())))
            });
            let (mut eye, mut inside_another) = (None, None);
            for p in std::iter::once(first).chain(besides) {
                match gap_depth(field.winding(p)) {
                    Some(0) => {
                        eye = Some(p);
                        break;
                    }
                    Some(_) => inside_another = inside_another.or(Some(p)),
                    None => {}
                }
            }
            eyes.extend(eye.or_else(|| outside_along_normal(first)).and_then(camera));
            enclosed.extend(inside_another.and_then(camera));
        }
        mouths.extend(
            mouth_points(edges.iter().map(|&i| &boundary[i]), &off, field, pixel, position)
                .into_iter()
                .filter_map(camera),
        );
        if eyes.len() >= MAX_EYES {
            eyes.truncate(MAX_EYES);
            break;
        }
    }
    (eyes, enclosed, mouths)
}

/// Points two pixels (`pixel`) off an opening's rim (`rim`, its edges) into the opening, every
/// two pixels along it, where the winding number is near a whole number k >= 1: the
/// opening's mouth where it lies inside k other parts, its own share there far from a half, as
/// in a slot between a lid and its rim, which [`gap_depth`] misses; or a window where two
/// parts' openings cross, a half from each. What lies inside those parts shows through there,
/// in directions that neither the opening's own cameras nor the sky views may sample. One
/// point per eight pixels of rim at most.
fn mouth_points<'e>(
    rim: impl Iterator<Item = &'e BoundaryEdge>,
    off: &HashMap<u32, DVec3>,
    field: &WindingField,
    pixel: f64,
    position: impl Fn(u32) -> DVec3,
) -> Vec<DVec3> {
    let samples: Vec<DVec3> = rim
        .flat_map(|e| {
            let (a, b) = (position(e.a), position(e.b));
            let into = [e.a, e.b]
                .iter()
                .map(|v| off.get(v).copied().unwrap_or_default())
                .sum::<DVec3>()
                .normalize_or_zero();
            let steps = (a.distance(b) / (2.0 * pixel)).ceil().max(1.0) as usize;
            (0..steps).map(move |k| a.lerp(b, (k as f64 + 0.5) / steps as f64) + into * 2.0 * pixel)
        })
        .collect();
    let mut points: Vec<DVec3> = Vec::new();
    for (&p, (winding, bound)) in samples.iter().zip(field.bounded_windings(&samples)) {
        let whole = winding.round();
        if whole >= 1.0
            && (winding - whole).abs() + bound < MOUTH_WINDING
            && points.iter().all(|q| q.distance(p) > 8.0 * pixel)
        {
            points.push(p);
        }
    }
    points
}

/// For a winding number near k + ½ (within [`OPEN_WINDING`]), k: the point lies in a gap of one
/// part, inside k others (0: open to the outside).
fn gap_depth(winding: f64) -> Option<u32> {
    let k = (winding - 0.5).round();
    ((winding - 0.5 - k).abs() < OPEN_WINDING && k >= 0.0).then_some(k as u32)
}

/// An opening's rim: a connected run of boundary edges.
struct Rim {
    /// Its vertices.
    vertices: Vec<u32>,
    /// Its edges, as indices into the boundary, in the boundary's order.
    edges: Vec<usize>,
    /// Its vector area.
    area: DVec3,
    /// Its extent.
    size: f64,
}

/// Each opening's rim.
fn openings(mesh: &Mesh, boundary: &[BoundaryEdge]) -> Vec<Rim> {
    let mut neighbours: HashMap<u32, Vec<usize>> = HashMap::new();
    for (i, e) in boundary.iter().enumerate() {
        neighbours.entry(e.a).or_default().push(i);
        neighbours.entry(e.b).or_default().push(i);
    }
    let mut starts: Vec<u32> = neighbours.keys().copied().collect();
    starts.sort_unstable();
    let position = |v: u32| mesh.positions[v as usize].as_dvec3();
    let mut visited = HashSet::new();
    let extent = |rim: &[u32]| {
        let (lo, hi) = crate::mesh::point_bounds(rim.iter().map(|&v| position(v)));
        (hi - lo).length()
    };
    let mut openings = Vec::new();
    for start in starts {
        let (mut stack, mut rim, mut edges, mut area) = (vec![start], Vec::new(), Vec::new(), DVec3::ZERO);
        while let Some(v) = stack.pop() {
            if visited.insert(v) {
                rim.push(v);
                for &i in &neighbours[&v] {
                    let e = &boundary[i];
                    stack.push(if e.a == v { e.b } else { e.a });
                    // Each edge is met from both ends: counted from its first.
                    if e.a == v {
                        edges.push(i);
                        area += position(e.a).cross(position(e.b)) * f64::from(e.weight) * 0.5;
                    }
                }
            }
        }
        if !rim.is_empty() {
            // An edge from a vertex to itself is met twice from its first.
            edges.sort_unstable();
            edges.dedup();
            let size = extent(&rim);
            openings.push(Rim {
                vertices: rim,
                edges,
                area,
                size,
            });
        }
    }
    openings
}

/// Per vertex of a boundary edge, the way off the surface into the opening beside it: for each
/// of its boundary edges, away from the edge's triangle in that triangle's plane, summed.
fn off_rim(mesh: &Mesh, boundary: &[BoundaryEdge]) -> HashMap<u32, DVec3> {
    let edges: HashSet<(u32, u32)> = boundary.iter().map(|e| (e.a.min(e.b), e.a.max(e.b))).collect();
    let mut on_rim = vec![false; mesh.positions.len()];
    for &(a, b) in &edges {
        (on_rim[a as usize], on_rim[b as usize]) = (true, true);
    }
    let position = |v: u32| mesh.positions[v as usize].as_dvec3();
    let mut off: HashMap<u32, DVec3> = HashMap::new();
    for tri in mesh
        .triangles
        .iter()
        .filter(|t| t.iter().filter(|&&v| on_rim[v as usize]).count() >= 2)
    {
        for k in 0..3 {
            let (a, b, c) = (tri[(k + 1) % 3], tri[(k + 2) % 3], tri[k]);
            if !edges.contains(&(a.min(b), a.max(b))) {
                continue;
            }
            let along = (position(b) - position(a)).normalize_or_zero();
            let away = position(a) - position(c);
            let away = (away - along * away.dot(along)).normalize_or_zero();
            *off.entry(a).or_default() += away;
            *off.entry(b).or_default() += away;
        }
    }
    off
}

/// Per triangle with a boundary edge along a crack, which of its edges (edge k joins corners
/// k + 1 and k + 2) do: another part of the surface, one that shares neither of the edge's
/// corners, lies within `width` of a point of the edge but farther than `touching`.
fn crack_edges(mesh: &Mesh, boundary: &[BoundaryEdge], width: f64, touching: f64) -> BTreeMap<usize, [bool; 3]> {
    let index = SurfaceIndex::new(mesh, width);
    let position = |v: u32| mesh.positions[v as usize].as_dvec3();
    let cracks: HashSet<(u32, u32)> = boundary
        .par_iter()
        .filter(|e| {
            let (a, b) = (position(e.a), position(e.b));
            [0.25, 0.5, 0.75]
                .into_iter()
                .any(|s| index.near_apart(a.lerp(b, s), touching, [e.a, e.b]))
        })
        .map(|e| (e.a.min(e.b), e.a.max(e.b)))
        .collect();
    // Only a triangle with two corners on cracks can have an edge along one.
    let mut on_crack = vec![false; mesh.positions.len()];
    for &(a, b) in &cracks {
        (on_crack[a as usize], on_crack[b as usize]) = (true, true);
    }
    let mut cracked = BTreeMap::new();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if tri.iter().filter(|&&v| on_crack[v as usize]).count() < 2 {
            continue;
        }
        let edges: [bool; 3] = std::array::from_fn(|k| {
            let (a, b) = (tri[(k + 1) % 3], tri[(k + 2) % 3]);
            cracks.contains(&(a.min(b), a.max(b)))
        });
        if edges.contains(&true) {
            cracked.insert(t, edges);
        }
    }
    cracked
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::raster::depth_image;
    use crate::mesh::topology::orient_closed_components;
    use crate::occluder::{BOX_FACES, Shape};
    use glam::Vec3;

    /// A unit cube cut down the middle (x = 0.5) into two boxes `gap` apart, each open towards
    /// the other: with a gap, a crack runs through the cube from top to bottom.
    fn split_cube(gap: f32) -> Mesh {
        let mut mesh = Mesh::default();
        for (lo, hi, open_face) in [(0.0, 0.5 - gap / 2.0, 1), (0.5 + gap / 2.0, 1.0, 0)] {
            let corner = |i: usize| {
                let pick = |bit: usize, a: f32, b: f32| if i & bit == 0 { a } else { b };
                Vec3::new(pick(1, lo, hi), pick(2, 0.0, 1.0), pick(4, 0.0, 1.0))
            };
            let base = mesh.positions.len() as u32;
            mesh.positions.extend((0..8).map(corner));
            for (_, q) in BOX_FACES.iter().enumerate().filter(|&(f, _)| f != open_face) {
                let q = q.map(|i| base + i as u32);
                mesh.triangles.extend([[q[0], q[1], q[2]], [q[0], q[2], q[3]]]);
            }
        }
        mesh
    }

    fn views_of(mut mesh: Mesh) -> OpenViews {
        let topology = orient_closed_components(&mut mesh);
        let field = WindingField::new(&mesh, &topology.boundary);
        let grid = Grid::fit(Vec3::ZERO, Vec3::ONE, 4);
        let no_inner = vec![false; grid.len()];
        OpenViews::new(&mesh, &topology.boundary, || &field, None, (&grid, &no_inner)).expect("the CPU draws")
    }

    /// A unit cube, open on face `open` (of [`BOX_FACES`]) if any, oriented, with its boundary.
    pub(super) fn open_cube(open: Option<usize>) -> (Mesh, Vec<BoundaryEdge>) {
        let mut mesh = Mesh {
            positions: (0..8)
                .map(|i| Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32))
                .collect(),
            triangles: Vec::new(),
        };
        for (_, q) in BOX_FACES.iter().enumerate().filter(|&(f, _)| Some(f) != open) {
            let q = q.map(|i| i as u32);
            mesh.triangles.extend([[q[0], q[1], q[2]], [q[0], q[2], q[3]]]);
        }
        let topology = orient_closed_components(&mut mesh);
        (mesh, topology.boundary)
    }

    /// [`open_cube`] with a grid over it, the voxels wholly inside the cube inner.
    fn open_box(open: usize) -> (Mesh, Vec<BoundaryEdge>, Grid, Vec<bool>) {
        let (mesh, boundary) = open_cube(Some(open));
        let grid = Grid::fit(Vec3::ZERO, Vec3::ONE, 10);
        let inner = (0..grid.len())
            .map(|i| {
                let [x, y, z] = grid.coords(i);
                let lo = grid.to_world(DVec3::new(x as f64, y as f64, z as f64));
                let hi = lo + grid.voxel_size;
                lo.min_element() > 1e-9 && hi.max_element() < 1.0 - 1e-9
            })
            .collect();
        (mesh, boundary, grid, inner)
    }

    #[test]
    fn where_the_sky_views_are_drawn_in_bands_every_corner_they_hide_is_behind_the_surface() {
        // Open on the side at x = 1: the top lies over every inner corner (W″ = 1), and from
        // the right the inside shows through the opening.
        let (mesh, boundary, grid, inner) = open_box(1);
        let field = WindingField::new(&mesh, &boundary);
        let views = OpenViews::new(&mesh, &boundary, || &field, None, (&grid, &inner)).expect("the CPU draws");
        assert!(views.band.is_some(), "every inner corner has W″ ≠ 0");
        let needed = needed_corners(&grid, &inner);
        let (mut seen, mut hidden) = (0, 0);
        let [nx, ny, nz] = grid.dims;
        let corners = (0..=nx).flat_map(|x| (0..=ny).flat_map(move |y| (0..=nz).map(move |z| [x, y, z])));
        for corner in corners.filter(|&c| needed[corner_index(&grid, c)]) {
            let p = corner_point(&grid, corner);
            for v in 0..views.sky_views {
                if views.sees(v, p) {
                    seen += 1;
                } else {
                    hidden += 1;
                    assert!(
                        line_blocked(&meshlets(&mesh), p, views.views[v].dir, f64::INFINITY),
                        "view {v} hides {p} in the open"
                    );
                }
            }
        }
        assert!(seen > 1_000 && hidden > 10_000, "{seen} seen, {hidden} hidden");
        // A quad through the opening meets the curtain hanging from its top edge, and counts as
        // shown; one deep inside does not.
        let quad = |x: [f64; 2]| Panel {
            shape: Shape::Quads,
            corners: [[x[0], 0.5, 0.2], [x[1], 0.5, 0.2], [x[1], 0.5, 0.8], [x[0], 0.5, 0.8]],
        };
        assert!(!views.band_answers(&quad([0.6, 1.4]).triangles()));
        assert!(!views.hides_panel(&quad([0.6, 1.4])));
        assert!(views.band_answers(&quad([0.1, 0.3]).triangles()));
    }

    #[test]
    fn an_inside_open_to_the_sky_is_drawn_whole() {
        // Open at the top (face 3, y = 1): nothing lies over the inside, so W″ = 0 there.
        let (mesh, boundary, grid, inner) = open_box(3);
        let field = WindingField::new(&mesh, &boundary);
        let views = OpenViews::new(&mesh, &boundary, || &field, None, (&grid, &inner)).expect("the CPU draws");
        assert!(views.band.is_none());
    }

    #[test]
    fn depths_drawn_into_memory_a_cook_left_are_those_drawn_into_fresh_memory() {
        let first = views_of(split_cube(0.004));
        // Left holding what no view draws, and more of it than the views need.
        *SPARE_DEPTHS.lock().unwrap() = vec![f32::NAN; 2 * first.depths.len()];
        let again = views_of(split_cube(0.004));
        assert_eq!(first.depths.len(), again.depths.len());
        assert!(
            first
                .depths
                .iter()
                .zip(&again.depths)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
    }

    fn panel(corners: [[f64; 3]; 4]) -> Panel {
        Panel {
            shape: Shape::Quads,
            corners,
        }
    }

    /// Just under the cube's top, beside the middle.
    fn under_the_top() -> Panel {
        panel([[0.45, 0.9, 0.3], [0.499, 0.9, 0.3], [0.499, 0.9, 0.7], [0.45, 0.9, 0.7]])
    }

    #[test]
    fn tiles_behind_the_depths_and_heights_above_an_opening_hide_no_pixel_a_whole_triangle_shows() {
        let views = views_of(split_cube(0.02));
        let mut rng = fastrand::Rng::with_seed(9);
        let (mut shown, mut hidden, mut eyes_shown) = (0, 0, 0);
        for case in 0..300 {
            // Inside the cube, across its faces and the crack, large and small.
            let scale = [0.05, 0.3, 1.2][case % 3];
            let centre = DVec3::new(rng.f64(), rng.f64(), rng.f64());
            let triangle: [DVec3; 3] =
                std::array::from_fn(|_| centre + (DVec3::new(rng.f64(), rng.f64(), rng.f64()) - 0.5) * scale);
            // The sky's views, and the cameras in the crack, which count nothing above it.
            for v in (0..views.sky_views)
                .step_by(9)
                .chain(views.sky_views..views.views.len())
            {
                let view = &views.views[v];
                let depth = &views.depths[v * PIXELS * PIXELS..(v + 1) * PIXELS * PIXELS];
                let mut whole = Vec::new();
                rasterize(view, &triangle, |i, d| {
                    let p = view.unproject(i, d);
                    if d < f64::from(depth[i]) - view.depth_tolerance() && views.horizon(v).is_none_or(|h| p.y <= h) {
                        whole.push(p.to_array().map(f64::to_bits));
                    }
                });
                let mut by_tiles = Vec::new();
                views.visit_seen(v, &triangle, |p| by_tiles.push(p.to_array().map(f64::to_bits)));
                whole.sort_unstable();
                by_tiles.sort_unstable();
                assert_eq!(whole, by_tiles, "case {case}, view {v}");
                shown += whole.len();
                hidden += usize::from(whole.is_empty());
                eyes_shown += usize::from(v >= views.sky_views && !whole.is_empty());
            }
        }
        assert!(
            shown > 10_000 && hidden > 500 && eyes_shown > 100,
            "{shown} pixels shown, {hidden} triangles hidden, {eyes_shown} shown to cameras in the crack"
        );
    }

    #[test]
    fn the_farthest_depths_nearby_and_per_tile_are_those_of_each_pixel_s_neighbours() {
        let n = 4 * TILE;
        let mut rng = fastrand::Rng::with_seed(5);
        let depth: Vec<f32> = (0..n * n)
            .map(|_| {
                if rng.u8(..) < 40 {
                    f32::INFINITY
                } else {
                    rng.f32() * 3.0
                }
            })
            .collect();
        let mut nearby = vec![0f32; n * n];
        farthest_nearby(&depth, n, &mut nearby);
        let mut tiles = vec![0f32; (n / TILE).pow(2)];
        farthest_per_tile(&depth, n, &mut tiles);
        for (y, x) in (0..n).flat_map(|y| (0..n).map(move |x| (y, x))) {
            let around = |k: usize| k.saturating_sub(1)..=(k + 1).min(n - 1);
            let depth = &depth;
            let far = around(y)
                .flat_map(|ny| around(x).map(move |nx| depth[ny * n + nx]))
                .fold(0f32, f32::max);
            assert_eq!(nearby[y * n + x].to_bits(), far.to_bits(), "pixel {x}, {y}");
            let tile = tiles[(y / TILE) * (n / TILE) + x / TILE];
            assert!(tile >= depth[y * n + x]);
        }
        for (t, &tile) in tiles.iter().enumerate() {
            let (ty, tx) = (t / (n / TILE), t % (n / TILE));
            let pixels = (0..TILE).flat_map(|dy| (0..TILE).map(move |dx| (ty * TILE + dy) * n + tx * TILE + dx));
            assert!(pixels.map(|i| depth[i]).any(|d| d == tile), "tile {t}");
        }
    }

    #[test]
    fn the_farthest_depths_nearby_in_a_window_are_those_over_the_whole_masked_image() {
        const ACROSS: usize = WindowTiles::ACROSS;
        let mut rng = fastrand::Rng::with_seed(29);
        // Rows of tiles the window leaves out, runs of them, and the first and last rows held.
        let held_rows = |row: usize| matches!(row, 0 | 3 | 4 | 9..=14 | 31);
        let window: Vec<bool> = (0..ACROSS * ACROSS)
            .map(|t| held_rows(t / ACROSS) && rng.u8(..) < 90)
            .collect();
        let depth: Vec<f32> = (0..PIXELS * PIXELS)
            .map(|i| match window[(i / PIXELS / TILE) * ACROSS + (i % PIXELS) / TILE] {
                false => 0.0,
                true if rng.u8(..) < 40 => f32::INFINITY,
                true => rng.f32() * 3.0,
            })
            .collect();
        let (mut whole, mut windowed) = (vec![0f32; PIXELS * PIXELS], vec![7f32; PIXELS * PIXELS]);
        farthest_nearby(&depth, PIXELS, &mut whole);
        farthest_nearby_in_window(&window, &depth, &mut windowed);
        for (i, (a, b)) in whole.iter().zip(&windowed).enumerate() {
            assert_eq!(a.to_bits(), b.to_bits(), "pixel {}, {}", i % PIXELS, i / PIXELS);
        }
        assert!(whole.iter().any(|&d| d > 0.0) && whole.contains(&0.0));
    }

    #[test]
    fn triangles_left_out_above_an_opening_change_no_answer_below_it() {
        // Small triangles around a camera at height 0, most of them higher, in a room whose
        // walls lie at all depths behind them.
        let mut rng = fastrand::Rng::with_seed(17);
        let mut mesh = Mesh::default();
        for k in 0..6000u32 {
            // Half of them flat and just above the camera, where a pixel's neighbours pass.
            let (low, high, size) = match k % 2 {
                0 => (-0.05, 0.3, Vec3::splat(0.06)),
                _ => (0.0004, 0.008, Vec3::new(0.03, 0.0005, 0.03)),
            };
            let centre =
                Vec3::new(rng.f32() - 0.5, 0.0, rng.f32() - 0.5) * 1.2 + Vec3::Y * (low + rng.f32() * (high - low));
            mesh.positions
                .extend((0..3).map(|_| centre + (Vec3::new(rng.f32(), rng.f32(), rng.f32()) - 0.5) * size));
            mesh.triangles.push([3 * k, 3 * k + 1, 3 * k + 2]);
        }
        let room = mesh.positions.len() as u32;
        mesh.positions
            .extend((0..8).map(|i| Vec3::new([-2.0, 2.5][i & 1], [-1.5, 2.0][i >> 1 & 1], [-2.5, 2.0][i >> 2 & 1])));
        for q in BOX_FACES {
            let q = q.map(|i| room + i as u32);
            mesh.triangles.extend([[q[0], q[1], q[2]], [q[0], q[2], q[3]]]);
        }
        let parts = meshlets(&mesh);
        // A meshlet a triangle: only the triangles' own tests leave any out.
        let singles: Vec<Meshlet> = (0..mesh.triangles.len())
            .map(|t| {
                let (lo, hi) = point_bounds(mesh.corners(t).map(|p| p.as_dvec3()));
                Meshlet {
                    mesh: Mesh {
                        positions: mesh.corners(t).to_vec(),
                        triangles: vec![[0, 1, 2]],
                    },
                    lo,
                    hi,
                }
            })
            .collect();
        let corner_sets = |mesh: &Mesh| {
            let mut sets: Vec<_> = (0..mesh.triangles.len())
                .map(|t| mesh.corners(t).map(|p| p.to_array().map(f32::to_bits)))
                .collect();
            sets.sort_unstable();
            sets
        };
        let (eye, horizon) = (DVec3::ZERO, 0.0);
        let (mut left_out, mut changed) = (0, 0);
        for view in View::cube_map(eye, PIXELS, 1e-4) {
            let kept = may_hide_counted(&parts, mesh.bounding_sphere(), &view, horizon);
            let one_by_one = may_hide_counted(&singles, mesh.bounding_sphere(), &view, horizon);
            assert_eq!(corner_sets(&kept), corner_sets(&one_by_one), "view {:?}", view.dir);
            left_out += mesh.triangles.len() - kept.triangles.len();
            let farthest = |mesh: &Mesh| {
                let mut out = vec![0f32; PIXELS * PIXELS];
                farthest_nearby(&depth_image(&view, mesh), PIXELS, &mut out);
                out
            };
            let (all, some) = (farthest(&mesh), farthest(&kept));
            let tolerance = view.depth_tolerance();
            for (i, (&before, &after)) in all.iter().zip(&some).enumerate() {
                if before == after {
                    continue;
                }
                changed += 1;
                // A point at pixel i's centre is seen at depths below the farthest depth less
                // the tolerance: what changed is seen at depths from `before` to `after`, and
                // every such point in front of the camera must lie above the horizon.
                let near = (f64::from(before) - tolerance).max(tolerance);
                let height = |depth: f64| view.unproject(i, depth).y;
                let rises = height(2.0 * near) > height(near);
                let far_side = match after {
                    f32::INFINITY => rises,
                    far => height(f64::from(far) - tolerance) > horizon,
                };
                assert!(height(near) > horizon && far_side, "view {:?}, pixel {i}", view.dir);
            }
        }
        assert!(
            left_out > 5_000 && changed > 1_000,
            "{left_out} triangles left out, {changed} pixels changed"
        );
    }

    #[test]
    fn a_view_drawn_in_its_window_is_drawn_whole_there() {
        // Small triangles over a sphere's worth of space and a few long ones across it.
        let mut rng = fastrand::Rng::with_seed(5);
        let mut mesh = Mesh::default();
        for k in 0..4000u32 {
            let size = if k % 200 == 0 { 1.5 } else { 0.03 };
            let centre = Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0;
            mesh.positions
                .extend((0..3).map(|_| centre + (Vec3::new(rng.f32(), rng.f32(), rng.f32()) - 0.5) * size));
            mesh.triangles.push([3 * k, 3 * k + 1, 3 * k + 2]);
        }
        let parts = meshlets(&mesh);
        let tiles = WindowTiles::ACROSS;
        // A window of scattered tiles and a solid block of them.
        let window: Vec<bool> = (0..tiles * tiles)
            .map(|k| rng.f32() < 0.1 || (k / tiles < 8 && k % tiles < 8))
            .collect();
        let (center, radius) = mesh.bounding_sphere();
        let (mut image, mut kept) = (Vec::new(), Kept::default());
        let mut drawn = 0;
        for dir in fibonacci_sphere(12) {
            let view = View::new(dir, center, radius, PIXELS);
            draw_in_window(&view, &parts, &window, (&mut image, &mut kept));
            let whole = depth_image(&view, &mesh);
            for (i, (&ours, &all)) in image.iter().zip(&whole).enumerate() {
                let (x, y) = (i % PIXELS, i / PIXELS);
                if window[(y / TILE) * tiles + x / TILE] {
                    assert_eq!(ours.to_bits(), all.to_bits(), "view {dir}, pixel {i}");
                    drawn += usize::from(all.is_finite());
                }
            }
        }
        assert!(drawn > 10_000, "{drawn} pixels drawn in the windows");
    }

    #[test]
    fn corners_tested_a_brick_at_a_time_are_those_every_view_sees_one_by_one() {
        // A cube split by a slit, with cameras in the slit, which see into both halves; a
        // closed box in one half, whose inside nothing sees; corners inside and around them.
        let mut mesh = split_cube(0.02);
        let base = mesh.positions.len() as u32;
        mesh.positions.extend((0..8).map(|i| {
            let pick = |bit: usize, lo: f32, hi: f32| if i & bit == 0 { lo } else { hi };
            Vec3::new(pick(1, 0.1, 0.4), pick(2, 0.1, 0.4), pick(4, 0.1, 0.9))
        }));
        for q in BOX_FACES.map(|q| q.map(|i| base + i as u32)) {
            mesh.triangles.extend([[q[0], q[1], q[2]], [q[0], q[2], q[3]]]);
        }
        let views = views_of(mesh);
        let grid = Grid::fit(Vec3::splat(0.02), Vec3::splat(1.02), 30);
        let dims = grid.dims.map(|d| d + 1);
        let mut rng = fastrand::Rng::with_seed(4);
        let needed: Vec<bool> = (0..dims.iter().product()).map(|_| rng.f64() < 0.7).collect();
        let by_bricks = views.seen_corners(&grid, &needed);
        let one_by_one: Vec<bool> = (0..needed.len())
            .map(|c| {
                let at = [c / (dims[1] * dims[2]), c / dims[2] % dims[1], c % dims[2]];
                let p = grid.to_world(DVec3::from_array(at.map(|i| i as f64)));
                needed[c] && (0..views.views.len()).any(|v| views.sees(v, p))
            })
            .collect();
        assert_eq!(by_bricks, one_by_one);
        let (seen, hidden) = (
            one_by_one.iter().filter(|&&s| s).count(),
            needed.iter().zip(&one_by_one).filter(|&(&n, &s)| n && !s).count(),
        );
        assert!(seen > 1_000 && hidden > 500, "{seen} corners seen, {hidden} hidden");
        // A view that skips a box sees none of its points, and boxes are skipped by the sky's
        // views and by the cameras in the crack: those above its top, and those behind them.
        let mut skipped = [0, 0];
        for _ in 0..200 {
            let lo = DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 1.4 - 0.2;
            let hi = lo + DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 0.3;
            for v in (0..views.views.len()).filter(|&v| views.view_hides_box(v, lo, hi)) {
                skipped[usize::from(v >= views.sky_views)] += 1;
                for k in 0..27 {
                    let t = DVec3::new((k % 3) as f64, (k / 3 % 3) as f64, (k / 9) as f64) / 2.0;
                    assert!(!views.sees(v, lo + (hi - lo) * t), "view {v} sees into {lo} {hi}");
                }
            }
        }
        assert!(skipped[0] > 1_000 && skipped[1] > 1_000, "{skipped:?} boxes skipped");
    }

    /// A unit box open at the top, with a lid (a plate) in its rim, `gap` short of it all round.
    fn lidded_box(gap: f32) -> (Mesh, Vec<BoundaryEdge>) {
        let (mut mesh, _) = open_cube(Some(3));
        let base = mesh.positions.len() as u32;
        let (near, far) = (gap, 1.0 - gap);
        mesh.positions
            .extend([[near, near], [far, near], [far, far], [near, far]].map(|[x, z]| Vec3::new(x, 1.0, z)));
        mesh.triangles
            .extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
        let topology = orient_closed_components(&mut mesh);
        (mesh, topology.boundary)
    }

    #[test]
    fn an_opening_whose_middle_a_lid_fills_gets_cameras_in_the_gap_beside_its_rim() {
        // Both openings' middles, the rim's and the lid's, lie under the lid; so do their rim
        // points drawn a fifth of the way in. Two rim points of each go into the gap instead:
        // the rim's towards its centre, the lid's on from the lid's edge.
        let (mesh, boundary) = lidded_box(0.03);
        let field = WindingField::new(&mesh, &boundary);
        let (eyes, ..) = opening_eyes(&mesh, &boundary, &field, 0.01);
        let in_gap = |p: DVec3| {
            let to_wall = [p.x, 1.0 - p.x, p.z, 1.0 - p.z]
                .into_iter()
                .fold(f64::INFINITY, f64::min);
            (p.y - 1.0).abs() < 1e-6 && to_wall > 0.0 && to_wall < 0.03
        };
        assert_eq!(eyes.iter().filter(|(p, _)| in_gap(*p)).count(), 4, "{eyes:?}");
        assert_eq!(eyes.len(), 6, "{eyes:?}");
    }

    /// A shaft 2 high over the unit square, open at the top if `shaft_open`, with a box open at
    /// the top standing in it: the box's opening lies inside the shaft.
    fn box_in_shaft(shaft_open: bool) -> (Mesh, Vec<BoundaryEdge>) {
        let mut mesh = Mesh::default();
        let shaft = (Vec3::ZERO, Vec3::new(1.0, 2.0, 1.0), shaft_open);
        for (lo, hi, open) in [shaft, (Vec3::new(0.3, 0.2, 0.3), Vec3::new(0.7, 0.6, 0.7), true)] {
            let (part, _) = open_cube(open.then_some(3));
            let base = mesh.positions.len() as u32;
            mesh.positions
                .extend(part.positions.iter().map(|&p| lo + p * (hi - lo)));
            mesh.triangles
                .extend(part.triangles.iter().map(|t| t.map(|i| i + base)));
        }
        let topology = orient_closed_components(&mut mesh);
        (mesh, topology.boundary)
    }

    #[test]
    fn an_opening_inside_another_part_gets_cameras_where_a_view_sees_it() {
        let faces = |eyes: &[Camera]| add_cube_maps(&mut Vec::new(), eyes, 1.0).len();
        for shaft_open in [true, false] {
            let (mesh, boundary) = box_in_shaft(shaft_open);
            let field = WindingField::new(&mesh, &boundary);
            let (eyes, enclosed, mouths) = opening_eyes(&mesh, &boundary, &field, 0.01);
            // The box's centre and two rim points drawn in, where the winding number is near 1.5.
            assert_eq!(enclosed.len(), 3, "{enclosed:?}");
            assert!(enclosed.iter().all(|(p, _)| (p.y - 0.6).abs() < 1e-6), "{enclosed:?}");
            assert_eq!(eyes.len(), if shaft_open { 3 } else { 0 }, "{eyes:?}");
            // Its mouth: two pixels over the rim of its walls, in the shaft.
            let over_rim = |p: DVec3| {
                let to_wall = [p.x - 0.3, 0.7 - p.x, p.z - 0.3, 0.7 - p.z]
                    .into_iter()
                    .fold(f64::INFINITY, f64::min);
                (p.y - 0.62).abs() < 1e-6 && to_wall.abs() < 0.02
            };
            assert!(
                mouths.len() >= if shaft_open { MAX_ENCLOSED_EYES - 3 } else { 1 },
                "{mouths:?}"
            );
            assert!(mouths.iter().all(|(p, _)| over_rim(*p)), "{mouths:?}");
            // Seen down the open shaft, they get cameras, the enclosed first; in the closed one,
            // nothing sees them.
            let seen = match shaft_open {
                true => faces(&enclosed) + faces(&mouths[..MAX_ENCLOSED_EYES - 3]),
                false => 0,
            };
            assert_eq!(
                views_of(mesh).horizons.len(),
                faces(&eyes) + seen,
                "shaft open: {shaft_open}"
            );
        }
    }

    /// The surface of the box over `lines` (each axis's from its first to its last), facing
    /// out, each face cut into rectangles along those lines, but for the top face's rectangle
    /// `slot` (its x and z cell indices): a box with a slot in its lid.
    fn slotted_box(lines: [&[f32]; 3], slot: [usize; 2]) -> Mesh {
        let mut mesh = Mesh::default();
        let mut corner = HashMap::new();
        for axis in 0..3 {
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            for side in [0, lines[axis].len() - 1] {
                for i in 0..lines[a].len() - 1 {
                    for j in 0..lines[b].len() - 1 {
                        let cell = if a == 2 { [j, i] } else { [i, j] };
                        if axis == 1 && side > 0 && cell == slot {
                            continue;
                        }
                        let quad = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)].map(|(u, v)| {
                            let mut p = Vec3::ZERO;
                            (p[axis], p[a], p[b]) = (lines[axis][side], lines[a][u], lines[b][v]);
                            *corner.entry(p.to_array().map(f32::to_bits)).or_insert_with(|| {
                                mesh.positions.push(p);
                                mesh.positions.len() as u32 - 1
                            })
                        });
                        // Facing out: along +axis on the far side, as (a, b) turn.
                        let [p, q, r, t] = if side > 0 {
                            quad
                        } else {
                            [quad[0], quad[3], quad[2], quad[1]]
                        };
                        mesh.triangles.extend([[p, q, r], [p, r, t]]);
                    }
                }
            }
        }
        mesh
    }

    #[test]
    fn where_two_parts_openings_cross_their_rims_give_points_in_the_window() {
        // Two overlapping boxes, the second a thousandth higher, each with a slot in its lid:
        // one along x, one along z. Only over the square where the slots cross does a line
        // reach inside both.
        let mut mesh = slotted_box([&[0.0, 0.2, 0.8, 1.0], &[0.0, 1.0], &[0.0, 0.47, 0.53, 1.0]], [1, 1]);
        mesh.append(&slotted_box(
            [&[0.1, 0.47, 0.53, 1.1], &[-0.001, 1.001], &[-0.1, 0.2, 0.8, 0.9]],
            [1, 1],
        ));
        let topology = orient_closed_components(&mut mesh);
        assert_eq!(topology.boundary.len(), 8);
        let field = WindingField::new(&mesh, &topology.boundary);
        let (_, enclosed, mouths) = opening_eyes(&mesh, &topology.boundary, &field, 0.01);
        let in_window = |p: DVec3| (0.47..0.53).contains(&p.x) && (0.47..0.53).contains(&p.z);
        assert!(!mouths.is_empty());
        assert!(mouths.iter().all(|(p, _)| in_window(*p)), "{mouths:?}");
        // The lower slot's rim elsewhere lies inside the taller box: a gap in a part inside
        // another, not a window.
        assert!(enclosed.iter().all(|(p, _)| !in_window(*p)), "{enclosed:?}");
    }

    #[test]
    fn what_lies_behind_a_hairline_crack_shows() {
        // A crack a hundred-thousandth of the cube wide, far narrower than a pixel.
        let cracked = views_of(split_cube(1e-5));
        assert!(cracked.cracks() > 0);
        assert!(!cracked.hides_panel(&under_the_top()));
        // From straight above, pixel centres would all but miss it: the top's pixels along the
        // crack see past the top.
        let above = (0..cracked.sky_views)
            .max_by(|&a, &b| cracked.views[a].dir.y.total_cmp(&cracked.views[b].dir.y))
            .expect("views from above");
        let view = &cracked.views[above];
        let top = view.project(DVec3::new(0.5, 1.0, 0.5)).z;
        let image = &cracked.depths[above * PIXELS * PIXELS..(above + 1) * PIXELS * PIXELS];
        let over_the_top = |i: &usize| {
            let p = view.unproject(*i, top);
            (0.05..0.95).contains(&p.x) && (0.05..0.95).contains(&p.z)
        };
        let (past_the_top, on_top): (Vec<usize>, Vec<usize>) = (0..image.len())
            .filter(over_the_top)
            .partition(|&i| f64::from(image[i]) > top + 0.1);
        let (past_the_top, on_top) = (past_the_top.len(), on_top.len());
        assert!(
            on_top > 10_000 && past_the_top > 100,
            "{on_top} pixels on the top, {past_the_top} past it"
        );
        // Where the halves touch, the cube is closed: nothing inside shows.
        let closed = views_of(split_cube(0.0));
        assert_eq!(closed.cracks(), 0);
        assert!(closed.hides_panel(&under_the_top()));
    }

    #[test]
    fn a_panel_that_shows_in_part_is_cut_down_to_the_rest() {
        let views = views_of(split_cube(0.0));
        // Half inside the closed cube, half beside it, where every side view sees it.
        let across = panel([[0.2, 0.2, 0.5], [1.8, 0.2, 0.5], [1.8, 0.8, 0.5], [0.2, 0.8, 0.5]]);
        assert!(!views.hides_panel(&across));
        let part = views.hidden_part(&across).expect("the half inside is hidden");
        assert!(views.hides_panel(&part));
        let xs = part.corners.map(|c| c[0]);
        let (lo, hi) = (
            xs.iter().copied().fold(f64::INFINITY, f64::min),
            xs.iter().copied().fold(0.0, f64::max),
        );
        assert!(hi <= 1.0 && lo <= 0.25 && hi >= 0.9, "kept x from {lo} to {hi}");
        assert!(part.area() >= 0.8 * 0.8 * 0.6, "kept {}", part.area());
    }
}
