//! Complete Polygonal Scene Voxelization (the seed article's `cpsv`): inside/outside by what the
//! empty space sees, for scenes too broken for crossing counts.
//!
//! The empty space (voxels no triangle touches) is cut into an octree of cells, each split until
//! it touches no triangle. A seed cell renders a cube map of the mesh from its centre, the near
//! plane at its edge, noting for each pixel whether the nearest surface shows its front or its
//! back. From inside a closed shell one sees back faces all around: a seed is inside when at
//! least `inside_faces` of its six faces show more than `back_share` back-face pixels, outside
//! when none do, and undecided otherwise. A decided seed votes for its status in every unknown
//! cell whose eight corners it sees (each corner nearer than its cube map's depth); a cell
//! commits at `votes` votes. Only seeds vote. Cells that reach out of the mesh's bounds are
//! outside but never seeds (the article's fix for open-bottomed buildings). Seeds are taken
//! largest first, in batches, until every cell is decided or none is left to try; undecided
//! cells count as outside, so the result stays conservative.

pub mod gpu;

use super::Grid;
use crate::geom::camera::View;
use crate::geom::clamped_index;
use crate::geom::raster::rasterize;
use crate::gpu::{Gpu, GpuError};
use crate::mesh::Mesh;
use glam::DVec3;
use gpu::{CubeMaps, Seed};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The article's thresholds, all settings (`cook.cpsv_*`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CpsvSettings {
    /// Pixels along a cube-map face.
    pub pixels: usize,
    /// Share of a face's pixels that must show back faces for the face to count.
    pub back_share: f64,
    /// Faces (of six) that must count for a seed to be inside.
    pub inside_faces: usize,
    /// Votes that commit an unknown cell.
    pub votes: u32,
}

/// What the classification found, for the report.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct CpsvStats {
    /// Empty cells of the octree.
    pub cells: usize,
    /// Cells that rendered their cube map.
    pub seeds: usize,
    /// Cells decided by neither their own view nor votes; counted as outside.
    pub undecided_cells: usize,
    pub undecided_voxels: usize,
}

/// Seeds rendered between two rounds of voting.
const BATCH: usize = 16;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Status {
    Unknown,
    Inside,
    Outside,
}

/// An empty cell: its first voxel and size in voxels, clipped to the grid.
#[derive(Clone, Copy, Debug)]
struct Cell {
    lo: [usize; 3],
    hi: [usize; 3],
}

impl Cell {
    fn within(&self, [lo, hi]: &[[f64; 3]; 2]) -> bool {
        (0..3).all(|a| self.lo[a] as f64 >= lo[a] && self.hi[a] as f64 <= hi[a])
    }

    /// Whether no part of the cell lies within the bounds.
    fn beyond(&self, [lo, hi]: &[[f64; 3]; 2]) -> bool {
        (0..3).any(|a| self.hi[a] as f64 <= lo[a] || self.lo[a] as f64 >= hi[a])
    }

    fn voxels(&self) -> usize {
        (0..3).map(|a| self.hi[a] - self.lo[a]).product()
    }

    fn corners(&self, grid: &Grid) -> [DVec3; 8] {
        std::array::from_fn(|c| {
            let pick = |a: usize| (if c >> a & 1 == 0 { self.lo[a] } else { self.hi[a] }) as f64;
            grid.to_world(DVec3::new(pick(0), pick(1), pick(2)))
        })
    }

    fn centre(&self, grid: &Grid) -> DVec3 {
        let mid = |a: usize| (self.lo[a] + self.hi[a]) as f64 * 0.5;
        grid.to_world(DVec3::new(mid(0), mid(1), mid(2)))
    }
}

/// A seed's cube map: per face, the nearest depth and whether it is a back face.
struct CubeMap {
    views: Vec<View>,
    depth: Vec<Vec<f32>>,
    back: Vec<Vec<bool>>,
}

impl CubeMap {
    fn render(mesh: &Mesh, eye: DVec3, near: f64, pixels: usize) -> CubeMap {
        let views = View::cube_map(eye, pixels, near);
        let mut depth = vec![vec![f32::INFINITY; pixels * pixels]; 6];
        let mut back = vec![vec![false; pixels * pixels]; 6];
        for tri in mesh.triangles_f64() {
            let facing_back = (tri[1] - tri[0]).cross(tri[2] - tri[0]).dot(eye - tri[0]) < 0.0;
            for (f, view) in views.iter().enumerate() {
                let (depth, back) = (&mut depth[f], &mut back[f]);
                rasterize(view, &tri, |i, d| {
                    let d = d as f32;
                    if d < depth[i] {
                        depth[i] = d;
                        back[i] = facing_back;
                    }
                });
            }
        }
        CubeMap { views, depth, back }
    }

    /// Back-face pixels per face.
    fn backs(&self) -> Vec<u32> {
        self.back
            .iter()
            .map(|b| b.iter().filter(|&&x| x).count() as u32)
            .collect()
    }

    /// Whether the eye sees `p`: nothing of the mesh lies between them.
    fn sees(&self, eye: DVec3, p: DVec3) -> bool {
        let d = p - eye;
        let a = d.abs();
        // The face whose frustum holds p: the cube map's views look along -X, +X, -Y, ...
        let face = if a.x >= a.y && a.x >= a.z {
            usize::from(d.x > 0.0)
        } else if a.y >= a.z {
            2 + usize::from(d.y > 0.0)
        } else {
            4 + usize::from(d.z > 0.0)
        };
        let view = &self.views[face];
        let q = view.project(p);
        if q.z <= view.depth_tolerance() {
            return true;
        }
        let n = view.pixels;
        let px = |v: f64| clamped_index(v, n);
        q.z < f64::from(self.depth[face][px(q.y) * n + px(q.x)])
    }
}

/// Inside, outside, or undecided (Unknown), by the back-face pixels of a seed's six faces.
fn verdict(backs: &[u32], settings: &CpsvSettings) -> Status {
    let pixels = (settings.pixels * settings.pixels) as f64;
    let faces = backs
        .iter()
        .filter(|&&b| f64::from(b) > settings.back_share * pixels)
        .count();
    match faces {
        0 => Status::Outside,
        n if n >= settings.inside_faces => Status::Inside,
        _ => Status::Unknown,
    }
}

/// One batch of seeds: each seed's verdict, and each cell's (inside, outside) votes from the
/// decided seeds that see all its corners (none for cells not unknown). On the device's
/// `cube_maps` when given (shaders/cpsv.wgsl), else here.
fn seeds_and_votes(
    mesh: &Mesh,
    grid: &Grid,
    cells: &[Cell],
    status: &[Status],
    seeds: &[Seed],
    settings: &CpsvSettings,
    cube_maps: Option<&CubeMaps>,
) -> Result<(Vec<Status>, Vec<[u32; 2]>), GpuError> {
    if let Some(cube_maps) = cube_maps {
        let unknown: Vec<bool> = status.iter().map(|s| *s == Status::Unknown).collect();
        let code = |s: Status| match s {
            Status::Unknown => 0,
            Status::Inside => 1,
            Status::Outside => 2,
        };
        let (verdicts, votes) = cube_maps.seeds_and_votes(seeds, &unknown, |b| code(verdict(b, settings)))?;
        let verdicts = verdicts
            .into_iter()
            .map(|v| [Status::Unknown, Status::Inside, Status::Outside][v as usize])
            .collect();
        return Ok((verdicts, votes));
    }
    let maps: Vec<CubeMap> = seeds
        .par_iter()
        .map(|seed| CubeMap::render(mesh, seed.eye, seed.near, settings.pixels))
        .collect();
    let verdicts: Vec<Status> = maps.iter().map(|m| verdict(&m.backs(), settings)).collect();
    let voters: Vec<(&Seed, &CubeMap, Status)> = seeds
        .iter()
        .zip(&maps)
        .zip(&verdicts)
        .filter(|(_, v)| **v != Status::Unknown)
        .map(|((s, m), v)| (s, m, *v))
        .collect();
    let votes = (0..cells.len())
        .into_par_iter()
        .map(|c| {
            let mut got = [0u32; 2];
            if status[c] == Status::Unknown {
                let corners = cells[c].corners(grid);
                for (seed, map, verdict) in &voters {
                    if corners.iter().all(|&p| map.sees(seed.eye, p)) {
                        got[usize::from(*verdict == Status::Outside)] += 1;
                    }
                }
            }
            got
        })
        .collect();
    Ok((verdicts, votes))
}

/// Classifies every voxel: `solid` is true inside and on the surface (`surface`). The cube
/// maps and votes run on `gpu` when given.
pub fn classify(
    mesh: &Mesh,
    grid: &Grid,
    surface: &[bool],
    settings: &CpsvSettings,
    gpu: Option<&Gpu>,
) -> Result<(Vec<bool>, CpsvStats), GpuError> {
    // The mesh's bounds in voxel units: cells are split along them too, and those outside
    // (the grid's padding, and whatever straddles the bounds at one voxel) are outside.
    let (lo, hi) = mesh.bounds();
    let in_voxels = |p: glam::Vec3| ((p.as_dvec3() - grid.origin()) / grid.voxel_size).to_array();
    let bounds = [in_voxels(lo), in_voxels(hi)];
    let cells = empty_cells(grid, surface, &bounds);
    let mut status: Vec<Status> = cells
        .iter()
        .map(|c| match c.within(&bounds) {
            true => Status::Unknown,
            false => Status::Outside,
        })
        .collect();
    let mut votes = vec![[0u32; 2]; cells.len()];
    let cube_maps = match gpu {
        Some(gpu) => {
            let corners: Vec<[DVec3; 2]> = cells
                .iter()
                .map(|c| [c.lo, c.hi].map(|v| grid.to_world(DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64))))
                .collect();
            Some(CubeMaps::new(gpu, mesh, settings.pixels as u32, &corners)?)
        }
        None => None,
    };
    // Largest first: a big cell sees much of what is around it.
    let mut order: Vec<usize> = (0..cells.len()).filter(|&i| status[i] == Status::Unknown).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(cells[i].voxels()));
    let mut next = 0;
    let mut seeds = 0;
    while next < order.len() {
        let batch: Vec<usize> = order[next..]
            .iter()
            .copied()
            .filter(|&i| status[i] == Status::Unknown)
            .take(BATCH)
            .collect();
        let Some(last) = batch.last() else { break };
        next += order[next..]
            .iter()
            .position(|i| i == last)
            .expect("the batch came from here")
            + 1;
        seeds += batch.len();
        let seeded: Vec<Seed> = batch
            .iter()
            .map(|&i| {
                let cell = &cells[i];
                let smallest = (0..3).map(|a| cell.hi[a] - cell.lo[a]).min().expect("three axes");
                Seed {
                    eye: cell.centre(grid),
                    near: 0.5 * grid.voxel_size * smallest as f64,
                }
            })
            .collect();
        // The seeds are decided by their own view, not by votes: out of the vote until their
        // verdict replaces this mark.
        for &i in &batch {
            status[i] = Status::Inside;
        }
        let (verdicts, cast) = seeds_and_votes(mesh, grid, &cells, &status, &seeded, settings, cube_maps.as_ref())?;
        for (&i, verdict) in batch.iter().zip(verdicts) {
            status[i] = verdict;
        }
        for (c, got) in cast.into_iter().enumerate() {
            if got == [0, 0] {
                continue;
            }
            votes[c][0] += got[0];
            votes[c][1] += got[1];
            if votes[c][0] >= settings.votes && votes[c][0] >= votes[c][1] {
                status[c] = Status::Inside;
            } else if votes[c][1] >= settings.votes {
                status[c] = Status::Outside;
            }
        }
    }
    Ok(solid_and_stats(grid, surface, &cells, &status, seeds))
}

/// The surface voxels and those of the cells decided inside, and what the classification found.
fn solid_and_stats(
    grid: &Grid,
    surface: &[bool],
    cells: &[Cell],
    status: &[Status],
    seeds: usize,
) -> (Vec<bool>, CpsvStats) {
    let mut solid = surface.to_vec();
    let mut stats = CpsvStats {
        cells: cells.len(),
        seeds,
        ..Default::default()
    };
    for (cell, s) in cells.iter().zip(status) {
        match s {
            Status::Inside => {
                for x in cell.lo[0]..cell.hi[0] {
                    for y in cell.lo[1]..cell.hi[1] {
                        for z in cell.lo[2]..cell.hi[2] {
                            solid[grid.index(x, y, z)] = true;
                        }
                    }
                }
            }
            Status::Unknown => {
                stats.undecided_cells += 1;
                stats.undecided_voxels += cell.voxels();
            }
            Status::Outside => {}
        }
    }
    (solid, stats)
}

/// The octree's empty cells: cubes of power-of-two size, split while they hold a surface voxel
/// or straddle the `bounds`.
fn empty_cells(grid: &Grid, surface: &[bool], bounds: &[[f64; 3]; 2]) -> Vec<Cell> {
    let [nx, ny, nz] = grid.dims;
    // Summed-volume table: surface voxels in any box in O(1).
    let at = |x: usize, y: usize, z: usize| (x * (ny + 1) + y) * (nz + 1) + z;
    let mut sums = vec![0u32; (nx + 1) * (ny + 1) * (nz + 1)];
    for x in 1..=nx {
        for y in 1..=ny {
            for z in 1..=nz {
                sums[at(x, y, z)] = u32::from(surface[grid.index(x - 1, y - 1, z - 1)])
                    + sums[at(x - 1, y, z)]
                    + sums[at(x, y - 1, z)]
                    + sums[at(x, y, z - 1)]
                    - sums[at(x - 1, y - 1, z)]
                    - sums[at(x - 1, y, z - 1)]
                    - sums[at(x, y - 1, z - 1)]
                    + sums[at(x - 1, y - 1, z - 1)];
            }
        }
    }
    let count = |lo: [usize; 3], hi: [usize; 3]| {
        let s = |x, y, z| i64::from(sums[at(x, y, z)]);
        s(hi[0], hi[1], hi[2]) - s(lo[0], hi[1], hi[2]) - s(hi[0], lo[1], hi[2]) - s(hi[0], hi[1], lo[2])
            + s(lo[0], lo[1], hi[2])
            + s(lo[0], hi[1], lo[2])
            + s(hi[0], lo[1], lo[2])
            - s(lo[0], lo[1], lo[2])
    };
    let side = nx.max(ny).max(nz).next_power_of_two();
    let mut cells = Vec::new();
    let mut stack = vec![([0usize; 3], side)];
    while let Some((lo, size)) = stack.pop() {
        let hi = [(lo[0] + size).min(nx), (lo[1] + size).min(ny), (lo[2] + size).min(nz)];
        if (0..3).any(|a| lo[a] >= hi[a]) {
            continue;
        }
        let cell = Cell { lo, hi };
        let straddles = !cell.within(bounds) && !cell.beyond(bounds);
        if count(lo, hi) == 0 && (!straddles || size == 1) {
            cells.push(cell);
        } else if size > 1 {
            let half = size / 2;
            for c in 0..8 {
                let offset = |a: usize| if c >> a & 1 == 0 { 0 } else { half };
                stack.push(([lo[0] + offset(0), lo[1] + offset(1), lo[2] + offset(2)], half));
            }
        }
    }
    cells
}
