// The exposure test's corners: which grid corners some view sees in front of the original, the
// views being orthographic from directions above the horizon or perspective from cameras in the
// mesh's openings. Twin: `OpenViews::remove_exposed` in src/occluder/exposure.rs.
//
// A workgroup takes a word of 32 corners (z fastest) and its lanes take the views, each lane
// testing its views against every corner of the word. A lane so loads its views' rows once,
// where a thread per corner would load every view's rows again; a software adapter (llvmpipe)
// loads them lane by lane. A view's image is looked at only where the corner is nearer than
// the farthest depth of the pixel's tile.

struct Params {
    corners_y: u32,
    corners_z: u32,
    words: u32,
    views: u32,
    pixels: u32,
}

@group(0) @binding(0) var<storage, read> params: Params;
// The words with corners to test: (word, one bit a corner), the corners of inner voxels.
@group(0) @binding(1) var<storage, read> needed: array<vec2<u32>>;
// Five rows a view, corners in voxel units: X, Y, W and depth + tolerance = row · (corner, 1),
// the pixel being (X / W, Y / W); then (the height it counts up to, in voxels; 1 for a camera
// in an opening, else 0; its near distance; unused).
@group(0) @binding(2) var<uniform> views: array<vec4<f32>, 1880>;
// The views' depth images, each pixel the farthest of its neighbourhood, rows from the bottom.
@group(0) @binding(3) var<storage, read> depths: array<f32>;
// One bit a corner: seen.
@group(0) @binding(4) var<storage, read_write> seen: array<atomic<u32>>;
// Per view, the farthest depth of each TILE × TILE tile of its image.
@group(0) @binding(5) var<storage, read> tiles: array<f32>;

const GROUPS_X: u32 = 65535u;
const LANES: u32 = 64u;
// TILE in src/occluder/exposure.rs; a constant, so that dividing by it is a shift (a software
// adapter divides lane by lane).
const TILE: u32 = 8u;

@compute @workgroup_size(64)
fn seen_corners(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let w = group.x + group.y * GROUPS_X;
    if w >= params.words {
        return;
    }
    let word = needed[w];
    let first = word.x * 32u;
    let dims = vec2<u32>(params.corners_y, params.corners_z);
    let start = vec3<u32>(first / (dims.x * dims.y), (first / dims.y) % dims.x, first % dims.y);
    let n = params.pixels;
    let tiles_per_row = n / TILE;
    var sees_bits = 0u;
    for (var v = lane; v < params.views; v += LANES) {
        let to_x = views[5u * v];
        let to_y = views[5u * v + 1u];
        let to_w = views[5u * v + 2u];
        let to_depth = views[5u * v + 3u];
        let limits = views[5u * v + 4u];
        let in_opening = limits.y != 0.0;
        // The word's corners in turn, counted rather than divided out of their index.
        var c = start;
        for (var k = 0u; k < 32u; k++) {
            let bit = 1u << k;
            if (word.y & bit) != 0u && (sees_bits & bit) == 0u {
                let corner = vec4<f32>(vec3<f32>(c), 1.0);
                let w = dot(to_w, corner);
                let x = dot(to_x, corner) / w;
                let y = dot(to_y, corner) / w;
                let off_image = !(x >= 0.0 && y >= 0.0 && x < f32(n) && y < f32(n));
                // As in the twin: off the image of a view above the horizon is seen; a camera
                // in an opening sees only what lies in front of it, in its face, and no higher
                // than its opening.
                var sees = off_image && !in_opening;
                let looked_at = !off_image && (!in_opening || (w > limits.z && corner.y <= limits.x));
                if looked_at {
                    let depth = dot(to_depth, corner);
                    let px = u32(x);
                    let py = u32(y);
                    let tile = (v * tiles_per_row + py / TILE) * tiles_per_row + px / TILE;
                    sees = depth < tiles[tile] && depth < depths[(v * n + py) * n + px];
                }
                if sees {
                    sees_bits |= bit;
                }
            }
            c.z++;
            if c.z == dims.y {
                c.z = 0u;
                c.y++;
                if c.y == dims.x {
                    c.y = 0u;
                    c.x++;
                }
            }
        }
    }
    if sees_bits != 0u {
        atomicOr(&seen[word.x], sees_bits);
    }
}
