//! Spatial batching: placed occluders split at the median of their centres, along the longest
//! axis, until every batch is within the triangle and extent limits.

use crate::mesh::point_bounds;
use glam::DVec3;

/// One placed occluder, for batching: its bounds and triangles.
#[derive(Clone, Copy, Debug)]
pub struct Placed {
    pub lo: DVec3,
    pub hi: DVec3,
    pub triangles: usize,
}

/// Groups of indices into `placed`, each within `max_triangles` and `max_extent` (a single
/// instance over the limits is a batch of its own).
pub fn cluster(placed: &[Placed], max_triangles: usize, max_extent: f64) -> Vec<Vec<usize>> {
    let mut done = Vec::new();
    let mut todo = vec![(0..placed.len()).collect::<Vec<usize>>()];
    while let Some(mut group) = todo.pop() {
        let (lo, hi) = point_bounds(group.iter().flat_map(|&i| [placed[i].lo, placed[i].hi]));
        let triangles: usize = group.iter().map(|&i| placed[i].triangles).sum();
        if group.len() <= 1 || (triangles <= max_triangles && (hi - lo).max_element() <= max_extent) {
            done.push(group);
            continue;
        }
        let centre = |i: usize| (placed[i].lo + placed[i].hi) * 0.5;
        let (clo, chi) = point_bounds(group.iter().map(|&i| centre(i)));
        let spread = chi - clo;
        let axis = (0..3)
            .max_by(|&a, &b| spread[a].total_cmp(&spread[b]))
            .expect("three axes");
        group.sort_by(|&a, &b| centre(a)[axis].total_cmp(&centre(b)[axis]).then(a.cmp(&b)));
        let right = group.split_off(group.len() / 2);
        todo.push(group);
        todo.push(right);
    }
    done.sort();
    done
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_grid_of_instances_splits_into_batches_within_the_limits() {
        let placed: Vec<Placed> = (0..64)
            .map(|i| {
                let lo = DVec3::new((i % 8) as f64 * 10.0, 0.0, (i / 8) as f64 * 10.0);
                Placed {
                    lo,
                    hi: lo + DVec3::splat(5.0),
                    triangles: 100,
                }
            })
            .collect();
        let batches = cluster(&placed, 1000, 40.0);
        let mut all: Vec<usize> = batches.iter().flatten().copied().collect();
        all.sort();
        assert_eq!(all, (0..64).collect::<Vec<_>>());
        for b in &batches {
            assert!(b.iter().map(|&i| placed[i].triangles).sum::<usize>() <= 1000);
        }
        assert!(batches.len() >= 8 && batches.len() <= 16, "{} batches", batches.len());
    }
}
