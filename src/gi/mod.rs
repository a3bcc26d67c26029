//! Voxel-transformation global illumination (see DESIGN.md): every part is voxelized once
//! more, coarsely, into a linear [`VoxelCache`]; each frame the caches of the instances are
//! transformed by their world matrices into a world [`Volume`] with nearest or 8-neighbour
//! split filtering, lit per cell ([`inject`](mod@inject)) and averaged up a level chain ([`levels`]).
//! and sampled by voxel cone tracing ([`cone`]). This module is the CPU reference of those
//! passes, and [`reference`](mod@reference) is the path tracer they are measured against.

pub mod cache;
pub mod cone;
pub mod inject;
pub mod levels;
pub mod reference;
pub mod shade;
pub mod sparse;
pub mod triangles;
pub mod volume;

pub use cache::{CacheError, CacheVoxel, VoxelCache};
pub use cone::{gather, ConeError, ConeSettings};
pub use inject::{inject, Injected};
pub use levels::{Chain, Level, Levels};
pub use reference::{path_trace, PathTracer, ReferenceError, ReferenceSettings};
pub use shade::{plan_volume, prepare_light, render_with_gi, GiCaches, GiReuse, GiSettings, GiStats, VolumeKey};
pub use sparse::{SparseLevels, SparseVolume};
pub use triangles::{TriangleScene, TriangleSceneError};
pub use volume::{Filter, GiError, Layout, SplatStats, Volume, VolumeSpec};
