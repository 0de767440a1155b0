//! What several stages share and that imports nothing of the pipeline: cameras and their
//! projections ([`camera`]), the rasterizer that draws meshes through them ([`raster`], with its
//! GPU twin), and which triangles lie near a point ([`proximity`]).

pub mod camera;
pub mod proximity;
pub mod raster;
