// cpsv: cube maps from seed cells, the back-face count of each face, and the votes of decided
// seeds in the cells they see. Twin: src/voxel/cpsv.rs.

// --- The cube-map faces: a render pass each, the nearest surface's depth signed by its side.

@group(0) @binding(0) var<uniform> clip_from_mesh: mat4x4<f32>;

struct Fragment {
    @builtin(position) clip: vec4<f32>,
    // Distance in front of the face's camera plane.
    @location(0) depth: f32,
}

@vertex
fn place(@location(0) position: vec3<f32>) -> Fragment {
    let clip = clip_from_mesh * vec4<f32>(position, 1.0);
    return Fragment(clip, clip.w);
}

// +depth for a front face, -depth for a back face.
@fragment
fn side(f: Fragment, @builtin(front_facing) front: bool) -> @location(0) f32 {
    return select(-f.depth, f.depth, front);
}

// --- Counting and voting, over the faces' images copied into one buffer.

struct Params {
    // Pixels along a face, and floats along an image row as copied (rows are padded).
    pixels: u32,
    row_floats: u32,
    // Face images in `images` (six a seed).
    faces: u32,
    cells: u32,
    voters: u32,
}

@group(0) @binding(1) var<storage, read> params: Params;
// Face images, one after another, rows from the top.
@group(0) @binding(2) var<storage, read> images: array<f32>;
// Back-face pixels per face image.
@group(0) @binding(3) var<storage, read_write> backs: array<atomic<u32>>;

const GROUPS_X: u32 = 65535u;

@compute @workgroup_size(64)
fn count_backs(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let i = (group.x + group.y * GROUPS_X) * 64u + local;
    let per_face = params.pixels * params.pixels;
    if i >= per_face * params.faces {
        return;
    }
    let face = i / per_face;
    let y = (i % per_face) / params.pixels;
    let x = i % params.pixels;
    if images[(face * params.pixels + y) * params.row_floats + x] < 0.0 {
        atomicAdd(&backs[face], 1u);
    }
}

struct Voter {
    // The seed's centre relative to the mesh's origin, and its near plane.
    eye: vec3<f32>,
    near: f32,
    // Its image's first face (six follow), and its verdict: 1 inside, 2 outside.
    first_face: u32,
    verdict: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(4) var<storage, read> voters: array<Voter>;
// Each face's clip-from-mesh matrix, six a voter, in the cube map's order (-x, +x, -y, ...
// looking directions).
@group(0) @binding(5) var<storage, read> face_clips: array<mat4x4<f32>>;
// Each cell's lowest and highest corner relative to the mesh's origin; w of lo is 1 where the
// cell is still unknown.
@group(0) @binding(6) var<storage, read> cells: array<vec4<f32>>;
// Votes per cell from this batch: (inside, outside).
@group(0) @binding(7) var<storage, read_write> votes: array<vec2<u32>>;

// Whether voter `v` sees point `p`: it lies nearer than the surface in its cube map.
fn sees(v: Voter, p: vec3<f32>) -> bool {
    let d = p - v.eye;
    let a = abs(d);
    var face: u32;
    if a.x >= a.y && a.x >= a.z {
        face = select(0u, 1u, d.x > 0.0);
    } else if a.y >= a.z {
        face = select(2u, 3u, d.y > 0.0);
    } else {
        face = select(4u, 5u, d.z > 0.0);
    }
    let clip = face_clips[v.first_face + face] * vec4<f32>(p, 1.0);
    if clip.w <= v.near {
        return true;
    }
    let half = f32(params.pixels) * 0.5;
    let last = f32(params.pixels - 1u);
    let x = u32(clamp((clip.x / clip.w + 1.0) * half, 0.0, last));
    let y = u32(clamp((clip.y / clip.w + 1.0) * half, 0.0, last));
    let row = params.pixels - 1u - y;
    let surface = abs(images[((v.first_face + face) * params.pixels + row) * params.row_floats + x]);
    return clip.w < surface;
}

@compute @workgroup_size(64)
fn vote(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) local: u32) {
    let c = (group.x + group.y * GROUPS_X) * 64u + local;
    if c >= params.cells {
        return;
    }
    let lo = cells[2u * c];
    let hi = cells[2u * c + 1u].xyz;
    var got = vec2<u32>(0u, 0u);
    if lo.w == 1.0 {
        for (var v = 0u; v < params.voters; v++) {
            let voter = voters[v];
            var all = true;
            for (var k = 0u; k < 8u; k++) {
                let p = select(lo.xyz, hi, vec3<bool>((k & 1u) != 0u, (k & 2u) != 0u, (k & 4u) != 0u));
                all = all && sees(voter, p);
            }
            if all {
                got[voter.verdict - 1u] += 1u;
            }
        }
    }
    votes[c] = got;
}
