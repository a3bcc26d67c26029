//! The GPU path (feature `gpu`): a wgpu device, the shared buffer layouts, the frame renderer
//! and the ray-list tracer, all running the WGSL twins of the CPU code in `wgsl/`.

pub mod baseline;
pub mod context;
pub mod gi;
pub mod layout;
pub mod prelude;
pub mod rays;
pub mod renderer;
mod scatter;
mod splat;

pub use context::{GpuContext, GpuError};
pub use renderer::{GpuRenderer, GpuTimes};
