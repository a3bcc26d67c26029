//! # voxray
//!
//! Ray tracing of sparse voxel octrees (SVOs): meshes are voxelized once per part into
//! Laine–Karras style octrees and traced with Revelles' parametric traversal.
//!
//! ```
//! use voxray::{mesh::{Material, Mesh, Part, Triangle}, voxelize, svo, traverse, Ray};
//! use glam::Vec3;
//!
//! // One red triangle, voxelized at 2^6 per axis and built into an SVO.
//! let tri = Triangle {
//!     positions: [Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 0.0, -1.0), Vec3::new(0.0, 0.0, 1.0)],
//!     uvs: None,
//!     material: 0,
//! };
//! let mesh = Mesh {
//!     parts: vec![Part { name: "tri".into(), triangles: vec![tri] }],
//!     materials: vec![Material::new("red", Vec3::new(0.8, 0.1, 0.1))],
//!     ..Default::default()
//! };
//! let opts = voxelize::VoxelizeOptions { resolution: voxelize::Resolution::Depth(6), solid: false };
//! let grid = voxelize::voxelize(&mesh.parts[0], &mesh.materials, &opts, &|_, _| {})?;
//! let octree = svo::build(&grid)?;
//!
//! // Cast a ray straight down onto it.
//! let ray = Ray::new(Vec3::new(0.0, 5.0, 0.0), Vec3::new(0.0, -1.0, 0.0));
//! let hit = traverse::trace(&octree, &ray, &traverse::TraceOptions::default()).expect("hit");
//! assert!((hit.t - 5.0).abs() < 0.05);
//! assert!(hit.albedo().x > 0.5);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs)]
// `!(x > y)` is deliberate throughout: it is true for NaN, so NaN input fails every check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Loops over the three axes index several per-axis arrays at once, as the WGSL twins do.
#![allow(clippy::needless_range_loop)]

pub mod backend;
pub mod bench;
pub mod cache;
pub mod cast;
mod error;
pub mod gi;
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod import;
pub mod input;
pub mod memory;
pub mod mesh;
pub mod model;
pub mod oracle;
pub mod partial;
pub mod pipeline;
pub mod pool;
mod prefetch;
pub mod ray;
pub mod render;
pub mod rng;
pub mod scene;
pub mod session;
pub mod stability;
pub mod svo;
pub mod traverse;
pub mod uninit_stack;
#[cfg(feature = "viewer")]
pub mod viewer;
pub mod voxelize;

pub use error::Error;
pub use ray::Ray;
