//! Where a player stands in a map, and where objects can: floors and free space found in a
//! bricked voxel grid of the map's surface ([`BrickGrid`]).
//!
//! A floor is a voxel whose surface faces up, with up-facing neighbours around it and empty
//! voxels above them to the height asked for. A point must be inside the map, as the grid's
//! inside stage finds it ([`BrickGrid::inside`]): looking along ±x and ±z from it, the first
//! surface met faces back towards it; on top of an outer wall, or inside a solid (where the
//! surface met shows its back), it does not.
//!
//! Cameras and probes are spread over the whole map: floors are drawn region by region, one
//! region after another, so that every part of the map that has floors gets its share.

use crate::voxel::bricks::{BrickGrid, FACES};
use glam::{DVec3, IVec3};
use serde::Serialize;
use std::collections::BTreeMap;

/// A camera standing on a floor: its eye, and a horizontal direction it looks along.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    pub eye: DVec3,
    pub forward: DVec3,
}

/// An axis-aligned box standing on a floor, in free space.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Probe {
    pub lo: [f64; 3],
    pub hi: [f64; 3],
}

/// Candidate floors tried per camera or probe wanted before the map counts as having no room.
const TRIES_PER_ITEM: usize = 200;

pub struct FreeSpace<'a> {
    grid: &'a BrickGrid,
    /// The eye's height above the floor, in world units.
    eye_height: f64,
    /// Voxels with an up-facing surface.
    floors: Vec<IVec3>,
}

impl<'a> FreeSpace<'a> {
    pub fn new(grid: &'a BrickGrid, eye_height: f64) -> FreeSpace<'a> {
        let mut floors: Vec<IVec3> = grid
            .surface_voxels()
            .filter(|&(_, bits)| bits & FACES[2] != 0)
            .map(|(v, _)| v)
            .collect();
        // The grid's bricks come in hash order: sort, so that a seed always draws the same.
        floors.sort_by_key(|v| (v.x, v.z, v.y));
        FreeSpace {
            grid,
            eye_height,
            floors,
        }
    }

    /// Up to `n` cameras at eye height above floors, inside the map, each looking in a random
    /// horizontal direction.
    pub fn cameras(&self, n: usize, seed: u64) -> Vec<Pose> {
        let clear = self.voxels(self.eye_height) + 1;
        self.spread(n, seed, |floor, rng| {
            let top = self.grid.to_world(floor.as_dvec3() + DVec3::new(0.5, 1.0, 0.5));
            let eye = top + DVec3::Y * self.eye_height;
            // The cheap test first: an eye above the map's top is outside it.
            if !self.grid.inside(self.grid.voxel_of(eye)) || !self.standing_room(floor, IVec3::new(1, clear, 1)) {
                return None;
            }
            let yaw = rng.f64() * std::f64::consts::TAU;
            Some(Pose {
                eye,
                forward: DVec3::new(yaw.cos(), 0.0, yaw.sin()),
            })
        })
    }

    /// Up to `n` boxes standing on floors inside the map, in free space: from a quarter to one
    /// and a half eye heights wide and deep, from a quarter to one and a quarter high.
    pub fn probes(&self, n: usize, seed: u64) -> Vec<Probe> {
        self.spread(n, seed, |floor, rng| {
            let size =
                |lo: f64, hi: f64, rng: &mut fastrand::Rng| self.voxels(self.eye_height * (lo + (hi - lo) * rng.f64()));
            let extent = IVec3::new(size(0.25, 1.5, rng), size(0.25, 1.25, rng), size(0.25, 1.5, rng));
            let half = IVec3::new(extent.x / 2, 0, extent.z / 2);
            let first = floor - half + IVec3::Y;
            let last = first + extent - 1;
            // A box wider or taller than the map does not fit; testing it voxel by voxel
            // would cost its whole volume.
            if !self.grid.contains(first) || !self.grid.contains(last) {
                return None;
            }
            if !self.standing_room(floor, half.max(IVec3::new(1, 0, 1)) + IVec3::Y * extent.y) {
                return None;
            }
            // A hair inside its voxels, so that it touches no surface.
            let hair = 1e-3;
            let lo = self.grid.to_world(first.as_dvec3() + hair);
            let hi = self.grid.to_world((last + 1).as_dvec3() - hair);
            self.grid.inside(self.grid.voxel_of((lo + hi) * 0.5)).then_some(Probe {
                lo: lo.to_array(),
                hi: hi.to_array(),
            })
        })
    }

    fn voxels(&self, length: f64) -> i32 {
        (length / self.grid.voxel_size()).ceil().max(1.0) as i32
    }

    /// Whether `floor` and its neighbours within `reach.x` and `reach.z` face up, with nothing
    /// above them for `reach.y` voxels.
    fn standing_room(&self, floor: IVec3, reach: IVec3) -> bool {
        (-reach.x..=reach.x).all(|dx| {
            (-reach.z..=reach.z).all(|dz| {
                let base = floor + IVec3::new(dx, 0, dz);
                let flat = (dx.abs() > 1 || dz.abs() > 1) || self.grid.get(base) & FACES[2] != 0;
                flat && (1..=reach.y).all(|dy| self.grid.get(base + IVec3::Y * dy) == 0)
            })
        })
    }

    /// Up to `n` items made by `make` from floors drawn region by region over the map's
    /// ground plan, a seeded shuffle within each region; fewer where [`TRIES_PER_ITEM`] floors
    /// per item make no more.
    fn spread<T>(&self, n: usize, seed: u64, mut make: impl FnMut(IVec3, &mut fastrand::Rng) -> Option<T>) -> Vec<T> {
        let mut rng = fastrand::Rng::with_seed(seed);
        let side = (n as f64).sqrt().ceil().max(1.0) as i32;
        let dims = self.grid.dims();
        let mut regions: BTreeMap<(i32, i32), Vec<IVec3>> = BTreeMap::new();
        for &v in &self.floors {
            regions
                .entry((v.x * side / dims.x, v.z * side / dims.z))
                .or_default()
                .push(v);
        }
        for floors in regions.values_mut() {
            rng.shuffle(floors);
        }
        let mut regions: Vec<Vec<IVec3>> = regions.into_values().collect();
        let (mut made, mut tries) = (Vec::with_capacity(n), 0);
        while made.len() < n && !regions.is_empty() && tries < TRIES_PER_ITEM * n {
            // One floor from each region in turn; a region with none left drops out.
            regions.retain(|floors| !floors.is_empty());
            for floors in &mut regions {
                let Some(floor) = floors.pop() else { continue };
                tries += 1;
                if let Some(item) = make(floor, &mut rng) {
                    made.push(item);
                    if made.len() == n {
                        break;
                    }
                }
            }
        }
        made
    }
}
