//! Sparse voxel octrees: the node format, the builder and the `.svo` file format.

pub mod build;
pub mod cover;
pub mod emitter;
pub mod format;
pub mod io;
pub mod part_id;

pub use build::{build, BuildError};
pub use emitter::Emitter;
pub use format::{Attr, Cube, Occupied, Svo, SvoStats, MAX_DEPTH, MAX_EMISSION};
pub use io::SvoFileError;
pub use part_id::PartId;
