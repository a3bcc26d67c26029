//! Rendering: per-frame instance preparation, the instance BVH, visibility searches, the
//! hit buffer, the frame plan, the CPU renderer and the image/AOV writers.

pub mod beam;
pub mod brdf;
pub mod bvh;
pub mod bvh_wide;
pub mod cpu;
pub mod emitters;
pub mod gather;
pub mod hitbuffer;
pub mod instances;
pub mod output;
pub mod packet_bvh;
pub mod pixel_spheres;
pub mod plan;
pub mod primary;
pub mod radiance_cache;
mod ray_setup;
pub mod splat;
pub mod tile_search;
mod unit_normals;
pub mod visibility;

pub use cpu::{render, render_lit, AmbientLight, Frame, RenderOptions, Renderer, SplatDraw};
pub use gather::Gather;
pub use hitbuffer::HitBuffer;
pub use plan::{Features, FramePlan};
