//! What several stages share and that imports nothing of the pipeline: cameras and their
//! projections ([`camera`]), and the rasterizer that draws meshes through them ([`raster`],
//! with its GPU twin).

pub mod camera;
pub mod raster;
