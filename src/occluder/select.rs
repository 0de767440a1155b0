//! Choosing boxes by what they add to the silhouette, not by volume: a box enters only when it
//! covers enough pixels of the original's silhouette that no chosen box covers yet, and the
//! box that adds the most pixels per triangle of the merged occluder goes first.

use super::{WorldBox, merge::merge};
use crate::eval::raster::{View, coverage_mask};
use crate::eval::views::fibonacci_sphere;
use crate::mesh::Mesh;
use rayon::prelude::*;

/// Views and pixels of the selection's silhouettes: coarser than `eval`'s, enough to rank boxes.
const VIEWS: usize = 24;
const PIXELS: usize = 128;
/// Candidates, by silhouette gain, whose real triangle cost is measured at each step.
const LOOKAHEAD: usize = 8;

pub struct Selection {
    /// Indices into the candidates, in the order chosen.
    pub chosen: Vec<usize>,
    /// Silhouette share each chosen box added.
    pub gains: Vec<f64>,
    /// The merged occluder of the chosen boxes, within the triangle budget.
    pub occluder: Mesh,
}

pub fn select(mesh: &Mesh, candidates: &[WorldBox], max_triangles: usize, min_gain: f64) -> Selection {
    let (center, radius) = mesh.bounding_sphere();
    let views: Vec<View> = fibonacci_sphere(VIEWS)
        .into_iter()
        .map(|d| View::new(d, center, radius, PIXELS))
        .collect();
    let silhouettes: Vec<Vec<u64>> = views
        .par_iter()
        .map(|v| coverage_mask(v, mesh.triangles_f64()))
        .collect();
    let total: u64 = silhouettes.iter().flatten().map(|w| u64::from(w.count_ones())).sum();
    // masks[box][view]
    let masks: Vec<Vec<Vec<u64>>> = candidates
        .par_iter()
        .map(|b| {
            views
                .iter()
                .zip(&silhouettes)
                .map(|(v, s)| {
                    let m = coverage_mask(v, b.triangles().into_iter());
                    m.iter().zip(s).map(|(a, b)| a & b).collect()
                })
                .collect()
        })
        .collect();
    let mut covered: Vec<Vec<u64>> = silhouettes.iter().map(|s| vec![0; s.len()]).collect();
    let mut selection = Selection {
        chosen: Vec::new(),
        gains: Vec::new(),
        occluder: Mesh::default(),
    };
    loop {
        let gain = |i: usize| -> u64 {
            masks[i]
                .iter()
                .zip(&covered)
                .flat_map(|(m, c)| m.iter().zip(c).map(|(a, b)| u64::from((a & !b).count_ones())))
                .sum()
        };
        let mut ranked: Vec<(usize, u64)> = (0..candidates.len())
            .filter(|i| !selection.chosen.contains(i))
            .map(|i| (i, gain(i)))
            .filter(|&(_, g)| g as f64 >= min_gain * total as f64 && g > 0)
            .collect();
        ranked.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        // The merge decides what a box really costs: touching boxes share faces, and T-junctions
        // add vertices. Price the best few by merging them in.
        let priced = ranked.iter().take(LOOKAHEAD).filter_map(|&(i, g)| {
            let mut boxes: Vec<WorldBox> = selection.chosen.iter().map(|&c| candidates[c]).collect();
            boxes.push(candidates[i]);
            let mesh = merge(&boxes);
            let added = mesh
                .triangles
                .len()
                .saturating_sub(selection.occluder.triangles.len())
                .max(1);
            (mesh.triangles.len() <= max_triangles).then_some((i, g, g as f64 / added as f64, mesh))
        });
        let Some((i, pixels, _, mesh)) = priced.max_by(|a, b| a.2.total_cmp(&b.2).then(b.0.cmp(&a.0))) else {
            break;
        };
        for (c, m) in covered.iter_mut().zip(&masks[i]) {
            for (a, b) in c.iter_mut().zip(m) {
                *a |= b;
            }
        }
        selection.chosen.push(i);
        selection.gains.push(pixels as f64 / total.max(1) as f64);
        selection.occluder = mesh;
    }
    selection
}
