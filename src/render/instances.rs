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
    let mut out = Vec::new();
    prepare_into(scene, eye, transform, &mut out);
    out
}

/// [`prepare`] into `out` (cleared first), keeping its memory: a renderer that prepares tens
/// of thousands of instances every frame reuses last frame's vector instead of faulting in
/// fresh pages.
pub fn prepare_into(scene: &Scene, eye: DVec3, transform: bool, out: &mut Vec<Prepared>) {
    let one = |i: usize| {
        let inst = &scene.instances()[i];
        let cube = scene.parts[inst.part].bounds;
        let (min, size) = (cube.min.as_dvec3(), cube.size as f64);
        let w = scene.world(i);
        // One inverse serves the ray map and the normals (the inverse transpose of the
        // linear part is the transpose of the inverse's).
        let inverse = w.inverse();
        let to_unit = if transform {
            // (scale 1/size) · (translate −min) · inverse · (translate eye), multiplied out.
            let k = 1.0 / size;
            let m = inverse.matrix3;
            ToUnit::Affine(DAffine3 { matrix3: m * k, translation: (m * eye + inverse.translation - min) * k })
        } else {
            ToUnit::Scale { offset: (eye - min) / size, inv_size: 1.0 / size }
        };
        // The exact bounding sphere of the transformed cube about its transformed centre:
        // the farthest points of a parallelepiped from its centre are corners, h·(±c0 ± c1 +
        // c2) for the linear part's columns c and the half size h.
        let half = size * 0.5;
        let (c0, c1, c2) = (w.matrix3.x_axis, w.matrix3.y_axis, w.matrix3.z_axis);
        let (a, b) = (c0 + c1, c0 - c1);
        let corner2 = (c2 + a)
            .length_squared()
            .max((c2 - a).length_squared())
            .max((c2 + b).length_squared())
            .max((c2 - b).length_squared());
        let radius = half * corner2.sqrt();
        let max_stretch = c0.length_squared().max(c1.length_squared()).max(c2.length_squared()).sqrt();
        let centre_obj = min + DVec3::splat(half);
        Prepared {
            part: inst.part,
            to_unit,
            normal_to_world: inverse.matrix3.transpose(),
            centre: w.transform_point3(centre_obj) - eye,
            radius: radius * (1.0 + SPHERE_PAD) + f64::MIN_POSITIVE,
            max_stretch,
        }
    };
    let n = scene.instances().len();
    // Thousands of instances (a crowd of cars): every one is independent.
    #[cfg(feature = "parallel")]
    if n >= 1024 {
        use rayon::prelude::*;
        (0..n).into_par_iter().with_min_len(512).map(one).collect_into_vec(out);
        return;
    }
    out.clear();
    out.extend((0..n).map(one));
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
