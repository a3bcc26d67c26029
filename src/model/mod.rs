//! Procedural models shipped with voxray: the default car (`voxray model car` rewrites
//! `models/car/`), the coloured-wall box of the GI tests (`voxray model box`), the emissive-panel room (`voxray model panel-room`), plus OBJ/MTL
//! writing for generated meshes.

pub mod car;
pub mod embedded;
pub mod obj_writer;
pub mod panel_room;
pub mod room;
pub mod shapes;
