//! How a `SceneSpec` becomes pixels: find (or install) Blender's Python, run long-lived worker
//! processes that build and render specs, and recover from workers that crash or hang.

mod faults;
pub mod protocol;
pub mod runtime;
pub mod scratch;
pub mod scripts;
pub mod service;
pub mod worker;

pub use faults::FaultPlan;
pub use protocol::{
    Device, Fault, GeometryOutput, Hello, RenderOutput, Reply, Request, WorkerReport,
};
pub use runtime::{BlenderRuntime, RuntimeError};
pub use service::{ExportedGeometry, RenderService, Rendered};
pub use worker::{Worker, WorkerConfig, WorkerError, WorkerOptions};
