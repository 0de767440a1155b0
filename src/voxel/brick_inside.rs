//! The bricked grid's inside stage: which voxels lie inside the map, brick by brick. A voxel is
//! inside when, along each of ±x and ±z (the four ways), the first surface met faces back
//! towards it. Inside a solid, or past an outer wall, some way meets a surface's back or
//! nothing at all.
//!
//! A way's answer at a voxel depends only on the voxels after it along its row, so the stage
//! runs in three steps and never visits a voxel outside a brick of surface:
//! 1. [`entries`]: each brick alone, what each of its rows meets first entering the brick
//!    along each way (twin: `shaders/brick_inside.wgsl`, [`gpu::entries`]).
//! 2. `link`: along each line of bricks, what each row meets past each brick (a row with no
//!    surface in a brick passes on what the next brick's row meets). Bricks with no surface
//!    are never stored: a voxel in one takes its answers from the next brick of each line.
//! 3. [`classify`]: each brick alone, each voxel's bit from its rows' marches, starting from
//!    what they meet past the brick (twin: [`gpu::classify`]).

pub mod gpu;

use super::bricks::{BRICK, BRICK_VOXELS, FACES, offset};
use crate::gpu::{Gpu, GpuError};
use glam::IVec3;
use rayon::prelude::*;
use std::collections::HashMap;

/// The four ways a voxel looks along: +x, -x, +z, -z.
pub const WAYS: usize = 4;
/// Rows of a brick along one axis.
pub const ROWS: usize = (BRICK * BRICK) as usize;
/// What a way meets first: no surface, a surface facing back towards it, or one facing away.
pub const NOTHING: u8 = 0;
pub const FRONT: u8 = 1;
pub const BACK: u8 = 2;
/// Each way's facing bit of a surface that faces back along it.
const FACING_BACK: [u8; WAYS] = [FACES[1], FACES[0], FACES[5], FACES[4]];

/// Per row of a brick, what each way meets: `rows[row][way]`. A row of the x ways is the
/// voxels of one y and z (row y + 8 z), of the z ways those of one x and y (row x + 8 y).
pub type Rows = [[u8; WAYS]; ROWS];
/// One bit per voxel of a brick, in the order of its voxels.
pub type Bits = [u64; BRICK_VOXELS / 64];
/// The bricks along each line of x (keyed by y and z) and of z (keyed by x and y): each brick's
/// place along the line and its index, sorted by place.
type Lines = [HashMap<(i32, i32), Vec<(i32, u32)>>; 2];

/// The stage's answer for a whole grid, kept beside its bricks (in the same order).
pub struct Inside {
    bits: Vec<Bits>,
    /// What each row meets entering each brick, past the brick where its own row is empty: per
    /// row, two bits a way.
    entries: Vec<[u8; ROWS]>,
    lines: Lines,
}

impl Inside {
    /// Whether voxel `v` is inside, where `brick` is the index of its brick (None: a brick with
    /// no surface).
    pub fn holds(&self, v: IVec3, brick: Option<u32>) -> bool {
        if let Some(b) = brick {
            let i = offset(v);
            return self.bits[b as usize][i / 64] >> (i % 64) & 1 == 1;
        }
        let local = v.rem_euclid(IVec3::splat(BRICK));
        (0..WAYS).all(|way| {
            let (key, at) = line_place(way, v.div_euclid(IVec3::splat(BRICK)));
            let Some(line) = self.lines[way / 2].get(&key) else {
                return false;
            };
            let next = if way.is_multiple_of(2) {
                line.get(line.partition_point(|&(p, _)| p <= at))
            } else {
                line.partition_point(|&(p, _)| p < at).checked_sub(1).map(|i| &line[i])
            };
            next.is_some_and(|&(_, b)| self.entries[b as usize][row_of(way, local)] >> (2 * way) & 3 == FRONT)
        })
    }

    /// Bytes held: the bits, the entries and the lines' index.
    pub fn bytes(&self) -> usize {
        let line = std::mem::size_of::<((i32, i32), Vec<(i32, u32)>)>() + 1;
        self.bits.len() * (std::mem::size_of::<Bits>() + ROWS)
            + self.lines.iter().map(|l| l.capacity() * line).sum::<usize>()
            + self.bits.len() * 2 * std::mem::size_of::<(i32, u32)>()
    }

    /// Voxels of the surface's bricks that are inside.
    pub fn voxels_in_bricks(&self) -> usize {
        self.bits.iter().flatten().map(|w| w.count_ones() as usize).sum()
    }
}

/// The whole stage for the bricks at `coords` with surface bytes `surface`, its per-brick
/// steps on `gpu` when one is given.
pub fn build(coords: &[IVec3], surface: &[[u8; BRICK_VOXELS]], gpu: Option<&Gpu>) -> Result<Inside, GpuError> {
    let own = match gpu {
        Some(gpu) => gpu::entries(gpu, surface)?,
        None => entries(surface),
    };
    let (lines, beyond) = link(coords, &own);
    let bits = match gpu {
        Some(gpu) => gpu::classify(gpu, surface, &beyond)?,
        None => classify(surface, &beyond),
    };
    let entries = own
        .iter()
        .zip(&beyond)
        .map(|(own, beyond)| {
            std::array::from_fn(|row| {
                (0..WAYS).fold(0, |packed, way| {
                    packed | met_entering(own[row][way], beyond[row][way]) << (2 * way)
                })
            })
        })
        .collect();
    Ok(Inside { bits, entries, lines })
}

/// Step 1: per brick, what each row meets first entering it along each way.
pub fn entries(surface: &[[u8; BRICK_VOXELS]]) -> Vec<Rows> {
    surface
        .par_iter()
        .map(|voxels| std::array::from_fn(|row| std::array::from_fn(|way| march(voxels, way, row, NOTHING, |_, _| {}))))
        .collect()
}

/// Step 2: the bricks' lines, and per brick what each row meets past it along each way.
fn link(coords: &[IVec3], entries: &[Rows]) -> (Lines, Vec<Rows>) {
    let mut lines = Lines::default();
    for (b, &brick) in coords.iter().enumerate() {
        for (axis, lines) in lines.iter_mut().enumerate() {
            let (key, at) = line_place(2 * axis, brick);
            lines.entry(key).or_default().push((at, b as u32));
        }
    }
    let mut beyond = vec![[[NOTHING; WAYS]; ROWS]; coords.len()];
    for (axis, lines) in lines.iter_mut().enumerate() {
        for line in lines.values_mut() {
            line.sort_unstable();
            for way in [2 * axis, 2 * axis + 1] {
                // What a brick's rows meet past it is known once the bricks after it along
                // the way are: walk the line against the way.
                let mut met = [NOTHING; ROWS];
                for k in 0..line.len() {
                    let b = line[if way.is_multiple_of(2) { line.len() - 1 - k } else { k }].1 as usize;
                    for (row, met) in met.iter_mut().enumerate() {
                        beyond[b][row][way] = *met;
                        *met = met_entering(entries[b][row][way], *met);
                    }
                }
            }
        }
    }
    (lines, beyond)
}

/// Step 3: per brick, each voxel's bit: set where every way meets a surface's front.
pub fn classify(surface: &[[u8; BRICK_VOXELS]], beyond: &[Rows]) -> Vec<Bits> {
    surface
        .par_iter()
        .zip(beyond)
        .map(|(voxels, beyond)| {
            let mut fronts = [0u8; BRICK_VOXELS];
            for way in 0..WAYS {
                for (row, beyond) in beyond.iter().enumerate() {
                    march(voxels, way, row, beyond[way], |i, met| {
                        if met == FRONT {
                            fronts[i] |= 1 << way;
                        }
                    });
                }
            }
            let mut bits = [0u64; BRICK_VOXELS / 64];
            for (i, &f) in fronts.iter().enumerate() {
                if f == (1 << WAYS) - 1 {
                    bits[i / 64] |= 1 << (i % 64);
                }
            }
            bits
        })
        .collect()
}

/// What a row meets entering a brick: its own first surface, else what it meets past the brick.
fn met_entering(own: u8, beyond: u8) -> u8 {
    if own == NOTHING { beyond } else { own }
}

/// Walks `row` of a brick against `way`, from the brick's far side, starting from `met` (what
/// the way meets past the brick); `visit` sees each voxel's index and what the way meets from
/// it. Returns what it meets from the row's first voxel.
fn march(voxels: &[u8; BRICK_VOXELS], way: usize, row: usize, mut met: u8, mut visit: impl FnMut(usize, u8)) -> u8 {
    for step in 0..BRICK as usize {
        let along = if way.is_multiple_of(2) {
            BRICK as usize - 1 - step
        } else {
            step
        };
        let i = if way < 2 {
            along + BRICK as usize * row
        } else {
            row + ROWS * along
        };
        let bits = voxels[i];
        if bits != 0 {
            met = if bits & FACING_BACK[way] != 0 { FRONT } else { BACK };
        }
        visit(i, met);
    }
    met
}

/// The row of `way` that holds the voxel at `local` in its brick.
fn row_of(way: usize, local: IVec3) -> usize {
    if way < 2 {
        (local.y + BRICK * local.z) as usize
    } else {
        (local.x + BRICK * local.y) as usize
    }
}

/// The line of bricks along `way`'s axis that holds `brick`, and the brick's place along it.
fn line_place(way: usize, brick: IVec3) -> ((i32, i32), i32) {
    if way < 2 {
        ((brick.y, brick.z), brick.x)
    } else {
        ((brick.x, brick.y), brick.z)
    }
}

#[cfg(test)]
mod tests {
    use super::super::bricks::BrickGrid;
    use super::*;
    use crate::mesh::Mesh;
    use crate::occluder::{WorldBox, merge::merge};

    /// The definition the stage answers: march voxel by voxel along each way to the first
    /// surface, or off the grid.
    fn marched(grid: &BrickGrid, v: IVec3) -> bool {
        let ways = [
            (IVec3::X, FACES[1]),
            (IVec3::NEG_X, FACES[0]),
            (IVec3::Z, FACES[5]),
            (IVec3::NEG_Z, FACES[4]),
        ];
        ways.into_iter().all(|(step, facing_back)| {
            let mut at = v;
            while grid.contains(at) {
                let bits = grid.get(at);
                if bits != 0 {
                    return bits & facing_back != 0;
                }
                at += step;
            }
            false
        })
    }

    fn block(lo: [f64; 3], hi: [f64; 3]) -> Mesh {
        merge(&[WorldBox { lo, hi }])
    }

    #[test]
    fn the_stage_answers_what_marching_finds_in_every_voxel() {
        // A room seen from within (its faces turned inwards), a pillar in it, and a solid
        // block outside it: lines of bricks with empty bricks between their surface bricks.
        let mut room = block([0.0; 3], [12.0, 6.0, 12.0]);
        room.triangles.iter_mut().for_each(|t| t.swap(1, 2));
        let mut map = room;
        map.append(&block([5.0, 0.0, 5.0], [7.0, 6.0, 7.0]));
        map.append(&block([20.0, 0.0, 2.0], [24.0, 3.0, 9.0]));
        let grid = BrickGrid::voxelize(&map, 0.25, None).expect("small grid");
        let at = |p: [f64; 3]| grid.voxel_of(glam::DVec3::from(p));
        assert!(grid.inside(at([2.5, 3.0, 2.5])), "in the room");
        assert!(grid.inside(at([9.5, 1.0, 6.0])), "in the room, beside the pillar");
        assert!(!grid.inside(at([6.0, 3.0, 6.0])), "in the pillar");
        assert!(!grid.inside(at([22.0, 1.0, 5.0])), "in the block outside");
        assert!(!grid.inside(at([16.0, 1.0, 5.0])), "between the room and the block");
        let dims = grid.dims();
        let (mut inside, mut differ) = (0, Vec::new());
        for x in -1..=dims.x {
            for y in -1..=dims.y {
                for z in -1..=dims.z {
                    let v = IVec3::new(x, y, z);
                    inside += usize::from(grid.inside(v));
                    if grid.inside(v) != marched(&grid, v) {
                        differ.push(v);
                    }
                }
            }
        }
        assert!(
            differ.is_empty(),
            "{} voxels differ, first {:?}",
            differ.len(),
            differ.first()
        );
        // The room's 48 x 24 x 48 voxels less the pillar's 8 x 8 columns, where each face lies on
        // voxel boundaries and so takes a layer of voxels on either side: a surface voxel
        // meets its own back along the way leaving the face.
        assert_eq!(inside, 46 * 22 * 46 - 10 * 22 * 10);
        let in_bricks = grid.stats().inside_voxels.expect("counted");
        assert!(in_bricks > 0 && in_bricks < inside, "{in_bricks}");
    }
}
