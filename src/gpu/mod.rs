//! The GPU path (feature `gpu`): a wgpu device, the shared buffer layouts, the frame renderer,
//! the ray-list tracer and the scene caster, all running the WGSL twins of the CPU code in
//! `wgsl/`.

pub mod baseline;
pub mod cast;
pub mod context;
pub mod crowd;
pub mod gi;
pub mod layout;
pub mod prelude;
pub mod rays;
pub mod refit;
pub mod renderer;
mod scatter;
mod splat;

pub use context::{GpuContext, GpuError};
pub use renderer::{GpuRenderer, GpuTimes};
