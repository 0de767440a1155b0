//! The merged union of boxes is watertight: every directed edge is matched by its reverse.

mod common;
use common::signed_volume;
use occluder_cook::occluder::{WorldBox, merge::merge};
use std::collections::HashMap;

fn assert_watertight(mesh: &occluder_cook::mesh::Mesh) {
    let mut edges: HashMap<(u32, u32), i32> = HashMap::new();
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_default() += if a < b { 1 } else { -1 };
        }
    }
    let open: Vec<_> = edges.iter().filter(|(_, n)| **n != 0).collect();
    assert!(open.is_empty(), "unmatched edges: {open:?}");
}

fn b(lo: [f64; 3], hi: [f64; 3]) -> WorldBox {
    WorldBox { lo, hi }
}

#[test]
fn one_box_is_twelve_triangles() {
    let m = merge(&[b([0.0; 3], [1.0, 2.0, 3.0])]);
    assert_eq!(m.triangles.len(), 12);
    assert_watertight(&m);
    assert!((signed_volume(&m) - 6.0).abs() < 1e-5);
}

#[test]
fn touching_boxes_lose_their_shared_face() {
    let m = merge(&[b([0.0; 3], [1.0; 3]), b([1.0, 0.0, 0.0], [2.0, 1.0, 1.0])]);
    assert_eq!(m.triangles.len(), 12, "coplanar faces merge into one box");
    assert_watertight(&m);
}

#[test]
fn staggered_and_overlapping_boxes_stay_watertight() {
    let boxes = [
        b([0.0; 3], [2.0, 1.0, 1.0]),
        b([0.5, 1.0, 0.25], [1.25, 1.6, 0.8]),
        b([1.5, -0.3, 0.2], [2.7, 0.7, 0.9]),
        b([0.2, 0.2, 0.2], [0.4, 0.4, 0.4]),
    ];
    let m = merge(&boxes);
    assert_watertight(&m);
    // Union volume: 2 + 0.75*0.6*0.55 + (1.2*1*0.7 - 0.5*0.7*0.7), the small box is inside.
    let expected = 2.0 + 0.75 * 0.6 * 0.55 + (1.2 * 1.0 * 0.7 - 0.5 * 0.7 * 0.7);
    assert!(
        (signed_volume(&m) - expected).abs() < 1e-4,
        "{} vs {expected}",
        signed_volume(&m)
    );
}
