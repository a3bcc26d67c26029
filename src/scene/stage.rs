//! Placing the car: `n` copies of its eight parts, each on a figure-eight of its own, on a
//! checkered ground sized to what the cars can reach. Shared by the CLI, the demo (which
//! re-stages when its car count changes) and the benchmark harness.

use super::animation::Rig;
use super::car::{add_car, clip_bounds, layout, pose_all, reach_box, Car, SeenCars};
use super::instances::box_corners;
use super::sight::Sight;
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
    /// What [`Staged::pose_seen`] keeps between frames.
    seen: SeenCars,
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
    Ok(Staged::new(scene, cars, bounds, None))
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
    /// A staged scene from its parts.
    pub fn new(scene: Scene, cars: Vec<Car>, bounds: (DVec3, DVec3), animated: Option<Animated>) -> Staged {
        Staged { scene, cars, bounds, animated, seen: SeenCars::default() }
    }

    /// Poses everything that moves at scene time `t` (seconds): the cars and the scene file's
    /// clip. Call [`Scene::update`] afterwards.
    pub fn pose(&mut self, t: f64) -> Result<(), crate::Error> {
        pose_all(&mut self.scene, &self.cars, t)?;
        if let Some(a) = &self.animated {
            a.rig.pose(&mut self.scene, a.clip, t)?;
        }
        Ok(())
    }

    /// [`Staged::pose`] for the cars some ray of `sight` can reach in their new or their last
    /// pose ([`SeenCars::pose`]; None: every car); a scene file's clip is posed whole.
    /// Returns how many cars were posed. `max_level`: the frame's level of detail.
    pub fn pose_seen(&mut self, t: f64, sight: Option<&Sight>, max_level: u32) -> Result<usize, crate::Error> {
        let posed = self.seen.pose(&mut self.scene, &self.cars, t, sight, max_level)?;
        if let Some(a) = &self.animated {
            a.rig.pose(&mut self.scene, a.clip, t)?;
        }
        Ok(posed)
    }

    /// How many cars the last [`Staged::pose_seen`] tested against its sight
    /// ([`SeenCars::tested`]).
    pub fn cars_tested(&self) -> usize {
        self.seen.tested()
    }

    /// A box holding every surface a ray at level of detail `max_level` can see at any time
    /// of the clip: [`surfaces`] and [`Staged::bounds`].
    pub fn surfaces(&self, max_level: u32) -> Result<(DVec3, DVec3), crate::Error> {
        let (lo, hi) = surfaces(&self.scene, &self.cars, max_level)?;
        Ok((lo.min(self.bounds.0), hi.max(self.bounds.1)))
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
        self.scene.bounds_of(self.cars.iter().flat_map(|c| c.instances()))
    }
}

/// A box holding every surface a ray at level of detail `max_level` can see at any time of
/// the cars' clip: the cars wherever they drive ([`super::car::reach_box`]) and the other
/// instances' occupied cells as they are placed now (for a [`Sight`]).
pub fn surfaces(scene: &Scene, cars: &[Car], max_level: u32) -> Result<(DVec3, DVec3), crate::Error> {
    let mut of_car = vec![false; scene.instances().len()];
    for c in cars {
        for i in c.instances() {
            if let Some(slot) = of_car.get_mut(i) {
                *slot = true;
            }
        }
    }
    // The other instances' occupied cells at the level, not their cubes (the ground's cube is
    // as tall as it is wide).
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for i in (0..of_car.len()).filter(|&i| !of_car[i]) {
        let (a, b) = scene.parts[scene.instances()[i].part].occupied_box(max_level);
        for corner in box_corners(a, b) {
            let p = scene.world(i).transform_point3(corner);
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    let cars = reach_box(scene, cars, max_level)?;
    Ok((cars.0.min(lo), cars.1.max(hi)))
}
