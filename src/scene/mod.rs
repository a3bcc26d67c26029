//! What is rendered: parts placed as instances with transforms, the camera and the lights.

pub mod animation;
pub mod camera;
pub mod car;
pub mod ground;
pub mod instances;
pub mod lights;
pub mod sight;
pub mod stage;
pub mod transform;

pub use camera::{Camera, CameraError};
pub use instances::{Instance, Scene, SceneError};
pub use lights::{Ambient, Lights, LightsError, Sun};
pub use sight::{FrameRays, Sight, Unbounded};
pub use stage::{add_ground, stage_cars, Animated, Staged};
pub use transform::{Transform, TransformError};
