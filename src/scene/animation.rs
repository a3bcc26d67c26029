//! Keyframed rigid animation of a node hierarchy: glTF 2.0's model of it (nodes with a rest
//! transform, channels that drive a node's translation, rotation or scale through STEP,
//! LINEAR or CUBICSPLINE samplers), evaluated into a [`Scene`]'s instance transforms.
//!
//! Only nodes that place a part become instances. A node without geometry (a group, an
//! animated empty) is folded into its descendants: an instance's local transform is the
//! product of its own and those of the geometry-less nodes between it and its nearest
//! instanced ancestor, which becomes its parent instance. Instances carry
//! translation · rotation · scale, so that product is decomposed again; a product with shear
//! (a non-uniformly scaled empty above a rotated child) cannot be carried and is refused with
//! the node's name rather than drawn wrong. Shear between two instanced nodes is no problem:
//! the scene composes parent and child worlds as full affine maps.

use super::instances::{Scene, SceneError};
use super::transform::Transform;
use glam::{DAffine3, DQuat, DVec3};

/// How a sampler fills the time between two keys.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    /// The earlier key's value until the next key.
    Step,
    /// Linear (spherical for rotations).
    Linear,
    /// Cubic Hermite spline with in- and out-tangents stored beside every key.
    CubicSpline,
}

/// Which property of a node a channel drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Property {
    /// Translation (x, y, z).
    Translation,
    /// Rotation quaternion (x, y, z, w).
    Rotation,
    /// Per-axis scale (x, y, z).
    Scale,
    /// Which part the node places (a flip-book: value x is an index into the rig's parts;
    /// always stepped).
    Part,
}

/// One animated property of one node.
#[derive(Clone, Debug, PartialEq)]
pub struct Channel {
    /// Index of the node in [`Rig::nodes`].
    pub node: usize,
    /// What it drives.
    pub property: Property,
    /// How keys are joined.
    pub interpolation: Interpolation,
    /// Key times in seconds, finite and strictly increasing.
    pub times: Vec<f64>,
    /// One value per key (xyz with w unused, or a quaternion xyzw); with
    /// [`Interpolation::CubicSpline`] three per key: in-tangent, value, out-tangent.
    pub values: Vec<[f64; 4]>,
}

/// Why a channel was refused.
#[derive(Clone, Debug, thiserror::Error, PartialEq)]
pub enum ChannelError {
    /// No keys.
    #[error("the sampler has no keys")]
    Empty,
    /// Key counts of input and output do not match.
    #[error("the sampler has {times} key times but {values} values (expected {expected})")]
    Count {
        /// Key times.
        times: usize,
        /// Values given.
        values: usize,
        /// Values expected.
        expected: usize,
    },
    /// A key time is NaN, infinite or not after the one before it.
    #[error("key time {index} ({time}) is not finite or not after the key before it")]
    Time {
        /// Key index.
        index: usize,
        /// The time.
        time: f64,
    },
    /// A value is NaN or infinite.
    #[error("value {index} is not finite")]
    Value {
        /// Value index.
        index: usize,
    },
}

impl Channel {
    /// Checks key times and values (finite, strictly increasing times, matching counts).
    pub fn validate(&self) -> Result<(), ChannelError> {
        if self.times.is_empty() {
            return Err(ChannelError::Empty);
        }
        let per_key = if self.interpolation == Interpolation::CubicSpline { 3 } else { 1 };
        let expected = self.times.len() * per_key;
        if self.values.len() != expected {
            return Err(ChannelError::Count { times: self.times.len(), values: self.values.len(), expected });
        }
        for (index, &time) in self.times.iter().enumerate() {
            let after = index == 0 || time > self.times[index - 1];
            if !time.is_finite() || !after {
                return Err(ChannelError::Time { index, time });
            }
        }
        if let Some(index) = self.values.iter().position(|v| v.iter().any(|c| !c.is_finite())) {
            return Err(ChannelError::Value { index });
        }
        Ok(())
    }

    fn value(&self, key: usize) -> [f64; 4] {
        match self.interpolation {
            Interpolation::CubicSpline => self.values[3 * key + 1],
            _ => self.values[key],
        }
    }

    /// The property's value at time `t` (seconds; before the first key: the first value,
    /// after the last: the last). Rotations come back normalized.
    pub fn sample(&self, t: f64) -> [f64; 4] {
        let n = self.times.len();
        let v = if n == 0 {
            [0.0, 0.0, 0.0, 1.0]
        } else if !(t > self.times[0]) {
            self.value(0)
        } else if t >= self.times[n - 1] {
            self.value(n - 1)
        } else {
            // The last key at or before t; t lies strictly inside [times[k], times[k + 1]).
            let k = self.times.partition_point(|&x| x <= t) - 1;
            let (t0, t1) = (self.times[k], self.times[k + 1]);
            let dt = t1 - t0;
            let u = (t - t0) / dt;
            match self.interpolation {
                _ if self.property == Property::Part => self.value(k),
                Interpolation::Step => self.value(k),
                Interpolation::Linear if self.property == Property::Rotation => {
                    let (a, b) = (DQuat::from_array(self.value(k)), DQuat::from_array(self.value(k + 1)));
                    a.normalize().slerp(b.normalize(), u).to_array()
                }
                Interpolation::Linear => {
                    let (a, b) = (self.value(k), self.value(k + 1));
                    [0, 1, 2, 3].map(|i| a[i] + (b[i] - a[i]) * u)
                }
                Interpolation::CubicSpline => {
                    // glTF's Hermite form: tangents are per second, so they scale by the interval.
                    let (p0, m0) = (self.values[3 * k + 1], self.values[3 * k + 2]);
                    let (p1, m1) = (self.values[3 * (k + 1) + 1], self.values[3 * (k + 1)]);
                    let (u2, u3) = (u * u, u * u * u);
                    let (h00, h10, h01, h11) =
                        (2.0 * u3 - 3.0 * u2 + 1.0, u3 - 2.0 * u2 + u, -2.0 * u3 + 3.0 * u2, u3 - u2);
                    [0, 1, 2, 3].map(|i| h00 * p0[i] + h10 * dt * m0[i] + h01 * p1[i] + h11 * dt * m1[i])
                }
            }
        };
        if self.property == Property::Rotation {
            let q = DQuat::from_array(v);
            let len = q.length();
            // A zero quaternion (possible between opposite cubic keys) reads as no rotation.
            return if len > 1e-12 { (q / len).to_array() } else { DQuat::IDENTITY.to_array() };
        }
        v
    }
}

/// A named set of channels played together.
#[derive(Clone, Debug, PartialEq)]
pub struct Clip {
    /// Name from the file (or "animation N").
    pub name: String,
    /// Its channels.
    pub channels: Vec<Channel>,
    /// The last key time of any channel; the clip loops with this period.
    pub duration: f64,
}

impl Clip {
    /// A clip over these channels; its duration is their last key time.
    pub fn new(name: String, channels: Vec<Channel>) -> Self {
        let duration = channels.iter().filter_map(|c| c.times.last().copied()).fold(0.0, f64::max);
        Clip { name, channels, duration }
    }

    /// Clip time of scene time `t`: looped over the duration (a clip of zero length stays at 0).
    pub fn local_time(&self, t: f64) -> f64 {
        if self.duration > 0.0 && t.is_finite() {
            t.rem_euclid(self.duration)
        } else {
            0.0
        }
    }
}

/// A node's rest transform.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Rest {
    /// Translation, rotation (xyzw, normalized) and scale.
    Trs(DVec3, DQuat, DVec3),
    /// A matrix (never targeted by a channel: glTF forbids animating matrix nodes).
    Matrix(DAffine3),
}

impl Rest {
    fn affine(&self) -> DAffine3 {
        match *self {
            Rest::Trs(t, r, s) => DAffine3::from_scale_rotation_translation(s, r, t),
            Rest::Matrix(m) => m,
        }
    }
}

/// One node of the hierarchy.
#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    /// Name from the file (or "node N").
    pub name: String,
    /// Parent node; parents come before their children in [`Rig::nodes`].
    pub parent: Option<usize>,
    /// Rest transform relative to the parent.
    pub rest: Rest,
    /// The part this node places, if any.
    pub part: Option<usize>,
}

/// Why a pose could not be applied.
#[derive(Debug, thiserror::Error)]
pub enum PoseError {
    /// The node's transform, folded with the geometry-less nodes above it, has shear.
    #[error(
        "node '{node}': its transform combined with the nodes without geometry above it has shear (a non-uniform scale above a rotation), which an instance cannot carry"
    )]
    Shear {
        /// Node name.
        node: String,
    },
    /// The scene refused a transform.
    #[error("node '{node}': {source}")]
    Scene {
        /// Node name.
        node: String,
        /// Why.
        source: SceneError,
    },
}

/// A node hierarchy, its animation clips, and which scene instance each placing node became.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Rig {
    /// Nodes, parents before children.
    pub nodes: Vec<Node>,
    /// Animation clips.
    pub clips: Vec<Clip>,
    /// Per node, its scene instance (set by [`Rig::instantiate`]).
    pub instances: Vec<Option<usize>>,
    /// Scene part index of the rig's part 0 (set by [`Rig::instantiate`]).
    pub first_part: usize,
}

/// Relative decomposition tolerance: products of f32 file data carry ~1e-7 of apparent shear.
const SHEAR_TOLERANCE: f64 = 1e-5;

/// `m` as translation · rotation · scale, or None when it has shear (or is singular).
pub fn decompose(m: &DAffine3) -> Option<Transform> {
    let (s, r, t) = m.to_scale_rotation_translation();
    if !(s.is_finite() && r.is_finite() && t.is_finite()) {
        return None;
    }
    let back = DAffine3::from_scale_rotation_translation(s, r, t);
    let size = m.matrix3.x_axis.length().max(m.matrix3.y_axis.length()).max(m.matrix3.z_axis.length());
    let diff = (back.matrix3 - m.matrix3).to_cols_array().iter().fold(0.0f64, |a, d| a.max(d.abs()));
    (diff <= SHEAR_TOLERANCE * size).then_some(Transform { translation: t, rotation: r.normalize(), scale: s })
}

impl Rig {
    /// Adds one instance per placing node to `scene` (part indices offset by `first_part`),
    /// each parented to its nearest placing ancestor, posed at rest (or at `clip`'s time 0).
    pub fn instantiate(&mut self, scene: &mut Scene, first_part: usize, clip: Option<usize>) -> Result<(), PoseError> {
        self.instances = vec![None; self.nodes.len()];
        self.first_part = first_part;
        for n in 0..self.nodes.len() {
            let Some(part) = self.nodes[n].part else { continue };
            let parent = self.instanced_ancestor(n);
            let node = self.nodes[n].name.clone();
            let i = scene
                .add(super::Instance { part: first_part + part, parent, local: Transform::IDENTITY })
                .map_err(|source| PoseError::Scene { node, source })?;
            self.instances[n] = Some(i);
        }
        self.pose(scene, clip, 0.0)
    }

    fn instanced_ancestor(&self, n: usize) -> Option<usize> {
        let mut p = self.nodes[n].parent;
        while let Some(k) = p {
            if let Some(i) = self.instances.get(k).copied().flatten() {
                return Some(i);
            }
            p = self.nodes[k].parent;
        }
        None
    }

    /// Sets every instance's local transform to the hierarchy posed at scene time `t` of
    /// `clip` (looped), or at rest without a clip. Call [`Scene::update`] afterwards.
    pub fn pose(&self, scene: &mut Scene, clip: Option<usize>, t: f64) -> Result<(), PoseError> {
        let n = self.nodes.len();
        // Per node: its TRS after the clip's channels (None: the rest matrix stands).
        let mut trs: Vec<Option<(DVec3, DQuat, DVec3)>> = self
            .nodes
            .iter()
            .map(|node| match node.rest {
                Rest::Trs(t, r, s) => Some((t, r, s)),
                Rest::Matrix(_) => None,
            })
            .collect();
        // Per node, the part a flip-book channel shows now (None: its own).
        let mut shown: Vec<Option<usize>> = vec![None; n];
        if let Some(c) = clip.and_then(|c| self.clips.get(c)) {
            let local = c.local_time(t);
            for ch in &c.channels {
                if ch.property == Property::Part {
                    if let Some(slot) = shown.get_mut(ch.node) {
                        // Validated finite; a part past the scene's is refused by set_part.
                        *slot = Some(ch.sample(local)[0].max(0.0) as usize);
                    }
                    continue;
                }
                let Some(slot) = trs.get_mut(ch.node) else { continue };
                let (mut tr, mut rot, mut sc) = slot.unwrap_or_else(|| {
                    let (s, r, t) = self.nodes[ch.node].rest.affine().to_scale_rotation_translation();
                    (t, r, s)
                });
                let v = ch.sample(local);
                match ch.property {
                    Property::Translation => tr = DVec3::new(v[0], v[1], v[2]),
                    Property::Rotation => rot = DQuat::from_array(v),
                    Property::Scale => sc = DVec3::new(v[0], v[1], v[2]),
                    Property::Part => {}
                }
                *slot = Some((tr, rot, sc));
            }
        }
        // Per node: its transform relative to its nearest instanced ancestor (or the world),
        // as the exact TRS when nothing was folded in, else as a matrix to decompose.
        let mut rel: Vec<Option<DAffine3>> = vec![None; n];
        for k in 0..n {
            let node = &self.nodes[k];
            let local = match trs[k] {
                Some((t, r, s)) => DAffine3::from_scale_rotation_translation(s, r, t),
                None => node.rest.affine(),
            };
            let above = node.parent.filter(|&p| self.instances.get(p).copied().flatten().is_none());
            let folded = above.and_then(|p| rel[p]).map(|m| m * local);
            rel[k] = Some(folded.unwrap_or(local));
            let Some(i) = self.instances.get(k).copied().flatten() else { continue };
            let transform = match (folded, trs[k]) {
                (None, Some((t, r, s))) => Some(Transform { translation: t, rotation: r, scale: s }),
                _ => rel[k].as_ref().and_then(decompose),
            };
            let transform = transform.ok_or_else(|| PoseError::Shear { node: node.name.clone() })?;
            let scene_error = |source| PoseError::Scene { node: node.name.clone(), source };
            scene.set_local(i, transform).map_err(scene_error)?;
            if let Some(part) = shown[k].or(node.part) {
                scene.set_part(i, self.first_part + part).map_err(scene_error)?;
            }
        }
        Ok(())
    }

    /// World bounds of every instance over the whole of `clip` (sampled at its keys and 64
    /// even steps), or at rest. Leaves the scene posed at time 0.
    pub fn clip_bounds(&self, scene: &mut Scene, clip: Option<usize>) -> Result<(DVec3, DVec3), crate::Error> {
        let mut times = vec![0.0];
        if let Some(c) = clip.and_then(|c| self.clips.get(c)) {
            times.extend((0..64).map(|k| c.duration * k as f64 / 64.0));
            times.extend(c.channels.iter().flat_map(|ch| ch.times.iter().copied()));
        }
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for &t in &times {
            self.pose(scene, clip, t)?;
            scene.update()?;
            let (a, b) = scene.bounds();
            lo = lo.min(a);
            hi = hi.max(b);
        }
        self.pose(scene, clip, 0.0)?;
        scene.update()?;
        Ok((lo, hi))
    }

    /// The clip named `which`, or numbered `which` (0-based).
    pub fn find_clip(&self, which: &str) -> Option<usize> {
        self.clips.iter().position(|c| c.name == which).or_else(|| which.parse().ok().filter(|&i| i < self.clips.len()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(property: Property, interpolation: Interpolation, times: &[f64], values: &[[f64; 4]]) -> Channel {
        Channel { node: 0, property, interpolation, times: times.to_vec(), values: values.to_vec() }
    }

    #[test]
    fn samplers_interpolate_as_gltf_defines() {
        let v = [[0.0, 0.0, 0.0, 0.0], [2.0, 4.0, -2.0, 0.0]];
        let lin = channel(Property::Translation, Interpolation::Linear, &[1.0, 3.0], &v);
        assert_eq!(lin.sample(2.0), [1.0, 2.0, -1.0, 0.0]);
        assert_eq!(lin.sample(0.0), v[0], "before the first key: the first value");
        assert_eq!(lin.sample(9.0), v[1], "after the last key: the last value");
        let step = channel(Property::Translation, Interpolation::Step, &[1.0, 3.0], &v);
        assert_eq!(step.sample(2.9), v[0]);
        assert_eq!(step.sample(3.0), v[1]);
        // Cubic with zero tangents: smoothstep between the values.
        let z = [0.0; 4];
        let cubic = channel(Property::Translation, Interpolation::CubicSpline, &[0.0, 2.0], &[z, v[0], z, z, v[1], z]);
        let s = cubic.sample(0.5);
        let u: f64 = 0.25;
        assert!((s[0] - 2.0 * (3.0 * u * u - 2.0 * u * u * u)).abs() < 1e-12, "{s:?}");
        // Cubic with the tangents of a straight line reproduces the line (tangents per second).
        let m = [1.0, 2.0, -1.0, 0.0];
        let line = channel(Property::Translation, Interpolation::CubicSpline, &[0.0, 2.0], &[m, v[0], m, m, v[1], m]);
        for t in [0.3, 1.0, 1.7] {
            let s = line.sample(t);
            assert!((s[0] - t).abs() < 1e-12 && (s[1] - 2.0 * t).abs() < 1e-12, "{t}: {s:?}");
        }
    }

    #[test]
    fn rotations_slerp_at_constant_speed_and_stay_unit() {
        let q0 = DQuat::IDENTITY.to_array();
        let q1 = DQuat::from_rotation_y(std::f64::consts::FRAC_PI_2).to_array();
        let c = channel(Property::Rotation, Interpolation::Linear, &[0.0, 1.0], &[q0, q1]);
        let q = DQuat::from_array(c.sample(1.0 / 3.0));
        let want = DQuat::from_rotation_y(std::f64::consts::FRAC_PI_2 / 3.0);
        assert!(q.angle_between(want) < 1e-9 && (q.length() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn bad_samplers_are_refused() {
        let v = [[0.0; 4]; 2];
        let mut c = channel(Property::Scale, Interpolation::Linear, &[0.0, f64::NAN], &v);
        assert!(matches!(c.validate(), Err(ChannelError::Time { index: 1, .. })));
        c.times = vec![1.0, 1.0];
        assert!(matches!(c.validate(), Err(ChannelError::Time { index: 1, .. })));
        c.times = vec![0.0, 1.0];
        c.values[1][2] = f64::INFINITY;
        assert!(matches!(c.validate(), Err(ChannelError::Value { index: 1 })));
        c.values = vec![[0.0; 4]; 3];
        assert!(matches!(c.validate(), Err(ChannelError::Count { expected: 2, .. })));
        c.values = vec![[0.0; 4]; 2];
        assert_eq!(c.validate(), Ok(()));
    }

    #[test]
    fn decomposition_refuses_shear_and_keeps_mirrors() {
        let m = DAffine3::from_scale_rotation_translation(
            DVec3::new(-2.0, 0.5, 3.0),
            DQuat::from_rotation_z(0.7),
            DVec3::new(1.0, 2.0, 3.0),
        );
        let t = decompose(&m).expect("a TRS decomposes");
        let back = DAffine3::from_scale_rotation_translation(t.scale, t.rotation, t.translation);
        assert!(back.abs_diff_eq(m, 1e-12));
        let sheared = DAffine3::from_scale(DVec3::new(1.0, 3.0, 1.0)) * DAffine3::from_rotation_z(0.7);
        assert!(decompose(&sheared).is_none());
    }
}
