//! The animated car: places the default car's eight parts as a hierarchy (wheels, doors and
//! steering wheel are children of the body) and poses them at time t.
//!
//! Motion is closed-form and deterministic in t: the body drives a figure-eight (a Gerono
//! lemniscate), the wheels roll by the arc length travelled (angle = distance / radius), the
//! front wheels steer by the path's curvature (bicycle model, δ = atan(wheelbase · κ)) and the
//! steering wheel turns with them (ratio 15), the doors open and close on their hinges. Time
//! and angles stay in f64 and are wrapped to one period before use, so a clip evaluated at
//! t = 10⁶ s looks like one in its first minute.

use super::instances::{box_corners, Instance, Scene, SceneError};
use super::sight::Sight;
use super::transform::Transform;
use crate::model::car::{rig, WHEELBASE, WHEEL_RADIUS};
use crate::svo::cover::covering_boxes;
use glam::{DAffine3, DQuat, DVec3};
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

impl Car {
    /// Its eight instances: body, four wheels, two doors, steering wheel.
    pub fn instances(&self) -> [usize; 8] {
        let (w, d) = (self.wheels, self.doors);
        [self.body, w[0], w[1], w[2], w[3], d[0], d[1], self.steering]
    }
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
    // One sine and cosine: those of 2s follow from them (posing 10 000 cars a frame).
    let (sin, cos) = s.sin_cos();
    let (sin2, cos2) = (2.0 * sin * cos, (cos - sin) * (cos + sin));
    let p = DVec3::new(PATH_A * sin, 0.0, 0.5 * PATH_A * sin2);
    let v = DVec3::new(PATH_A * cos, 0.0, PATH_A * cos2) * w;
    let a = DVec3::new(-PATH_A * sin, 0.0, -2.0 * PATH_A * sin2) * (w * w);
    (p, v, a)
}

/// `x` wrapped into [0, period): `rem_euclid` without its software `fmod`, which was a tenth
/// of posing a crowd. Exact for the clip's magnitudes (t below 10⁹ s loses under 10⁻⁶ s).
pub(crate) fn wrap(x: f64, period: f64) -> f64 {
    let r = x - (x / period).floor() * period;
    if r >= period || r < 0.0 {
        0.0
    } else {
        r
    }
}

/// The rotation about +y that turns +x towards the horizontal direction of `v` (yaw
/// atan2(−v.z, v.x)), from the direction's cosine and sine by the half-angle formulas
/// instead of an arctangent and a sine and cosine of it.
fn heading(v: DVec3) -> DQuat {
    // (The path's speeds are far from overflow: no need of `hypot`, a library call.)
    let len = (v.x * v.x + v.z * v.z).sqrt();
    if !(len > 0.0) {
        return DQuat::IDENTITY;
    }
    let (c, s) = (v.x / len, -v.z / len);
    // Yaw lies in (−π, π], so its half's cosine is never negative; each branch divides by
    // the larger of the half's sine and cosine.
    let (half_sin, half_cos) = if c >= 0.0 {
        let hc = (0.5 * (1.0 + c)).sqrt();
        (s / (2.0 * hc), hc)
    } else {
        let hs = (0.5 * (1.0 - c)).sqrt().copysign(s);
        (hs, s / (2.0 * hs))
    };
    DQuat::from_xyzw(0.0, half_sin, 0.0, half_cos)
}

/// A rotation about the line through `pivot` along unit `axis`, given the sine and cosine of
/// half its angle (as [`Transform::about_pivot`], whose sine and cosine the two doors share).
fn about_pivot_half(pivot: DVec3, axis: DVec3, half_sin: f64, half_cos: f64) -> Transform {
    let v = axis * half_sin;
    let rotation = DQuat::from_xyzw(v.x, v.y, v.z, half_cos);
    Transform { translation: pivot - rotation * pivot, rotation, scale: DVec3::ONE }
}

/// |dp/ds|: the path's speed per unit of its parameter.
fn speed(s: f64) -> f64 {
    path(s).1.length() / (TAU / PATH_PERIOD)
}

/// Intervals of the arc-length table over one lap.
pub(crate) const ARC_STEPS: usize = 1024;

/// Arc length and speed at `ARC_STEPS + 1` parameters evenly spread over [0, 2π]: Simpson's
/// rule on 16 steps per interval, summed once per process, so posing a car costs a table
/// lookup instead of an integral (it was most of a 10 000-car frame).
pub(crate) fn arc_table() -> &'static [(f64, f64)] {
    static TABLE: std::sync::OnceLock<Vec<(f64, f64)>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let h = TAU / ARC_STEPS as f64;
        let mut out = Vec::with_capacity(ARC_STEPS + 1);
        let mut length = 0.0;
        for k in 0..=ARC_STEPS {
            let s = k as f64 * h;
            out.push((length, speed(s)));
            const SUB: usize = 16; // even
            let q = h / SUB as f64;
            let mut sum = speed(s) + speed(s + h);
            for j in 1..SUB {
                sum += speed(s + j as f64 * q) * if j % 2 == 1 { 4.0 } else { 2.0 };
            }
            length += sum * q / 3.0;
        }
        out
    })
}

/// Arc length along the path from parameter 0 to `s` in [0, 2π]: cubic Hermite between the
/// table's lengths, with the speeds as slopes (error ~h⁴, far below a micrometre), a smooth
/// deterministic function of s.
fn arc_length(s: f64) -> f64 {
    let table = arc_table();
    let h = TAU / ARC_STEPS as f64;
    let k = ((s / h).floor().max(0.0) as usize).min(ARC_STEPS - 1);
    let u = (s - k as f64 * h) / h;
    let ((l0, v0), (l1, v1)) = (table[k], table[k + 1]);
    let (u2, u3) = (u * u, u * u * u);
    (2.0 * u3 - 3.0 * u2 + 1.0) * l0 + (u3 - 2.0 * u2 + u) * h * v0 + (3.0 * u2 - 2.0 * u3) * l1 + (u3 - u2) * h * v1
}

/// Length of one lap.
pub fn lap_length() -> f64 {
    arc_table()[ARC_STEPS].0
}

/// Door angle over its cycle: closed, opening, open, closing, closed.
fn door_angle(t: f64) -> f64 {
    let u = wrap(t, DOOR_PERIOD) / DOOR_PERIOD;
    let ramp = |a: f64, b: f64| ((u - a) / (b - a)).clamp(0.0, 1.0);
    let smooth = |x: f64| x * x * (3.0 - 2.0 * x);
    DOOR_OPEN * (smooth(ramp(0.25, 0.4)) - smooth(ramp(0.7, 0.85)))
}

/// The whole laps driven by time t and the path parameter within the lap: time is wrapped to
/// one lap before angles are formed (f64 keeps t = 10⁶ s exact to ~1e-10 s).
fn lap_and_parameter(t: f64) -> (f64, f64) {
    let laps = (t / PATH_PERIOD).floor();
    (laps, (t - laps * PATH_PERIOD) * TAU / PATH_PERIOD)
}

/// The body's local transform (identity unless `travel`), the steering angle and the
/// distance driven at time t.
pub fn drive_state(t: f64, travel: bool) -> (Transform, f64, f64) {
    let (laps, s) = lap_and_parameter(t);
    let (p, v, a) = path(s);
    let curvature = (a.x * v.z - v.x * a.z) / v.length().powi(3);
    let steer = (WHEELBASE as f64 * curvature).atan().clamp(-STEER_MAX, STEER_MAX);
    let distance = laps * lap_length() + arc_length(s);
    if !travel {
        return (Transform::IDENTITY, steer, distance);
    }
    let body = Transform { translation: p, rotation: heading(v), scale: DVec3::ONE };
    (body, steer, distance)
}

/// The local transforms of a car's eight instances at time t: body, four wheels, two doors,
/// steering wheel.
pub fn car_pose(car: &Car, t: f64) -> [(usize, Transform); 8] {
    let t = t + car.phase;
    let (mut body, steer, distance) = drive_state(t, car.travel);
    body.translation += car.origin;
    let r = rig();
    let radius = WHEEL_RADIUS as f64;
    // Rolling forward (+x) turns the wheel about −z; wrap the angle before it leaves f64.
    let spin = -(wrap(distance, TAU * radius) / radius);
    // One sine and cosine per angle, shared by the wheels (spin, steer) and the doors.
    let (ss, cs) = (0.5 * spin).sin_cos();
    let steer_q = DQuat::from_rotation_y(steer);
    let wheel = |k: usize| {
        let (pivot, axle) = (r[k + 1].0.as_dvec3(), r[k + 1].1.as_dvec3());
        let v = axle * ss; // as DQuat::from_axis_angle(axle, spin) computes it
        let mut q = DQuat::from_xyzw(v.x, v.y, v.z, cs);
        if k < 2 {
            q = steer_q * q;
        }
        (car.wheels[k], Transform { translation: pivot - q * pivot, rotation: q, scale: DVec3::ONE })
    };
    let (door_s, door_c) = (0.5 * door_angle(t)).sin_cos();
    let door = |k: usize| {
        let (pivot, axis) = (r[k + 5].0.as_dvec3(), r[k + 5].1.as_dvec3());
        (car.doors[k], about_pivot_half(pivot, axis.normalize(), door_s, door_c))
    };
    // Seen from the driver (looking along the column axis), a left turn is counter-clockwise.
    let (pivot, axis) = (r[7].0.as_dvec3(), r[7].1.as_dvec3());
    let steering = (car.steering, Transform::about_pivot(pivot, axis, -steer * STEERING_RATIO));
    [(car.body, body), wheel(0), wheel(1), wheel(2), wheel(3), door(0), door(1), steering]
}

/// Poses a car at time t.
pub fn pose(scene: &mut Scene, car: &Car, t: f64) -> Result<(), SceneError> {
    scene.set_locals(&car_pose(car, t))
}

/// Poses many cars at time t, computing their transforms in parallel (when enabled).
pub fn pose_all(scene: &mut Scene, cars: &[Car], t: f64) -> Result<(), SceneError> {
    scene.set_locals_from(cars.len(), |k| car_pose(&cars[k], t))
}

/// The radius of a sphere about a car's body origin that holds its eight parts' occupied
/// cells at `max_level` (what rays at that level of detail can hit) in every pose: each
/// child turns about its pivot, so its points stay within |pivot| + (their farthest
/// distance from the pivot) of the body's origin. Refused when one of its instances or their
/// parts is missing.
pub fn car_radius(scene: &Scene, car: &Car, max_level: u32) -> Result<f64, SceneError> {
    let r = rig();
    let ids = car.instances();
    let mut radius: f64 = 0.0;
    for (k, &i) in ids.iter().enumerate() {
        let inst = scene.instances().get(i).ok_or(SceneError::Instance(i))?;
        let part = scene.parts.get(inst.part).ok_or(SceneError::Part(inst.part))?;
        let (lo, hi) = part.occupied_box(max_level);
        // The body does not turn relative to itself: its pivot is its origin.
        let pivot = if k == 0 { DVec3::ZERO } else { r[k].0.as_dvec3() };
        let far = box_corners(lo, hi).iter().map(|c| (*c - pivot).length()).fold(0.0, f64::max);
        radius = radius.max(pivot.length() + far);
    }
    Ok(radius)
}

/// A box in a car's body frame that holds its eight parts' occupied cells at `max_level` in
/// every pose: the box around [`car_part_boxes`]. A sphere about every pivot ([`car_radius`])
/// is far looser: a door's hinge stands on the ground. Refused when one of its instances or
/// their parts is missing.
pub fn car_box(scene: &Scene, car: &Car, max_level: u32) -> Result<(DVec3, DVec3), SceneError> {
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for (a, b) in car_part_boxes(scene, car, max_level)? {
        (lo, hi) = (lo.min(a), hi.max(b));
    }
    Ok((lo, hi))
}

/// Boxes in a car's body frame that hold each of its eight parts' occupied cells at
/// `max_level` in every pose, in the order of [`Car::instances`]: the body's own box, and for
/// each child the box around the cylinder its cells sweep turning about their axis through
/// its pivot, as [`car_pose`] turns them (the front wheels' spinning cylinder swept again
/// about the vertical, for the steering). Refused when one of its instances or their parts
/// is missing.
pub fn car_part_boxes(scene: &Scene, car: &Car, max_level: u32) -> Result<[(DVec3, DVec3); 8], SceneError> {
    let r = rig();
    let mut out = [(DVec3::ZERO, DVec3::ZERO); 8];
    for (k, &i) in car.instances().iter().enumerate() {
        let inst = scene.instances().get(i).ok_or(SceneError::Instance(i))?;
        let part = scene.parts.get(inst.part).ok_or(SceneError::Part(inst.part))?;
        let (mut a, mut b) = part.occupied_box(max_level);
        if k > 0 {
            let (pivot, axis) = (r[k].0.as_dvec3(), r[k].1.as_dvec3().normalize());
            // Each part over the angles it turns through ([`car_pose`]): a wheel spins all the
            // way round its axle, the front wheels (wheels 0 and 1) also steer about the
            // vertical within ±STEER_MAX, a door swings between shut and DOOR_OPEN, and the
            // steering wheel turns more than once each way.
            let (from, to) = match k {
                5 | 6 => (0.0f64.min(DOOR_OPEN), 0.0f64.max(DOOR_OPEN)),
                _ => (0.0, TAU),
            };
            (a, b) = swept_through(a, b, pivot, axis, from, to);
            if k == 1 || k == 2 {
                (a, b) = swept_through(a, b, pivot, DVec3::Y, -STEER_MAX, STEER_MAX);
            }
        }
        out[k] = (a, b);
    }
    Ok(out)
}

/// Boxes covering a car body's occupied cells ([`car_outline`]): two (the cabin and what
/// lies below it) posed 8 % fewer cars of the 10 000-car crowd than one, and frames took
/// 3–5 % less time; three and more posed fewer still but took longer to test
/// (docs/benchmarks.md, step 85).
const BODY_BOXES: usize = 2;

/// The level whose occupied cells [`car_outline`] covers the body with (capped at the
/// frame's level): cells of 3.5 cm on the default car, a fortieth of its length. Level 8
/// posed the same cars, and took four times as long to cover (13 ms).
const COVER_LEVEL: u32 = 7;

/// The boxes in a car's body frame a ray must meet to reach the car at `max_level`: the
/// body's occupied cells covered by two boxes ([`covering_boxes`]) and each other part's box
/// ([`car_part_boxes`]), those not inside another. The other parts turn through wide angles
/// (a wheel all the way round), so their own covering boxes, swept, would each fill most of
/// the part's box.
pub fn car_outline(scene: &Scene, car: &Car, max_level: u32) -> Result<Vec<(DVec3, DVec3)>, SceneError> {
    let mut boxes = car_part_boxes(scene, car, max_level)?.to_vec();
    let inst = scene.instances().get(car.body).ok_or(SceneError::Instance(car.body))?;
    let body = scene.parts.get(inst.part).ok_or(SceneError::Part(inst.part))?;
    boxes.splice(0..1, covering_boxes(body, max_level.min(COVER_LEVEL), BODY_BOXES));
    Ok(outermost(&boxes))
}

/// Of `boxes`, those not inside another (the first of equal ones kept): a set of boxes
/// holding the same points, fewer to test.
fn outermost(boxes: &[(DVec3, DVec3)]) -> Vec<(DVec3, DVec3)> {
    let inside = |(a, b): (DVec3, DVec3), (lo, hi): (DVec3, DVec3)| lo.cmple(a).all() && b.cmple(hi).all();
    boxes
        .iter()
        .enumerate()
        .filter(|&(i, &x)| !boxes.iter().enumerate().any(|(j, &y)| j != i && inside(x, y) && (!inside(y, x) || j < i)))
        .map(|(_, &x)| x)
        .collect()
}

/// The box around the box `lo..hi` turned about the unit `axis` through `pivot` by every
/// angle from `from` to `to` (radians, right-handed, as a quaternion about the axis turns):
/// the box of its corners' arcs, which holds every turned box (a turned box is the hull of
/// its turned corners). Each coordinate of a corner's arc is h + A·cos θ + B·sin θ, whose
/// extremes lie at the range's ends or where θ is the phase of (A, B), or half a turn from
/// it, inside the range; over a whole turn or more they are h ± √(A² + B²).
fn swept_through(lo: DVec3, hi: DVec3, pivot: DVec3, axis: DVec3, from: f64, to: f64) -> (DVec3, DVec3) {
    let (mut out_lo, mut out_hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    let mut reach = 0.0f64;
    for c in box_corners(lo, hi) {
        let v = c - pivot;
        let along = axis * v.dot(axis);
        let (u, w) = (v - along, axis.cross(v - along));
        reach = reach.max(v.length());
        if !(to - from < TAU) {
            let radius = (u * u + w * w).map(f64::sqrt);
            (out_lo, out_hi) = (out_lo.min(pivot + along - radius), out_hi.max(pivot + along + radius));
            continue;
        }
        let mut angles = vec![from, to];
        for i in 0..3 {
            let phase = w[i].atan2(u[i]);
            // The phase's half turns inside the range, wherever the range lies.
            let first = ((from - phase) / PI).floor() as i64;
            for k in first..=first + 3 {
                let theta = phase + k as f64 * PI;
                if from < theta && theta < to {
                    angles.push(theta);
                }
            }
        }
        for theta in angles {
            let p = pivot + along + u * theta.cos() + w * theta.sin();
            (out_lo, out_hi) = (out_lo.min(p), out_hi.max(p));
        }
    }
    // The rounding of the sines and of the sums, far below the renderer's padding, is
    // covered here all the same.
    let pad = DVec3::splat(1e-9 * (reach + pivot.abs().max_element()));
    (out_lo - pad, out_hi + pad)
}

/// [`car_box`] of every car, computed once per distinct set of parts.
pub fn car_boxes(scene: &Scene, cars: &[Car], max_level: u32) -> Result<Vec<(DVec3, DVec3)>, SceneError> {
    per_parts(scene, cars, |car| car_box(scene, car, max_level))
}

/// `of(car)` for every car, computed once per set of parts the cars share (a bound that
/// depends only on the parts).
fn per_parts<T: Copy>(
    scene: &Scene,
    cars: &[Car],
    of: impl Fn(&Car) -> Result<T, SceneError>,
) -> Result<Vec<T>, SceneError> {
    let (values, index) = shared_per_parts(scene, cars, of)?;
    Ok(index.into_iter().map(|k| values[k as usize]).collect())
}

/// `of(car)` once per set of parts the cars share, and for every car the index of its value.
fn shared_per_parts<T>(
    scene: &Scene,
    cars: &[Car],
    of: impl Fn(&Car) -> Result<T, SceneError>,
) -> Result<(Vec<T>, Vec<u32>), SceneError> {
    let (mut keys, mut values) = (Vec::<[usize; 8]>::new(), Vec::new());
    let mut index = Vec::with_capacity(cars.len());
    for car in cars {
        let key = car_parts(scene, car).ok_or(SceneError::Instance(car.body))?;
        let k = match keys.iter().position(|k| *k == key) {
            Some(k) => k,
            None => {
                values.push(of(car)?);
                keys.push(key);
                keys.len() - 1
            }
        };
        // (At most one set of parts per car: fewer than 2³² cars fit in memory's instances.)
        index.push(k as u32);
    }
    Ok((values, index))
}

/// A bound on the speed of a driving car's body origin: |dp/dt|² = A²w²(cos² s + cos² 2s)
/// ≤ 2A²w² along the figure-eight ([`path`]).
fn max_speed() -> f64 {
    std::f64::consts::SQRT_2 * PATH_A * TAU / PATH_PERIOD
}

/// A bound on a driving car's yaw rate |dθ/dt|: along the figure-eight it is
/// w·|2 cos s sin 2s − cos 2s sin s| / (cos² s + cos² 2s), whose numerator changes by at most
/// 3 per unit of s and denominator (at least 0.4375) by at most 3. Over 4096 pieces of a
/// lap, each piece's value at its middle, numerator raised and denominator lowered by what
/// half a piece can change them: about 0.84 rad/s, where the plain bound 3w/0.4375 is 1.8.
fn max_yaw_rate() -> f64 {
    const PIECES: usize = 4096;
    let (w, half) = (TAU / PATH_PERIOD, PI / PIECES as f64);
    (0..PIECES)
        .map(|k| {
            let s = (2 * k + 1) as f64 * half;
            let num = (2.0 * s.cos() * (2.0 * s).sin() - (2.0 * s).cos() * s.sin()).abs() + 3.0 * half;
            let den = s.cos().powi(2) + (2.0 * s).cos().powi(2) - 3.0 * half;
            w * num / den
        })
        .fold(0.0, f64::max)
}

/// How far a box (`lo..hi` in a car's body frame) reaches from the vertical axis through the
/// body's origin, about which the body turns.
fn axis_reach(lo: DVec3, hi: DVec3) -> f64 {
    (lo.x.abs().max(hi.x.abs()).powi(2) + lo.z.abs().max(hi.z.abs()).powi(2)).sqrt()
}

/// How fast any point of a car's box can move while it drives: its origin's speed plus the
/// yaw rate (bounded by `yaw_rate`) times the box's [`axis_reach`] `reach`. 0 for a parked car.
fn box_speed(car: &Car, reach: f64, yaw_rate: f64) -> f64 {
    if !car.travel {
        return 0.0;
    }
    max_speed() + yaw_rate * reach
}

/// A car's body world transform at time t, as [`car_pose`] places its body (which has no
/// parent), without the rest of the pose.
pub fn body_world(car: &Car, t: f64) -> DAffine3 {
    if !car.travel {
        return DAffine3::from_translation(car.origin);
    }
    // As drive_state forms the body's place and heading.
    let (p, v, _) = path(lap_and_parameter(t + car.phase).1);
    Transform { translation: p + car.origin, rotation: heading(v), scale: DVec3::ONE }.to_affine()
}

/// The parts of a car's eight instances (None: an instance is missing).
fn car_parts(scene: &Scene, car: &Car) -> Option<[usize; 8]> {
    let inst = scene.instances();
    let ids = car.instances();
    let mut out = [0; 8];
    for (o, i) in out.iter_mut().zip(ids) {
        *o = inst.get(i)?.part;
    }
    Some(out)
}

/// [`car_radius`] of each car, computed once per set of parts the cars share.
pub fn car_radii(scene: &Scene, cars: &[Car], max_level: u32) -> Result<Vec<f64>, SceneError> {
    per_parts(scene, cars, |car| car_radius(scene, car, max_level))
}

/// A box holding every car at every time of its clip, as far as rays at `max_level` can
/// hit it: each body origin's figure-eight grown by [`car_radius`].
pub fn reach_box(scene: &Scene, cars: &[Car], max_level: u32) -> Result<(DVec3, DVec3), SceneError> {
    let radii = car_radii(scene, cars, max_level)?;
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for (car, r) in cars.iter().zip(radii) {
        let path = if car.travel { DVec3::new(PATH_A, 0.0, 0.5 * PATH_A) } else { DVec3::ZERO };
        lo = lo.min(car.origin - path - DVec3::splat(r));
        hi = hi.max(car.origin + path + DVec3::splat(r));
    }
    Ok((lo, hi))
}

/// Posing only the cars a frame's rays can reach, with what it keeps between frames: the
/// cars' boxes ([`car_box`]), outlines ([`car_outline`]) and radii ([`car_radius`]) at a
/// level of detail, and per car the
/// last placement of its body tested under the last frame's [`Sight`] and the answer (so a
/// car that stays where it was is not tested again while the sight stays the same), and
/// the times over which the car cannot come near any ray (or, found in sight, over which it
/// is posed again without a test).
#[derive(Clone, Debug, Default)]
pub struct SeenCars {
    /// Part edits, level, car count and the parts' addresses the boxes are for.
    boxes_for: Option<(u64, u32, usize, Vec<usize>)>,
    /// Per car, its [`car_box`], [`car_radius`], the box's [`axis_reach`] and which of
    /// `shapes` is its outline.
    boxes: Vec<(DVec3, DVec3, f64, f64, u32)>,
    /// Per set of parts the cars share, its [`car_outline`]: a car whose [`car_box`] a ray
    /// meets may still be clear of every box of it (two cars in five of the far crowd's).
    shapes: Vec<Vec<(DVec3, DVec3)>>,
    /// [`max_yaw_rate`], once.
    yaw_rate: f64,
    sight: Option<Sight>,
    /// The scene the sight's knowledge is of ([`Scene::id`]).
    scene: Option<u64>,
    known: Vec<Known>,
    /// Per car, the body placement last tested (read only when the body moved since).
    placed: Vec<DAffine3>,
    /// Cars tested against the sight by the last [`SeenCars::pose`].
    tested: usize,
}

/// What is known of one car under the last sight, read for every car every frame (kept
/// small: the crowd's frame streams ten thousand of these).
#[derive(Clone, Copy, Debug)]
struct Known {
    /// Times at which the car, wherever it drives then, is reached by no ray (empty when
    /// not known); for a car `seen`, the times over which it is posed untested...
    clear: (f64, f64),
    /// ...for the car driving as it did then: its origin, phase and whether it travels.
    motion: (DVec3, f64, bool),
    /// The scene update ([`Scene::epoch`]) as of which the body's world transform was the
    /// placement last tested (0: not known to be): while the body's [`Scene::stamp`] is no
    /// later, the two are not compared again.
    placed_at: u64,
    /// Whether a ray can reach the car placed as last tested.
    seen: bool,
}

impl Known {
    const NONE: Known = Known {
        clear: (f64::INFINITY, f64::NEG_INFINITY),
        motion: (DVec3::ZERO, 0.0, false),
        placed_at: 0,
        seen: false,
    };
}

/// A placement no body has: nothing is known of a car placed so.
const NOWHERE: DAffine3 =
    DAffine3 { matrix3: glam::DMat3::IDENTITY, translation: DVec3::new(f64::NAN, f64::NAN, f64::NAN) };

/// Longest stretch of time a car is let go untested after a test found it clear of the
/// rays (s): the room it is tested for is its speed times this.
const CLEAR_FOR: f64 = 0.1;

/// How long a car found in sight is posed again without a test (s): posing a car no ray
/// reaches changes no pixel, and a test costs a fifth of posing one. Of 0.05, 0.1 and 0.2 s,
/// 0.1 s tested the fewest cars for the fewest posed (docs/benchmarks.md, step 68).
const SEEN_FOR: f64 = 0.1;

impl SeenCars {
    /// How many cars the last [`SeenCars::pose`] tested against its sight (every car when
    /// it had none); the others were known clear of the rays where they stood and drove.
    pub fn tested(&self) -> usize {
        self.tested
    }

    /// Poses at time t only the cars that some ray of the frame `sight` describes can reach,
    /// in their new pose or in the one they were last given (None: every car), and returns
    /// how many were posed. A car left out is not reached in either pose, so the frame's
    /// picture is the one [`pose_all`] would give; it is posed again in the first frame that
    /// can see it. `max_level`: the frame's level of detail.
    pub fn pose(
        &mut self,
        scene: &mut Scene,
        cars: &[Car],
        t: f64,
        sight: Option<&Sight>,
        max_level: u32,
    ) -> Result<usize, SceneError> {
        let Some(sight) = sight else {
            self.tested = cars.len();
            pose_all(scene, cars, t)?;
            self.sight = None;
            return Ok(cars.len());
        };
        let parts = scene.parts.iter().map(|p| std::sync::Arc::as_ptr(p) as usize).collect();
        let key = Some((scene.part_edits(), max_level, cars.len(), parts));
        if self.boxes_for != key {
            let radii = car_radii(scene, cars, max_level)?;
            self.yaw_rate = max_yaw_rate();
            let (shapes, shape) = shared_per_parts(scene, cars, |car| car_outline(scene, car, max_level))?;
            self.boxes = car_boxes(scene, cars, max_level)?
                .into_iter()
                .zip(radii)
                .zip(shape)
                .map(|(((lo, hi), r), k)| (lo, hi, r, axis_reach(lo, hi), k))
                .collect();
            self.shapes = shapes;
            self.boxes_for = key;
            self.sight = None;
        }
        if self.sight.as_ref() != Some(sight) || self.scene != Some(scene.id()) {
            // Nothing known holds under another sight, or of another scene.
            self.known.clear();
            self.known.resize(cars.len(), Known::NONE);
            self.placed.clear();
            self.placed.resize(cars.len(), NOWHERE);
            self.sight = Some(sight.clone());
            self.scene = Some(scene.id());
        }
        let (scene_ref, boxes, shapes, yaw_rate) = (&*scene, &self.boxes, &self.shapes, self.yaw_rate);
        let epoch = scene.epoch();
        // Whether car k is posed, and whether it was tested.
        let seen = |k: usize, (known, placed): (&mut Known, &mut DAffine3)| -> (bool, bool) {
            let car = &cars[k];
            // A missing body: posing reports it.
            if car.body >= scene_ref.worlds().len() {
                return (true, false);
            }
            let motion = (car.origin, car.phase, car.travel);
            let within = known.motion == motion && known.clear.0 <= t && t <= known.clear.1;
            // Still placed where it was found clear (its body unmoved since that was known, or
            // moved back there), and clear wherever it drives now.
            if within && !known.seen {
                if scene_ref.stamp(car.body) <= known.placed_at {
                    return (false, false);
                }
                if *placed == scene_ref.world(car.body) {
                    known.placed_at = epoch;
                    return (false, false);
                }
            }
            // Found in sight a moment ago: posed again untested (posing a car no ray reaches
            // changes no pixel).
            if within && known.seen {
                return (true, false);
            }
            let (lo, hi, r, reach, shape) = boxes[k];
            let parts = &shapes[shape as usize];
            // (Of the car as it drives now: whether it travels is not part of the boxes' key.)
            let speed = box_speed(car, reach, yaw_rate);
            let (old, new) = (scene_ref.world(car.body), body_world(car, t));
            // The car's box, then its outline for the rays that come near the box.
            let Some(room) = sight.boxes_slack(&new, (lo, hi), parts, r, speed * CLEAR_FOR) else {
                // Posed: its body stands elsewhere after the next update.
                *placed = new;
                *known = Known { clear: (t - SEEN_FOR, t + SEEN_FOR), motion, placed_at: 0, seen: true };
                return (true, true);
            };
            // Its points cover the room in no less than room / speed (a parked car, never).
            let clear = match room / speed {
                _ if speed == 0.0 => (f64::NEG_INFINITY, f64::INFINITY),
                d if d > 0.0 => (t - d, t + d),
                _ => Known::NONE.clear,
            };
            // Where the car was last tested, under this sight: the same answer.
            let old_seen = if *placed == old { known.seen } else { sight.reaches_boxes(&old, (lo, hi), parts, r) };
            // Posed (its old place is seen) it stands where it was found clear after the next
            // update; else it stays where it is now.
            *placed = if old_seen { new } else { old };
            *known = Known { clear, motion, placed_at: if old_seen { 0 } else { epoch }, seen: false };
            (old_seen, true)
        };
        // Per car: posed, tested.
        let each = |(mut list, tested): (Vec<usize>, usize), (k, known): (usize, (&mut Known, &mut DAffine3))| {
            let (posed, was_tested) = seen(k, known);
            if posed {
                list.push(k);
            }
            (list, tested + was_tested as usize)
        };
        #[cfg(feature = "parallel")]
        let (list, tested) = {
            use rayon::prelude::*;
            self.known
                .par_iter_mut()
                .zip(self.placed.par_iter_mut())
                .enumerate()
                .with_min_len(256)
                .fold(|| (Vec::new(), 0), each)
                .reduce(
                    || (Vec::new(), 0),
                    |(mut a, n), (b, m)| {
                        a.extend_from_slice(&b);
                        (a, n + m)
                    },
                )
        };
        #[cfg(not(feature = "parallel"))]
        let (list, tested) = self.known.iter_mut().zip(self.placed.iter_mut()).enumerate().fold((Vec::new(), 0), each);
        self.tested = tested;
        if let Err(e) = scene.set_locals_from(list.len(), |k| car_pose(&cars[list[k]], t)) {
            self.sight = None;
            return Err(e);
        }
        Ok(list.len())
    }
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

    /// The motion bounds hold and are near the truth: over a lap, the yaw rate found by
    /// differences stays below the bound and comes within 2 % of it, and no corner of a
    /// car-sized box moves faster than its box speed (the fastest at over 60 % of it: the
    /// fastest drive and the fastest turn come at different places).
    #[test]
    fn a_cars_box_moves_no_faster_than_its_bound() {
        let car = Car {
            body: 0,
            wheels: [1, 2, 3, 4],
            doors: [5, 6],
            steering: 7,
            origin: DVec3::new(5.0, 0.0, -3.0),
            phase: 1.3,
            travel: true,
        };
        let (lo, hi) = (DVec3::new(-2.2, -0.1, -1.9), DVec3::new(2.1, 1.5, 1.95));
        let yaw_rate = max_yaw_rate();
        let speed = box_speed(&car, axis_reach(lo, hi), yaw_rate);
        let dt = 1e-4;
        let (mut fastest_yaw, mut fastest) = (0.0f64, 0.0f64);
        for k in 0..24_000 {
            let t = k as f64 * PATH_PERIOD / 24_000.0;
            let (a, b) = (body_world(&car, t), body_world(&car, t + dt));
            let turn = (a.matrix3.transpose() * b.matrix3).x_axis;
            fastest_yaw = fastest_yaw.max(turn.z.atan2(turn.x).abs() / dt);
            for p in box_corners(lo, hi) {
                let moved = (b.transform_point3(p) - a.transform_point3(p)).length() / dt;
                assert!(moved <= speed, "t {t}: a corner moves at {moved} m/s, over the bound {speed}");
                fastest = fastest.max(moved);
            }
        }
        assert!(fastest_yaw <= yaw_rate && fastest_yaw > 0.98 * yaw_rate, "yaw rate {fastest_yaw} against {yaw_rate}");
        assert!(fastest > 0.6 * speed, "fastest corner {fastest} against the bound {speed}");
        assert_eq!(box_speed(&Car { travel: false, ..car }, axis_reach(lo, hi), yaw_rate), 0.0);
    }

    /// Of random boxes (some inside others, some equal), `outermost` keeps exactly those
    /// inside no other box, and one of each set of equal ones: every box kept or inside a
    /// kept one, no kept box inside another kept one.
    #[test]
    fn the_outermost_boxes_hold_all_and_none_holds_another() {
        let mut rng = crate::rng::Rng::new(11);
        let inside = |(a, b): (DVec3, DVec3), (lo, hi): (DVec3, DVec3)| lo.cmple(a).all() && b.cmple(hi).all();
        let mut dropped = 0;
        for case in 0..300 {
            let mut boxes: Vec<(DVec3, DVec3)> = Vec::new();
            for k in 0..1 + case % 8 {
                let r = |rng: &mut crate::rng::Rng| DVec3::new(rng.f64(), rng.f64(), rng.f64());
                let b = match (k, rng.f64()) {
                    (0, _) | (_, ..0.4) => {
                        let lo = r(&mut rng) * 4.0;
                        (lo, lo + r(&mut rng) * 3.0)
                    }
                    // Inside an earlier box, or equal to one.
                    (_, p) => {
                        let (lo, hi) = boxes[rng.below(boxes.len() as u64) as usize];
                        if p < 0.7 {
                            (lo, hi)
                        } else {
                            let (u, v) = (r(&mut rng), r(&mut rng));
                            (lo + (hi - lo) * u.min(v), lo + (hi - lo) * u.max(v))
                        }
                    }
                };
                boxes.push(b);
            }
            let kept = outermost(&boxes);
            for &b in &boxes {
                assert!(kept.iter().any(|&k| inside(b, k)), "case {case}: {b:?} is in no kept box");
            }
            for (i, &a) in kept.iter().enumerate() {
                assert!(boxes.contains(&a), "case {case}");
                for (j, &b) in kept.iter().enumerate() {
                    assert!(i == j || !inside(a, b), "case {case}: kept {a:?} is inside kept {b:?}");
                }
            }
            dropped += boxes.len() - kept.len();
        }
        assert!(dropped > 300, "only {dropped} boxes dropped");
    }

    /// A box turned through a range of angles stays inside `swept_through`'s box at every
    /// angle, and the box is no larger than the turned corners reach (random boxes, axes,
    /// pivots and ranges, a whole turn and more among them).
    #[test]
    fn a_box_turned_through_a_range_stays_in_its_swept_box() {
        let mut rng = crate::rng::Rng::new(7);
        let mut v = |s: f64| DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5) * s;
        for case in 0..200 {
            let (c, half, pivot) = (v(4.0), v(2.0).abs() + DVec3::splat(0.01), v(3.0));
            let axis = if case % 3 == 0 { DVec3::Y } else { (v(1.0) + DVec3::splat(1e-3)).normalize() };
            let (a, b) = (v(2.0 * TAU).x, v(2.0 * TAU).x);
            // Some ranges far from zero, some of more than a turn.
            let far = (case % 5) as f64 * 7.0 * TAU - 14.0 * TAU;
            let (from, to) = if case % 7 == 0 { (-4.0, 4.0) } else { (a.min(b) + far, a.max(b) + far) };
            let (lo, hi) = swept_through(c - half, c + half, pivot, axis, from, to);
            // The rounding of the turned points (the users of the box pad it far more).
            let (lo, hi) = (lo - DVec3::splat(1e-12), hi + DVec3::splat(1e-12));
            let (mut reach_lo, mut reach_hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
            for k in 0..=4000 {
                let angle = from + (to - from) * k as f64 / 4000.0;
                let turn = Transform::about_pivot(pivot, axis, angle).to_affine();
                for p in box_corners(c - half, c + half).map(|q| turn.transform_point3(q)) {
                    assert!(p.cmpge(lo).all() && p.cmple(hi).all(), "case {case}: {p} outside {lo}..{hi}");
                    (reach_lo, reach_hi) = (reach_lo.min(p), reach_hi.max(p));
                }
            }
            let loose = (reach_lo - lo).max(hi - reach_hi).max_element();
            assert!(loose < 1e-3 * (1.0 + pivot.length() + c.length()), "case {case}: {loose} too loose");
        }
    }

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

    /// The table's arc length against Simpson's rule on a fine grid over the whole range.
    #[test]
    fn tabulated_arc_length_matches_the_integral() {
        let direct = |s: f64| {
            let n = 20_000; // even
            let h = s / n as f64;
            let mut sum = speed(0.0) + speed(s);
            for k in 1..n {
                sum += speed(k as f64 * h) * if k % 2 == 1 { 4.0 } else { 2.0 };
            }
            sum * h / 3.0
        };
        for s in [0.0, 0.001, 0.7, 1.5, 3.0, 4.7, 6.0, TAU] {
            assert!((arc_length(s) - direct(s)).abs() < 1e-7, "s {s}: {} vs {}", arc_length(s), direct(s));
        }
        assert!((lap_length() - direct(TAU)).abs() < 1e-7);
    }

    /// The shortcuts of posing against the formulas they replace: the heading against the
    /// yaw's arctangent (every quadrant, the axes, ±π and −0), the wrap against `rem_euclid`,
    /// the path's double angles and the doors' shared half angle against their own.
    #[test]
    fn posing_shortcuts_match_the_direct_formulas() {
        let close = |a: DQuat, b: DQuat| (a.x - b.x).abs().max((a.y - b.y).abs()).max((a.w - b.w).abs()) < 1e-12;
        let mut dirs: Vec<DVec3> =
            (0..720).map(|k| k as f64 * TAU / 720.0).map(|y| DVec3::new(y.cos(), 0.3, -y.sin()) * 7.0).collect();
        dirs.extend([
            DVec3::X,
            -DVec3::X,
            DVec3::Z,
            -DVec3::Z,
            DVec3::new(-1.0, 0.0, -0.0),
            DVec3::new(-1.0, 0.0, 1e-300),
        ]);
        for v in dirs {
            let direct = DQuat::from_rotation_y((-v.z).atan2(v.x));
            // q and −q are the same rotation.
            assert!(close(heading(v), direct) || close(heading(v), -direct), "{v}: {:?} vs {direct:?}", heading(v));
            assert!((heading(v).length() - 1.0).abs() < 1e-12);
        }
        assert_eq!(heading(DVec3::Y), DQuat::IDENTITY);
        for x in [0.0, 1e-9, 3.7, 9.999_999, 10.0, 123.4, 1e6 + 0.25, -0.5, -10.0, -1e6 - 0.25] {
            let (a, b) = (wrap(x, DOOR_PERIOD), x.rem_euclid(DOOR_PERIOD));
            assert!((0.0..DOOR_PERIOD).contains(&a));
            assert!((a - b).abs() < 1e-9 || (a - b).abs() > DOOR_PERIOD - 1e-9, "{x}: {a} vs {b}");
        }
        for s in [0.0, 0.4, 1.9, 3.3, 5.0, 6.2] {
            let (p, v, a) = path(s);
            let w = TAU / PATH_PERIOD;
            assert!((p.z - 0.5 * PATH_A * (2.0 * s).sin()).abs() < 1e-12);
            assert!((v.z - PATH_A * (2.0 * s).cos() * w).abs() < 1e-12);
            assert!((a.z + 2.0 * PATH_A * (2.0 * s).sin() * w * w).abs() < 1e-12);
        }
        let r = rig();
        for t in [0.0, 3.0, 3.5, 4.1, 7.9] {
            let car = Car {
                body: 0,
                wheels: [1, 2, 3, 4],
                doors: [5, 6],
                steering: 7,
                origin: DVec3::ZERO,
                phase: 0.0,
                travel: true,
            };
            let pose = car_pose(&car, t);
            for k in 0..2 {
                let direct = Transform::about_pivot(r[k + 5].0.as_dvec3(), r[k + 5].1.as_dvec3(), door_angle(t));
                let got = pose[5 + k].1;
                assert!(close(got.rotation, direct.rotation), "t {t}: {got:?} vs {direct:?}");
                assert!((got.translation - direct.translation).length() < 1e-12);
            }
        }
    }

    #[test]
    fn doors_close_open_close() {
        assert_eq!(door_angle(0.0), 0.0);
        assert!((door_angle(5.5) - DOOR_OPEN).abs() < 1e-12);
        assert_eq!(door_angle(9.0), 0.0);
    }
}
