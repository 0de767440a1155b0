//! Edge and component structure: the open boundary that the winding number corrects for, and the
//! orientation of closed parts.

use super::Mesh;
use rayon::slice::ParallelSliceMut;
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
    #[serde(skip)]
    pub boundary: Vec<BoundaryEdge>,
    /// Per triangle: whether its component has an open boundary (no volume of its own).
    #[serde(skip)]
    pub open_triangles: Vec<bool>,
}

/// Turns inverted closed components outwards in place and returns the topology of the result.
pub fn orient_closed_components(mesh: &mut Mesh) -> Topology {
    let component = components(mesh);
    let count = component.iter().copied().max().map_or(0, |m| m as usize + 1);
    let mut open = vec![false; count];
    let mut volume = vec![0.0f64; count];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let [a, b, c] = mesh.corners(t).map(|p| p.as_dvec3());
        volume[component[tri[0] as usize] as usize] += a.dot(b.cross(c));
    }
    let edges = edge_uses(mesh);
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

struct EdgeUses {
    /// Uses as `a → b` minus uses as `b → a`, for the key `(a, b)` with `a < b`.
    net: i32,
    total: u32,
}

/// Each edge's uses, by its key, the keys in order.
fn edge_uses(mesh: &Mesh) -> Vec<((u32, u32), EdgeUses)> {
    let mut directed: Vec<((u32, u32), i32)> = mesh
        .triangles
        .iter()
        .flat_map(|tri| {
            (0..3).map(|k| {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                if a < b { ((a, b), 1) } else { ((b, a), -1) }
            })
        })
        .collect();
    // Equal entries are the same value, so the parallel sort's order is the serial one's.
    directed.par_sort_unstable();
    directed
        .chunk_by(|x, y| x.0 == y.0)
        .map(|uses| {
            let net = uses.iter().map(|&(_, sign)| sign).sum();
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
