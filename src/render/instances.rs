//! Per-frame instance data, all relative to the camera: the map from camera-relative world
//! space into each instance's SVO unit cube (the inverse transform, never renormalized, so t
//! is the same everywhere), the inverse transpose for normals, and the bounding sphere.
//!
//! Everything is formed in f64 from f64 world transforms and the f64 eye, so large world
//! coordinates cancel before any rounding to f32 (a car 10⁶ units away renders like one at the
//! origin).

use crate::scene::Scene;
use glam::{DAffine3, DMat3, DVec3};

/// Sphere radii are padded by this fraction so that hits computed in f32 never fall outside
/// the sphere computed in f64 (culling, early-out and the hit buffer rely on it).
pub const SPHERE_PAD: f64 = 1e-6;

/// How rays reach an instance's unit cube.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ToUnit {
    /// Identity world transform: only the cube's offset and scale (no ray transformation).
    Scale {
        /// Unit-cube position of the camera-relative origin.
        offset: DVec3,
        /// 1 / cube size.
        inv_size: f64,
    },
    /// General affine map (inverse world transform, then the cube mapping).
    Affine(DAffine3),
}

impl ToUnit {
    /// Maps a camera-relative point.
    #[inline]
    pub fn point(&self, p: DVec3) -> DVec3 {
        match self {
            ToUnit::Scale { offset, inv_size } => *offset + p * *inv_size,
            ToUnit::Affine(m) => m.transform_point3(p),
        }
    }
    /// Maps a direction (not renormalized).
    #[inline]
    pub fn vector(&self, d: DVec3) -> DVec3 {
        match self {
            ToUnit::Scale { inv_size, .. } => d * *inv_size,
            ToUnit::Affine(m) => m.transform_vector3(d),
        }
    }
}

/// One instance, ready for this frame's rays.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prepared {
    /// The part it places.
    pub part: usize,
    /// Camera-relative world → SVO unit cube.
    pub to_unit: ToUnit,
    /// Object → world for normals: the inverse transpose of the world linear part.
    pub normal_to_world: DMat3,
    /// Bounding-sphere centre, camera-relative.
    pub centre: DVec3,
    /// Bounding-sphere radius (padded by [`SPHERE_PAD`]).
    pub radius: f64,
    /// Largest stretch of the world transform (object → world length factor).
    pub max_stretch: f64,
}

/// Prepares every instance for a camera at `eye`. `transform == false` (a frame plan that
/// found only identity transforms) maps rays with the cube offset and scale alone.
pub fn prepare(scene: &Scene, eye: DVec3, transform: bool) -> Vec<Prepared> {
    let one = |i: usize| {
        let inst = &scene.instances()[i];
        {
            let cube = scene.parts[inst.part].bounds;
            let (min, size) = (cube.min.as_dvec3(), cube.size as f64);
            let w = scene.world(i);
            let to_unit = if transform {
                let cube_from_world = DAffine3::from_scale(DVec3::splat(1.0 / size)) * DAffine3::from_translation(-min);
                ToUnit::Affine(cube_from_world * w.inverse() * DAffine3::from_translation(eye))
            } else {
                ToUnit::Scale { offset: (eye - min) / size, inv_size: 1.0 / size }
            };
            // The exact bounding sphere of the transformed cube about its transformed centre:
            // the farthest points of a parallelepiped from its centre are corners.
            let half = DVec3::splat(size * 0.5);
            let centre_obj = min + half;
            let mut radius = 0.0f64;
            let mut max_stretch = 0.0f64;
            for k in 0..4 {
                let s = DVec3::new(if k & 1 == 0 { 1.0 } else { -1.0 }, if k & 2 == 0 { 1.0 } else { -1.0 }, 1.0);
                radius = radius.max(w.transform_vector3(half * s).length());
            }
            for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
                max_stretch = max_stretch.max(w.transform_vector3(axis).length());
            }
            Prepared {
                part: inst.part,
                to_unit,
                normal_to_world: w.matrix3.inverse().transpose(),
                centre: w.transform_point3(centre_obj) - eye,
                radius: radius * (1.0 + SPHERE_PAD) + f64::MIN_POSITIVE,
                max_stretch,
            }
        }
    };
    // Thousands of instances (a crowd of cars): every one is independent.
    #[cfg(feature = "parallel")]
    if scene.instances().len() >= 1024 {
        use rayon::prelude::*;
        return (0..scene.instances().len()).into_par_iter().map(one).collect();
    }
    (0..scene.instances().len()).map(one).collect()
}

/// Whether the eye (the camera-relative origin `prepared` was made for) lies inside a voxel
/// of some instance: every ray from there hits at t = 0 and the image is one colour. For
/// callers without the frame's pixels (a GPU frame kept on the GPU);
/// [`super::Frame::eye_inside_fraction`] measures the same from the pixels. Only instances
/// whose bounding sphere holds the eye are looked up.
pub fn eye_inside(parts: &[std::sync::Arc<crate::svo::Svo>], prepared: &[Prepared]) -> bool {
    prepared.iter().any(|p| {
        p.centre.length() <= p.radius && parts.get(p.part).is_some_and(|svo| svo.contains(p.to_unit.point(DVec3::ZERO)))
    })
}

/// The interval of t over which the ray `o + t·d` (d unit length) is inside the sphere, or
/// None when it misses it or the sphere lies behind the origin.
#[inline]
pub fn sphere_interval(centre: DVec3, radius: f64, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
    let oc = centre - o;
    let b = oc.dot(d);
    let c = oc.length_squared() - radius * radius;
    let disc = b * b - c;
    if !(disc >= 0.0) {
        return None;
    }
    let s = disc.sqrt();
    let (t0, t1) = (b - s, b + s);
    (t1 >= 0.0).then_some((t0, t1))
}
