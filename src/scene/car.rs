//! The animated car: places the default car's eight parts as a hierarchy (wheels, doors and
//! steering wheel are children of the body) and poses them at time t.
//!
//! Motion is closed-form and deterministic in t: the body drives a figure-eight (a Gerono
//! lemniscate), the wheels roll by the arc length travelled (angle = distance / radius), the
//! front wheels steer by the path's curvature (bicycle model, δ = atan(wheelbase · κ)) and the
//! steering wheel turns with them (ratio 15), the doors open and close on their hinges. Time
//! and angles stay in f64 and are wrapped to one period before use, so a clip evaluated at
//! t = 10⁶ s looks like one in its first minute.

use super::instances::{Instance, Scene, SceneError};
use super::transform::Transform;
use crate::model::car::{rig, WHEELBASE, WHEEL_RADIUS};
use glam::{DQuat, DVec3};
use std::f64::consts::{PI, TAU};

/// Figure-eight half-length (m).
pub const PATH_A: f64 = 9.0;
/// Seconds per lap of the figure-eight.
pub const PATH_PERIOD: f64 = 24.0;
/// Seconds per door open/close cycle.
pub const DOOR_PERIOD: f64 = 10.0;
/// Door opening angle.
pub const DOOR_OPEN: f64 = 70.0 * PI / 180.0;
/// Largest steering angle of the front wheels.
pub const STEER_MAX: f64 = 30.0 * PI / 180.0;
/// Steering wheel turns per wheel turn.
pub const STEERING_RATIO: f64 = 15.0;

/// The instances of one car in a scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Car {
    /// Body instance; the others are its children.
    pub body: usize,
    /// Wheel instances: front left, front right, rear left, rear right.
    pub wheels: [usize; 4],
    /// Door instances: left, right.
    pub doors: [usize; 2],
    /// Steering wheel instance.
    pub steering: usize,
    /// Where the figure-eight is centred.
    pub origin: DVec3,
    /// Time offset of this car's clip.
    pub phase: f64,
    /// Whether the body travels along the figure-eight (false: it stays at `origin` while its
    /// wheels, steering and doors move as if driving, like a car on rollers).
    pub travel: bool,
}

/// Adds a car whose eight parts are `scene.parts[first_part..first_part + 8]` in the order of
/// [`crate::model::car::PART_NAMES`], and poses it at t = 0.
pub fn add_car(
    scene: &mut Scene,
    first_part: usize,
    origin: DVec3,
    phase: f64,
    travel: bool,
) -> Result<Car, SceneError> {
    let mut add = |part: usize, parent: Option<usize>| {
        scene.add(Instance { part: first_part + part, parent, local: Transform::IDENTITY })
    };
    let body = add(0, None)?;
    let child = |k| (k, Some(body));
    let mut ids = [0usize; 7];
    for (j, k) in (1..8).enumerate() {
        let (part, parent) = child(k);
        ids[j] = add(part, parent)?;
    }
    let car = Car {
        body,
        wheels: [ids[0], ids[1], ids[2], ids[3]],
        doors: [ids[4], ids[5]],
        steering: ids[6],
        origin,
        phase,
        travel,
    };
    pose(scene, &car, 0.0)?;
    Ok(car)
}

/// Position on the figure-eight and its first and second derivatives at path parameter s.
fn path(s: f64) -> (DVec3, DVec3, DVec3) {
    let w = TAU / PATH_PERIOD;
    let p = DVec3::new(PATH_A * s.sin(), 0.0, 0.5 * PATH_A * (2.0 * s).sin());
    let v = DVec3::new(PATH_A * s.cos(), 0.0, PATH_A * (2.0 * s).cos()) * w;
    let a = DVec3::new(-PATH_A * s.sin(), 0.0, -2.0 * PATH_A * (2.0 * s).sin()) * (w * w);
    (p, v, a)
}

/// Arc length along the path from parameter 0 to `s` in [0, 2π] (Simpson's rule on a fixed
/// grid, so the result is a smooth deterministic function of s).
fn arc_length(s: f64) -> f64 {
    const N: usize = 512; // even
    let speed = |u: f64| path(u).1.length() / (TAU / PATH_PERIOD);
    let h = s / N as f64;
    let mut sum = speed(0.0) + speed(s);
    for k in 1..N {
        sum += speed(k as f64 * h) * if k % 2 == 1 { 4.0 } else { 2.0 };
    }
    sum * h / 3.0
}

/// Length of one lap (integrated once; every car asks for it every frame).
pub fn lap_length() -> f64 {
    static LAP: std::sync::OnceLock<f64> = std::sync::OnceLock::new();
    *LAP.get_or_init(|| arc_length(TAU))
}

/// Door angle over its cycle: closed, opening, open, closing, closed.
fn door_angle(t: f64) -> f64 {
    let u = t.rem_euclid(DOOR_PERIOD) / DOOR_PERIOD;
    let ramp = |a: f64, b: f64| ((u - a) / (b - a)).clamp(0.0, 1.0);
    let smooth = |x: f64| x * x * (3.0 - 2.0 * x);
    DOOR_OPEN * (smooth(ramp(0.25, 0.4)) - smooth(ramp(0.7, 0.85)))
}

/// The body's local transform (identity unless `travel`), the steering angle and the
/// distance driven at time t.
pub fn drive_state(t: f64, travel: bool) -> (Transform, f64, f64) {
    // Wrap time to one lap before forming angles (f64 keeps t = 10⁶ s exact to ~1e-10 s).
    let laps = (t / PATH_PERIOD).floor();
    let tm = t - laps * PATH_PERIOD;
    let s = tm * TAU / PATH_PERIOD;
    let (p, v, a) = path(s);
    let yaw = (-v.z).atan2(v.x);
    let curvature = (a.x * v.z - v.x * a.z) / v.length().powi(3);
    let steer = (WHEELBASE as f64 * curvature).atan().clamp(-STEER_MAX, STEER_MAX);
    let distance = laps * lap_length() + arc_length(s);
    if !travel {
        return (Transform::IDENTITY, steer, distance);
    }
    let body = Transform { translation: p, rotation: DQuat::from_rotation_y(yaw), scale: DVec3::ONE };
    (body, steer, distance)
}

/// Poses a car at time t.
pub fn pose(scene: &mut Scene, car: &Car, t: f64) -> Result<(), SceneError> {
    let t = t + car.phase;
    let (mut body, steer, distance) = drive_state(t, car.travel);
    body.translation += car.origin;
    scene.set_local(car.body, body)?;
    let r = rig();
    let radius = WHEEL_RADIUS as f64;
    // Rolling forward (+x) turns the wheel about −z; wrap the angle before it leaves f64.
    let spin = -(distance.rem_euclid(TAU * radius) / radius);
    for (k, &inst) in car.wheels.iter().enumerate() {
        let (pivot, axle) = (r[k + 1].0.as_dvec3(), r[k + 1].1.as_dvec3());
        let mut q = DQuat::from_axis_angle(axle, spin);
        if k < 2 {
            q = DQuat::from_rotation_y(steer) * q;
        }
        scene.set_local(inst, Transform { translation: pivot - q * pivot, rotation: q, scale: DVec3::ONE })?;
    }
    for (k, &inst) in car.doors.iter().enumerate() {
        let (pivot, axis) = (r[k + 5].0.as_dvec3(), r[k + 5].1.as_dvec3());
        scene.set_local(inst, Transform::about_pivot(pivot, axis, door_angle(t)))?;
    }
    // Seen from the driver (looking along the column axis), a left turn is counter-clockwise.
    let (pivot, axis) = (r[7].0.as_dvec3(), r[7].1.as_dvec3());
    scene.set_local(car.steering, Transform::about_pivot(pivot, axis, -steer * STEERING_RATIO))?;
    Ok(())
}

/// Where `n` cars go: a grid of figure-eights, each with its own time offset.
pub fn layout(n: usize) -> Vec<(DVec3, f64)> {
    let k = (n as f64).sqrt().ceil().max(1.0) as usize;
    (0..n)
        .map(|i| {
            let origin = DVec3::new((i % k) as f64 * 25.0, 0.0, (i / k) as f64 * 16.0);
            (origin, i as f64 * 2.37)
        })
        .collect()
}

/// A box containing every car of [`layout`]`(n)` at any time (for framing cameras).
pub fn clip_bounds(n: usize) -> (DVec3, DVec3) {
    let reach = DVec3::new(PATH_A + 2.6, 0.0, 0.5 * PATH_A + 2.6);
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for (o, _) in layout(n) {
        lo = lo.min(o - reach);
        hi = hi.max(o + reach + DVec3::Y * 1.5);
    }
    (lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wheels_roll_by_the_distance_driven() {
        // Over a short step the spin changes by Δdistance / r.
        let (_, _, d0) = drive_state(3.0, true);
        let (_, _, d1) = drive_state(3.01, true);
        let v = path(3.0 * TAU / PATH_PERIOD).1.length();
        assert!(((d1 - d0) - v * 0.01).abs() < 1e-4, "{} vs {}", d1 - d0, v * 0.01);
    }

    #[test]
    fn the_clip_repeats_each_lap_even_after_a_million_seconds() {
        let t0 = 5.25;
        let t1 = t0 + PATH_PERIOD * (1e6 / PATH_PERIOD).floor();
        let (b0, s0, d0) = drive_state(t0, true);
        let (b1, s1, d1) = drive_state(t1, true);
        assert!((b0.translation - b1.translation).length() < 1e-6);
        assert!((s0 - s1).abs() < 1e-9);
        // The wheel angle (distance modulo a turn) repeats only up to the lap/turn ratio, but
        // the distance itself is exact to f64 precision.
        assert!(((d1 - d0) - (t1 - t0) / PATH_PERIOD * lap_length()).abs() < 1e-6);
    }

    #[test]
    fn doors_close_open_close() {
        assert_eq!(door_angle(0.0), 0.0);
        assert!((door_angle(5.5) - DOOR_OPEN).abs() < 1e-12);
        assert_eq!(door_angle(9.0), 0.0);
    }
}
