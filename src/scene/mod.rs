//! What is rendered: the camera and the lights (and, with animation, instances).

pub mod camera;
pub mod lights;

pub use camera::{Camera, CameraError};
pub use lights::{Lights, LightsError, Sun};
