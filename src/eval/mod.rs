//! Quality figures of an occluder against its original (see DESIGN.md): coverage, false pixels,
//! outside samples, triangles.

pub mod metrics;
pub mod preview;

pub use metrics::{EvalSettings, Quality, ViewSet, evaluate, evaluate_where_it_can};
