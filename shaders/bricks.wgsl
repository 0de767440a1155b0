// Bricked surface voxelization: a workgroup per (triangle, brick) pair, a lane per column of the
// brick's 8³ voxels, the separating-axis test of surface.wgsl, and the triangle's facing bits
// OR-ed into the voxel's byte. Twin: src/voxel/bricks.rs.

// Each brick's first voxel, in grid voxels.
@group(0) @binding(5) var<storage, read> brick_origins: array<vec4<u32>>;
// 512 voxel bytes a brick, four to a word.
@group(0) @binding(6) var<storage, read_write> brick_voxels: array<atomic<u32>>;

// items: (triangle, brick, unused, facing bits); params.items counts them.
@compute @workgroup_size(64)
fn bricks(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let id = flat_group(group);
    if id >= params.items {
        return;
    }
    let item = items[id];
    let t0 = corner(item.x, 0u);
    let t1 = corner(item.x, 1u);
    let t2 = corner(item.x, 2u);
    let origin = brick_origins[item.y].xyz;
    let column = vec2<u32>(lane % 8u, lane / 8u);
    for (var z = 0u; z < 8u; z++) {
        let centre = vec3<f32>(origin + vec3<u32>(column, z)) + vec3<f32>(0.5);
        if overlaps(centre, params.half, t0, t1, t2) {
            let voxel = item.y * 512u + lane + 64u * z;
            atomicOr(&brick_voxels[voxel / 4u], item.w << (8u * (voxel % 4u)));
        }
    }
}
