//! Placing the car: `n` copies of its eight parts, each on a figure-eight of its own, on a
//! checkered ground sized to what the cars can reach. Shared by the CLI, the demo (which
//! re-stages when its car count changes) and the benchmark harness.

use super::animation::Rig;
use super::car::{add_car, clip_bounds, layout, pose_all, Car};
use super::{ground, Instance, Scene, Transform};
use crate::svo::Svo;
use glam::DVec3;
use std::sync::Arc;

/// A scene with the cars in it.
pub struct Staged {
    /// The scene (car parts first, then the ground part when there is one).
    pub scene: Scene,
    /// The cars' instances.
    pub cars: Vec<Car>,
    /// A box holding every car at any clip time (or the scene's bounds if the cars stay in place).
    pub bounds: (DVec3, DVec3),
    /// A scene file's node hierarchy and the clip it plays (None: nothing but the cars moves).
    pub animated: Option<Animated>,
}

/// A scene file's animation as staged: its rig (with the instances it made) and the clip
/// that plays, if any.
#[derive(Clone, Debug, Default)]
pub struct Animated {
    /// The node hierarchy.
    pub rig: Rig,
    /// Index into the rig's clips; None poses the rest pose.
    pub clip: Option<usize>,
}

/// Stages `n` cars built from `car_parts` (the eight parts in [`crate::model::car::PART_NAMES`]
/// order). `travel`: the cars drive their figure-eights (else they stay in place, wheels still
/// turning). `with_ground`: a 1 m checkered ground under everything the cars can reach.
pub fn stage_cars(car_parts: &[Arc<Svo>], n: usize, travel: bool, with_ground: bool) -> Result<Staged, crate::Error> {
    if car_parts.len() != 8 {
        return Err(crate::Error::CarParts { got: car_parts.len() });
    }
    let mut scene = Scene::new(car_parts.to_vec());
    let mut cars = Vec::with_capacity(n);
    for (origin, phase) in layout(n.max(1)) {
        cars.push(add_car(&mut scene, 0, origin, phase, travel)?);
    }
    scene.update()?;
    let bounds = if travel { clip_bounds(n.max(1)) } else { scene.bounds() };
    if with_ground {
        add_ground(&mut scene, bounds)?;
    }
    Ok(Staged { scene, cars, bounds, animated: None })
}

/// Adds a checkered ground (1 m tiles, voxels of at least 5 cm) reaching 3 m beyond `bounds`
/// as one more part and instance.
pub fn add_ground(scene: &mut Scene, bounds: (DVec3, DVec3)) -> Result<(), crate::Error> {
    let (lo, hi) = (bounds.0 - DVec3::splat(3.0), bounds.1 + DVec3::splat(3.0));
    scene.parts.push(Arc::new(ground::ground(lo, hi, 1.0, 0.05)?));
    let part = scene.parts.len() - 1;
    scene.add(Instance { part, parent: None, local: Transform::IDENTITY })?;
    scene.update()?;
    Ok(())
}

impl Staged {
    /// Poses everything that moves at scene time `t` (seconds): the cars and the scene file's
    /// clip. Call [`Scene::update`] afterwards.
    pub fn pose(&mut self, t: f64) -> Result<(), crate::Error> {
        pose_all(&mut self.scene, &self.cars, t)?;
        if let Some(a) = &self.animated {
            a.rig.pose(&mut self.scene, a.clip, t)?;
        }
        Ok(())
    }

    /// Whether anything moves over time.
    pub fn moves(&self) -> bool {
        !self.cars.is_empty() || self.animated.as_ref().is_some_and(|a| a.clip.is_some())
    }

    /// World bounds of the car instances only (not the ground); of everything if no cars.
    pub fn cars_bounds(&self) -> (DVec3, DVec3) {
        if self.cars.is_empty() {
            return self.scene.bounds();
        }
        self.scene.bounds_of(self.cars.iter().flat_map(|c| {
            [c.body, c.wheels[0], c.wheels[1], c.wheels[2], c.wheels[3], c.doors[0], c.doors[1], c.steering]
        }))
    }
}
