//! occluder-cook: conservative occluders for game meshes.
//!
//! The pipeline, one module per stage: [`mesh`] (ingest, weld, export), [`voxel`] (surface and
//! inside/outside), [`occluder`] (boxes, refinement, quads, patches, exposure, selection, merge),
//! [`eval`] (quality figures), tied together as a list of stages by [`cook`]. Each stage with a
//! GPU twin keeps its host code in a `gpu` module beside it; [`gpu`] is the device alone, and
//! [`geom`] holds the cameras and the rasterizer that several stages share. [`store`] keeps jobs,
//! inputs and results (sled or NATS); [`service`] runs the pipeline behind an HTTP job queue on
//! it, and [`level`] bakes whole levels through the same store.

pub mod bench;
pub mod config;
pub mod cook;
pub mod eval;
pub mod fuzz;
pub mod geom;
pub mod gpu;
pub mod key;
pub mod level;
pub mod mesh;
pub mod occluder;
pub mod service;
pub mod soak;
pub mod store;
pub mod voxel;

/// A panic's message and where it was raised, on one line: what a caught panic reports.
pub fn panic_text(info: &std::panic::PanicHookInfo) -> String {
    let message = info
        .payload()
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| info.payload().downcast_ref::<String>().cloned())
        .unwrap_or_default();
    let at = info
        .location()
        .map(|l| format!(" at {}:{}", l.file(), l.line()))
        .unwrap_or_default();
    format!("{message}{at}").replace('\n', " ")
}
