// Depth images of a mesh from orthographic views: the vertex stage alone, the depth test keeping
// the nearest surface at each pixel centre. Twin: `depth_image` in src/eval/raster.rs.

@group(0) @binding(0) var<uniform> clip_from_mesh: mat4x4<f32>;

@vertex
fn place(@location(0) position: vec3<f32>) -> @builtin(position) vec4<f32> {
    return clip_from_mesh * vec4<f32>(position, 1.0);
}
