//! occluder-cook: conservative occluders for game meshes.
//!
//! The pipeline, one module per stage: [`mesh`] (ingest, weld, export), [`voxel`] (surface and
//! inside/outside), [`occluder`] (boxes, refinement, selection, merge), [`eval`] (quality
//! figures), tied together by [`cook`]; [`gpu`] runs the voxel stages' shaders through wgpu; [`service`] runs it behind an HTTP job queue with a
//! content-addressed cache.

pub mod bench;
pub mod camera;
pub mod config;
pub mod cook;
pub mod eval;
pub mod gpu;
pub mod key;
pub mod level;
pub mod mesh;
pub mod occluder;
pub mod raster;
pub mod service;
pub mod store;
pub mod voxel;
