//! What several stages share and that imports nothing of the pipeline: cameras and their
//! projections ([`camera`]), the rasterizer that draws meshes through them ([`raster`], with its
//! GPU twin), which triangles lie near a point ([`proximity`]), and the openings of a mesh
//! narrower than a width, closed ([`openings`]), and items grouped by a dense key ([`buckets`]).

pub mod buckets;
pub mod camera;
pub mod openings;
pub mod proximity;
pub mod raster;
