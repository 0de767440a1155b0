// The bricked grid's inside stage, brick by brick: a workgroup per brick, a lane per row of its
// 8³ voxels, each lane marching its row along the four ways (+x, -x, +z, -z) from the brick's
// far side. Twin: src/voxel/brick_inside.rs.

// Each brick's 512 surface bytes (facing bits), four to a word.
@group(0) @binding(5) var<storage, read> surface: array<u32>;
// Per brick, one word a row, one byte a way: `entries` writes what each row meets first
// entering the brick; `classify` reads what each row meets past the brick.
@group(0) @binding(6) var<storage, read_write> rows: array<u32>;
// Per brick, 512 bits: the voxels inside.
@group(0) @binding(7) var<storage, read_write> inside: array<atomic<u32>>;

const NOTHING: u32 = 0u;
const FRONT: u32 = 1u;
const BACK: u32 = 2u;

// Voxels inside on each way so far, a bit a way, per voxel of the workgroup's brick.
var<workgroup> fronts: array<atomic<u32>, 512>;

fn facing_back(way: u32) -> u32 {
    // The facing bits of -x, +x, -z, +z (FACES in src/voxel/bricks.rs).
    return array<u32, 4>(2u, 1u, 32u, 16u)[way];
}

fn voxel_index(way: u32, row: u32, along: u32) -> u32 {
    if way < 2u {
        return along + 8u * row;
    }
    return row + 64u * along;
}

// What `way` meets from the voxel `step` places from the far side of `row`, given what it met
// before; `voxel` is that voxel's index.
fn met_at(brick: u32, way: u32, row: u32, step: u32, met: u32) -> vec2<u32> {
    let along = select(step, 7u - step, way % 2u == 0u);
    let voxel = voxel_index(way, row, along);
    let at = brick * 512u + voxel;
    let bits = (surface[at / 4u] >> (8u * (at % 4u))) & 0xffu;
    if bits == 0u {
        return vec2<u32>(voxel, met);
    }
    return vec2<u32>(voxel, select(BACK, FRONT, (bits & facing_back(way)) != 0u));
}

@compute @workgroup_size(64)
fn entries(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) row: u32) {
    let brick = flat_group(group);
    if brick >= params.items {
        return;
    }
    var word = 0u;
    for (var way = 0u; way < 4u; way++) {
        var met = NOTHING;
        for (var step = 0u; step < 8u; step++) {
            met = met_at(brick, way, row, step, met).y;
        }
        word |= met << (8u * way);
    }
    rows[brick * 64u + row] = word;
}

@compute @workgroup_size(64)
fn classify(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) row: u32) {
    let brick = flat_group(group);
    let valid = brick < params.items;
    if valid {
        let beyond = rows[brick * 64u + row];
        for (var way = 0u; way < 4u; way++) {
            var met = (beyond >> (8u * way)) & 0xffu;
            for (var step = 0u; step < 8u; step++) {
                let at = met_at(brick, way, row, step, met);
                met = at.y;
                if met == FRONT {
                    atomicOr(&fronts[at.x], 1u << way);
                }
            }
        }
    }
    workgroupBarrier();
    if valid {
        // This lane's byte of the brick's bits: voxels 8 row to 8 row + 7.
        var byte = 0u;
        for (var k = 0u; k < 8u; k++) {
            if atomicLoad(&fronts[8u * row + k]) == 15u {
                byte |= 1u << k;
            }
        }
        atomicOr(&inside[brick * 16u + row / 4u], byte << (8u * (row % 4u)));
    }
}
