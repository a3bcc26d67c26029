//! Procedural models shipped with voxray: the default car (`voxray model car` rewrites
//! `models/car/`), the coloured-wall box of the GI tests (`voxray model box`), plus OBJ/MTL
//! writing for generated meshes.

pub mod car;
pub mod embedded;
pub mod obj_writer;
pub mod room;
pub mod shapes;
