//! Edge and component structure: the open boundary that the winding number corrects for, and the
//! orientation of closed parts.

use super::Mesh;
use super::buckets::Buckets;
use serde::Serialize;

/// An edge of the surface's boundary chain: `weight` copies of the directed edge `a → b`.
/// Edges of a consistently oriented closed surface cancel and never appear.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoundaryEdge {
    pub a: u32,
    pub b: u32,
    pub weight: i32,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct Topology {
    /// Edges used by exactly one triangle (holes, open bottoms).
    pub boundary_edges: usize,
    /// Edges used by three or more triangles.
    pub non_manifold_edges: usize,
    pub components: usize,
    pub closed_components: usize,
    /// Closed components whose faces pointed inwards; they were turned outwards.
    pub inverted_components: usize,
    /// Flipped faces of closed components, turned to agree with the rest.
    pub reoriented_triangles: usize,
    /// Copies left out of components whose every triangle has one ([`remove_doubled_copies`]).
    pub duplicate_triangles: usize,
    #[serde(skip)]
    pub boundary: Vec<BoundaryEdge>,
    /// Per triangle: whether its component has an open boundary (no volume of its own).
    #[serde(skip)]
    pub open_triangles: Vec<bool>,
}

/// Leaves out the copies of doubled components ([`remove_doubled_copies`]), turns the flipped faces of
/// closed components to agree with the rest ([`close_flipped_components`]), then inverted
/// closed components outwards, in place, and returns the topology of the result.
pub fn orient_closed_components(mesh: &mut Mesh) -> Topology {
    let component = components(mesh);
    let count = component.iter().copied().max().map_or(0, |m| m as usize + 1);
    let duplicate_triangles = remove_doubled_copies(mesh, &component, count);
    let uses = directed_uses(mesh);
    let turned = close_flipped_components(mesh, &uses, &component, count);
    let reoriented_triangles = turned.iter().filter(|&&t| t).count();
    let mut open = vec![false; count];
    let mut volume = vec![0.0f64; count];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
        volume[component[tri[0] as usize] as usize] += a.dot(b.cross(c));
    }
    let edges = edge_uses(&uses, &turned);
    for ((a, _), uses) in &edges {
        if uses.net != 0 {
            open[component[*a as usize] as usize] = true;
        }
    }
    let inverted: Vec<bool> = (0..count).map(|c| !open[c] && volume[c] < 0.0).collect();
    for tri in &mut mesh.triangles {
        if inverted[component[tri[0] as usize] as usize] {
            tri.swap(1, 2);
        }
    }
    let mut topology = Topology {
        components: count,
        closed_components: open.iter().filter(|o| !**o).count(),
        inverted_components: inverted.iter().filter(|i| **i).count(),
        reoriented_triangles,
        duplicate_triangles,
        open_triangles: mesh
            .triangles
            .iter()
            .map(|t| open[component[t[0] as usize] as usize])
            .collect(),
        ..Default::default()
    };
    // In the keys' order, so that floating-point sums over the boundary are reproducible.
    for &((a, b), ref uses) in &edges {
        let net = if inverted[component[a as usize] as usize] {
            -uses.net
        } else {
            uses.net
        };
        topology.boundary_edges += usize::from(uses.total == 1);
        topology.non_manifold_edges += usize::from(uses.total > 2);
        if net != 0 {
            topology.boundary.push(BoundaryEdge { a, b, weight: net });
        }
    }
    topology
}

/// Leaves out, in place, the copies in each component all of whose triangles share their three
/// corners with another: all but the first on the same corners. Returns how many. A face
/// copied with its winding reversed, as double-sided art often is, cancels the original's
/// winding and would leave no inside; a copy either way adds no surface. Where only some
/// triangles have a copy (a fold, a fin), a copy is part of the surface, and stays.
fn remove_doubled_copies(mesh: &mut Mesh, component: &[u32], count: usize) -> usize {
    let corners = sorted_by_vertex(
        mesh.positions.len(),
        mesh.triangles.iter().zip(0..).map(|(tri, t)| {
            let mut sorted = *tri;
            sorted.sort_unstable();
            (sorted[0], (sorted, t))
        }),
    );
    let mut repeated = vec![false; mesh.triangles.len()];
    let mut doubled = vec![true; count];
    for same in corners.chunk_by(|a, b| a.0 == b.0) {
        let (first, copies) = same.split_first().expect("chunks are not empty");
        match copies.is_empty() {
            true => doubled[component[first.0[0] as usize] as usize] = false,
            false => copies.iter().for_each(|&(_, t)| repeated[t as usize] = true),
        }
    }
    let mut left_out = 0;
    let mut t = 0;
    mesh.triangles.retain(|tri| {
        let copy = repeated[t] && doubled[component[tri[0] as usize] as usize];
        t += 1;
        left_out += usize::from(copy);
        !copy
    });
    left_out
}

struct EdgeUses {
    /// Uses as `a → b` minus uses as `b → a`, for the key `(a, b)` with `a < b`.
    net: i32,
    total: u32,
}

/// An edge's use by a triangle: the edge's key (its lower vertex first), 1 where the triangle
/// runs from the key's lower vertex and -1 where from its higher, and the triangle.
type Use = ((u32, u32), i32, u32);

/// The use of triangle `t`'s edge from corner k to the next.
fn edge_use(tri: &[u32; 3], k: usize, t: u32) -> Use {
    let (a, b) = (tri[k], tri[(k + 1) % 3]);
    if a < b { ((a, b), 1, t) } else { ((b, a), -1, t) }
}

/// Every edge use of `mesh`, in order of key: grouped by the key's lower vertex.
fn directed_uses(mesh: &Mesh) -> Vec<Use> {
    let uses = (mesh.triangles.iter().zip(0..))
        .flat_map(|(tri, t)| (0..3).map(move |k| edge_use(tri, k, t)))
        .map(|edge| (edge.0.0, edge));
    sorted_by_vertex(mesh.positions.len(), uses)
}

/// `items` sorted, each given with the vertex (below `vertices`) its order starts with: grouped
/// by that vertex in a counting sort, then each group sorted, where a vertex has a few items.
/// Equal items are the same value, so the order is a plain sort's.
fn sorted_by_vertex<T: Copy + Default + Ord>(vertices: usize, items: impl Iterator<Item = (u32, T)> + Clone) -> Vec<T> {
    let Buckets { starts, mut items } = Buckets::new(vertices, items.map(|(v, item)| (v as usize, item)));
    for group in starts.windows(2) {
        items[group[0]..group[1]].sort_unstable();
    }
    items
}

/// Each edge's uses, by its key, the keys in order; a triangle `turned` runs the other way.
fn edge_uses(uses: &[Use], turned: &[bool]) -> Vec<((u32, u32), EdgeUses)> {
    uses.chunk_by(|x, y| x.0 == y.0)
        .map(|uses| {
            let net = uses
                .iter()
                .map(|&(_, sign, t)| if turned[t as usize] { -sign } else { sign })
                .sum();
            (
                uses[0].0,
                EdgeUses {
                    net,
                    total: uses.len() as u32,
                },
            )
        })
        .collect()
}

/// Turns triangles, in place, so that two that alone share an edge cross it in opposite
/// directions, as a surface's faces do: each part so joined keeps the way most of its triangles
/// face. Only where that closes a component (every edge's uses cancel) does it stay; an open one
/// keeps its triangles as they were. Returns which were turned.
fn close_flipped_components(mesh: &mut Mesh, uses: &[Use], component: &[u32], count: usize) -> Vec<bool> {
    let n = mesh.triangles.len();
    // Per triangle, its neighbours across edges that two triangles share, and whether each runs
    // the edge the same way (disagrees).
    let mut neighbours = vec![[(u32::MAX, false); 3]; n];
    for pair in uses.chunk_by(|x, y| x.0 == y.0).filter(|pair| pair.len() == 2) {
        let ((_, s_sign, s), (_, t_sign, t)) = (pair[0], pair[1]);
        for (from, to) in [(s, t), (t, s)] {
            if let Some(slot) = neighbours[from as usize].iter_mut().find(|n| n.0 == u32::MAX) {
                *slot = (to, s_sign == t_sign);
            }
        }
    }
    // Part by part, whether each triangle turns to agree with where the part began.
    let mut turn: Vec<Option<bool>> = vec![None; n];
    let mut turned = vec![false; n];
    let (mut part, mut stack) = (Vec::new(), Vec::new());
    for seed in 0..n {
        if turn[seed].is_some() {
            continue;
        }
        turn[seed] = Some(false);
        part.clear();
        stack.push(seed);
        while let Some(t) = stack.pop() {
            part.push(t);
            let flip = turn[t] == Some(true);
            for &(u, disagree) in neighbours[t].iter().filter(|n| n.0 != u32::MAX) {
                if turn[u as usize].is_none() {
                    turn[u as usize] = Some(flip != disagree);
                    stack.push(u as usize);
                }
            }
        }
        let most_turn = 2 * part.iter().filter(|&&t| turn[t] == Some(true)).count() > part.len();
        for &t in &part {
            turned[t] = (turn[t] == Some(true)) != most_turn;
        }
    }
    let mut open = vec![false; count];
    for (key, edge) in edge_uses(uses, &turned) {
        if edge.net != 0 {
            open[component[key.0 as usize] as usize] = true;
        }
    }
    for (t, tri) in mesh.triangles.iter_mut().enumerate() {
        turned[t] &= !open[component[tri[0] as usize] as usize];
        if turned[t] {
            tri.swap(1, 2);
        }
    }
    turned
}

/// Connected components over shared vertices, numbered densely from 0, one entry per vertex.
pub fn components(mesh: &Mesh) -> Vec<u32> {
    let links = mesh
        .triangles
        .iter()
        .flat_map(|tri| [(tri[0], tri[1]), (tri[0], tri[2])]);
    linked_components(mesh.positions.len(), links)
}

/// Connected components of `count` vertices joined by `links`, numbered densely from 0 in the
/// order of their first vertex, one entry per vertex.
pub fn linked_components(count: usize, links: impl IntoIterator<Item = (u32, u32)>) -> Vec<u32> {
    let mut parent: Vec<u32> = (0..count as u32).collect();
    fn root(parent: &mut [u32], mut x: u32) -> u32 {
        while parent[x as usize] != x {
            parent[x as usize] = parent[parent[x as usize] as usize];
            x = parent[x as usize];
        }
        x
    }
    for (a, b) in links {
        let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
        if ra != rb {
            parent[ra.max(rb) as usize] = ra.min(rb);
        }
    }
    let mut label = vec![u32::MAX; parent.len()];
    let mut next = 0;
    (0..parent.len() as u32)
        .map(|v| {
            let r = root(&mut parent, v) as usize;
            if label[r] == u32::MAX {
                label[r] = next;
                next += 1;
            }
            label[r]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::occluder::BOX_FACES;
    use glam::Vec3;

    /// A unit cube, wound outwards, without the faces in `skip` (in `BOX_FACES`' order).
    fn cube(skip: &[usize]) -> Mesh {
        let corner = |i: u32| Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, (i >> 2) as f32);
        Mesh {
            positions: (0..8).map(corner).collect(),
            triangles: BOX_FACES
                .iter()
                .enumerate()
                .filter(|(f, _)| !skip.contains(f))
                .flat_map(|(_, q)| {
                    let [a, b, c, d] = q.map(|i| i as u32);
                    [[a, b, c], [a, c, d]]
                })
                .collect(),
        }
    }

    #[test]
    fn a_closed_cube_with_flipped_faces_is_closed_again_and_an_open_one_is_left_alone() {
        let outward = cube(&[]);
        assert_eq!(orient_closed_components(&mut outward.clone()).closed_components, 1);
        let mut flipped = outward.clone();
        for t in [3, 7] {
            flipped.triangles[t].swap(1, 2);
        }
        let topology = orient_closed_components(&mut flipped);
        assert_eq!((topology.closed_components, topology.reoriented_triangles), (1, 2));
        assert!(topology.boundary.is_empty());
        assert_eq!(flipped.triangles, outward.triangles);
        // All of it flipped: one inverted component, turned outwards whole.
        let mut inside_out = outward.clone();
        inside_out.triangles.iter_mut().for_each(|t| t.swap(1, 2));
        let topology = orient_closed_components(&mut inside_out);
        assert_eq!((topology.inverted_components, topology.reoriented_triangles), (1, 0));
        assert_eq!(inside_out.triangles, outward.triangles);
        // Open, its flipped face stays: nothing says which way an open surface faces.
        let mut open = cube(&[3]);
        open.triangles[0].swap(1, 2);
        let before = open.triangles.clone();
        let topology = orient_closed_components(&mut open);
        assert_eq!((topology.closed_components, topology.reoriented_triangles), (0, 0));
        assert_eq!(open.triangles, before);
    }

    #[test]
    fn a_cube_doubled_for_both_sides_is_one_closed_cube_again() {
        let outward = cube(&[]);
        // Each face copied wound the other way, then a third copy of one face, as given.
        let mut doubled = outward.clone();
        doubled
            .triangles
            .extend(outward.triangles.iter().map(|&[a, b, c]| [a, c, b]));
        doubled.triangles.push(outward.triangles[5]);
        let topology = orient_closed_components(&mut doubled);
        assert_eq!((topology.duplicate_triangles, topology.closed_components), (13, 1));
        assert!(topology.boundary.is_empty());
        assert_eq!(doubled.triangles, outward.triangles);
        // One face copied, a fold of the surface: it stays.
        let mut folded = outward.clone();
        folded
            .triangles
            .extend([outward.triangles[0], outward.triangles[1]].map(|[a, b, c]| [a, c, b]));
        let topology = orient_closed_components(&mut folded);
        assert_eq!((topology.duplicate_triangles, folded.triangles.len()), (0, 14));
    }

    #[test]
    fn edge_uses_by_vertex_come_in_a_plain_sorts_order() {
        // A fan around vertex 0 and a strip, with repeated and flipped triangles: vertices
        // with many uses, equal keys and equal uses.
        let mut mesh = Mesh {
            positions: vec![Vec3::ZERO; 40],
            triangles: (1..39).map(|k| [0, k, k + 1]).collect(),
        };
        mesh.triangles.extend((5..30).map(|k| [k + 1, k, (k * 7) % 39 + 1]));
        mesh.triangles.extend([[3, 2, 0], [0, 2, 3], [0, 1, 2]]);
        let mut plain: Vec<Use> = (mesh.triangles.iter().zip(0..))
            .flat_map(|(tri, t)| (0..3).map(move |k| edge_use(tri, k, t)))
            .collect();
        plain.sort_unstable();
        assert_eq!(directed_uses(&mesh), plain);
    }
}
