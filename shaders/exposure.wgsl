// The exposure test's corners: which grid corners some view above the horizon sees in front of
// the original. A thread per corner tries the views in turn until one sees it. Twin:
// `OpenViews::remove_exposed` in src/occluder/exposure.rs.

struct Params {
    corners_y: u32,
    corners_z: u32,
    corners: u32,
    views: u32,
    pixels: u32,
}

@group(0) @binding(0) var<storage, read> params: Params;
// One bit a corner (z fastest): the corners of inner voxels, the only ones worth testing.
@group(0) @binding(1) var<storage, read> needed: array<u32>;
// Three rows a view: (x pixel, y pixel, depth + tolerance) = row · (corner, 1), corners in
// voxel units.
@group(0) @binding(2) var<storage, read> views: array<vec4<f32>>;
// The views' depth images, each pixel the farthest of its neighbourhood, rows from the bottom.
@group(0) @binding(3) var<storage, read> depths: array<f32>;
// One bit a corner: seen.
@group(0) @binding(4) var<storage, read_write> seen: array<atomic<u32>>;

const GROUPS_X: u32 = 65535u;

@compute @workgroup_size(64)
fn seen_corners(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let c = (group.x + group.y * GROUPS_X) * 64u + lane;
    if c >= params.corners || (needed[c / 32u] & (1u << (c % 32u))) == 0u {
        return;
    }
    let corner = vec4<f32>(
        f32(c / (params.corners_y * params.corners_z)),
        f32((c / params.corners_z) % params.corners_y),
        f32(c % params.corners_z),
        1.0,
    );
    let n = params.pixels;
    for (var v = 0u; v < params.views; v++) {
        let x = dot(views[3u * v], corner);
        let y = dot(views[3u * v + 1u], corner);
        // Off the image counts as seen, as in the twin.
        var sees = !(x >= 0.0 && y >= 0.0 && x < f32(n) && y < f32(n));
        if !sees {
            sees = dot(views[3u * v + 2u], corner) < depths[(v * n + u32(y)) * n + u32(x)];
        }
        if sees {
            atomicOr(&seen[c / 32u], 1u << (c % 32u));
            return;
        }
    }
}
