//! Emissive surfaces as lights: every instance's emissive triangles ([`crate::svo::Emitter`])
//! moved into the frame's camera-relative world, picked in proportion to their power, and
//! sampled uniformly by area. A shaded point sends a shadow ray to each sample, which gives
//! soft shadows. The same table, the same random numbers and the same estimator run on the GPU
//! (`wgsl/trace.wgsl`: `emitter_light`), where the table is uploaded as `GpuEmitter` rows.

use crate::render::brdf;
use crate::scene::Scene;
use glam::{DVec3, Vec3};

/// Shadow rays end this many of the emitter's voxels short of the sampled point, so the
/// emitter's own voxels (which stand up to a voxel off its triangle) do not shadow it.
pub const MARGIN_VOXELS: f64 = 1.5;

/// One emissive triangle of one instance, in camera-relative world coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldEmitter {
    /// First corner.
    pub a: DVec3,
    /// Second corner minus the first.
    pub e1: DVec3,
    /// Third corner minus the first.
    pub e2: DVec3,
    /// Unit normal of the lit side.
    pub normal: DVec3,
    /// Area (world units²).
    pub area: f64,
    /// Emitted radiance (linear RGB).
    pub emission: Vec3,
    /// How far short of a sampled point its shadow rays end (world units).
    pub margin: f64,
}

/// A point sampled on the emitters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightSample {
    /// The point (camera-relative).
    pub point: DVec3,
    /// Unit normal of the emitter's lit side there.
    pub normal: DVec3,
    /// Emitted radiance.
    pub emission: Vec3,
    /// Probability density of having drawn the point, per unit area.
    pub pdf_area: f64,
    /// The emitter's [`WorldEmitter::margin`].
    pub margin: f64,
    /// Which triangle of [`EmitterTable::emitters`] it lies on.
    pub index: usize,
}

/// The frame's emitters with the cumulative distribution of their power.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EmitterTable {
    /// The triangles.
    pub emitters: Vec<WorldEmitter>,
    /// Cumulative power fraction per triangle (the last is 1).
    pub cdf: Vec<f64>,
    /// Total emitted power, Σ area · mean(emission) · π (world units² × radiance).
    pub power: f64,
}

impl EmitterTable {
    /// Every emissive triangle of every instance of `scene`, relative to `origin` (the eye).
    pub fn new(scene: &Scene, origin: DVec3) -> Self {
        let mut emitters = Vec::new();
        for (i, inst) in scene.instances().iter().enumerate() {
            let svo = &scene.parts[inst.part];
            if svo.emitters.is_empty() {
                continue;
            }
            let w = scene.world(i);
            let stretch = [DVec3::X, DVec3::Y, DVec3::Z].map(|a| w.transform_vector3(a).length());
            let voxel = svo.bounds.voxel_size(svo.depth) as f64 * stretch.into_iter().fold(0.0, f64::max);
            // A mirroring transform turns the winding around; the lit side stays the one the
            // object-space winding names.
            let flip = if w.matrix3.determinant() < 0.0 { -1.0 } else { 1.0 };
            for e in &svo.emitters {
                let [p0, p1, p2] = e.vertices.map(|v| w.transform_point3(v.as_dvec3()) - origin);
                let (e1, e2) = (p1 - p0, p2 - p0);
                let cross = e1.cross(e2) * flip;
                let area = cross.length() * 0.5;
                if !(area > 0.0 && area.is_finite()) {
                    continue;
                }
                emitters.push(WorldEmitter {
                    a: p0,
                    e1,
                    e2,
                    normal: cross / (2.0 * area),
                    area,
                    emission: e.emission,
                    margin: MARGIN_VOXELS * voxel,
                });
            }
        }
        let mut cdf = Vec::with_capacity(emitters.len());
        let mut sum = 0.0;
        for e in &emitters {
            sum += e.area * e.emission.as_dvec3().element_sum() / 3.0;
            cdf.push(sum);
        }
        if !(sum > 0.0 && sum.is_finite()) {
            return EmitterTable::default();
        }
        for c in &mut cdf {
            *c /= sum;
        }
        if let Some(last) = cdf.last_mut() {
            *last = 1.0;
        }
        EmitterTable { emitters, cdf, power: sum * std::f64::consts::PI }
    }

    /// Whether there is nothing to sample.
    pub fn is_empty(&self) -> bool {
        self.emitters.is_empty()
    }

    /// The point that three uniform numbers in [0, 1) pick: `u[0]` chooses the triangle by
    /// power, `u[1]` and `u[2]` the point on it (uniform by area).
    pub fn sample(&self, u: [f32; 3]) -> Option<LightSample> {
        let k = self.cdf.partition_point(|&c| c <= u[0] as f64).min(self.cdf.len().checked_sub(1)?);
        let e = &self.emitters[k];
        let p = self.cdf[k] - if k > 0 { self.cdf[k - 1] } else { 0.0 };
        let su = (u[1] as f64).sqrt();
        let (b1, b2) = (su * (1.0 - u[2] as f64), su * u[2] as f64);
        Some(LightSample {
            point: e.a + e.e1 * b1 + e.e2 * b2,
            normal: e.normal,
            emission: e.emission,
            pdf_area: p / e.area,
            margin: e.margin,
            index: k,
        })
    }
}

/// PCG's output permutation of a 32-bit state (O'Neill 2014, the RXS-M-XS variant): the
/// random numbers of light sampling, identical in WGSL (`pcg_hash`).
#[inline]
pub fn pcg_hash(v: u32) -> u32 {
    let state = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// Three uniform numbers in [0, 1) for light sample `sample` of pixel (or cell) `key`.
#[inline]
pub fn light_random(key: u32, sample: u32) -> [f32; 3] {
    let mut h = pcg_hash(key ^ pcg_hash(sample.wrapping_add(0x51ED_270B)));
    std::array::from_fn(|_| {
        h = pcg_hash(h);
        (h >> 8) as f32 / (1u32 << 24) as f32
    })
}

/// A cone through the GI volume towards a light (cone-traced soft shadows,
/// [`crate::gi::cone::visibility`]): from a camera-relative surface point with its unit
/// normal, along a unit direction, of a full aperture (radians), ending on the light's
/// surface; the fraction of the light that gets through.
pub type ShadowCone<'a> = dyn Fn(DVec3, DVec3, DVec3, f64, crate::gi::cone::ConeEnd) -> f32 + Sync + 'a;

/// Widest shadow cone (full angle, radians): an emitter seen from close by fills most of the
/// hemisphere, and a cone wider than this samples the surface it leaves from.
pub const MAX_SHADOW_CONE: f64 = 2.0 * std::f64::consts::FRAC_PI_3;

/// How emitters' shadows are found.
pub enum EmitterShadows<'s, 'c> {
    /// A shadow ray per sample: `visible(start, unit direction, distance)` says whether one
    /// reaches its end.
    Rays(&'s mut dyn FnMut(DVec3, DVec3, f64) -> bool),
    /// One cone per emitter triangle the samples land on, as wide as the triangle looks from
    /// the shaded point; every sample on it is dimmed by what the cone lets through.
    Cones(&'s ShadowCone<'c>),
}

/// The cone that stands for emitter triangle `e` seen from camera-relative `at`: its unit
/// direction (to the centroid), full aperture (a disc of the triangle's projected solid
/// angle, at most [`MAX_SHADOW_CONE`]) and end; None when the triangle faces away.
pub fn shadow_cone_of(e: &WorldEmitter, at: DVec3) -> Option<(DVec3, f64, crate::gi::cone::ConeEnd)> {
    let to = e.a + (e.e1 + e.e2) / 3.0 - at;
    let dist = to.length();
    if !(dist > 0.0 && dist.is_finite()) {
        return None;
    }
    let dir = to / dist;
    let cos = -e.normal.dot(dir);
    if !(cos > 0.0) {
        return None;
    }
    // A disc of solid angle Ω has half-angle acos(1 − Ω / 2π).
    let omega = (e.area * cos / (dist * dist)).min(std::f64::consts::TAU);
    let aperture = (2.0 * (1.0 - omega / std::f64::consts::TAU).clamp(-1.0, 1.0).acos()).min(MAX_SHADOW_CONE);
    Some((dir, aperture.max(1e-4), crate::gi::cone::ConeEnd { distance: dist, cos }))
}

/// Triangles whose shadow cone one shaded point keeps (more are traced again per sample).
const CONE_MEMO: usize = 8;

/// What a surface reflects towards the viewer from the emitters, estimated with `samples`
/// points: at `at` (camera-relative) with unit normal `n` facing the viewer, seen along unit
/// `d`, with albedo, specular reflectance `ks` and Phong exponent `shininess`. Shadow rays
/// leave from `start`, or cones from `at` ([`EmitterShadows`]). `key` seeds the random
/// numbers (the pixel or cell index).
#[allow(clippy::too_many_arguments)]
pub fn emitter_light(
    table: &EmitterTable,
    samples: u32,
    key: u32,
    at: DVec3,
    start: DVec3,
    n: Vec3,
    d: Vec3,
    albedo: Vec3,
    ks: f32,
    shininess: f32,
    mut shadows: EmitterShadows,
) -> Vec3 {
    if table.is_empty() || samples == 0 {
        return Vec3::ZERO;
    }
    let mut sum = Vec3::ZERO;
    let (mut memo, mut memo_len) = ([(usize::MAX, 0.0f32); CONE_MEMO], 0);
    for s in 0..samples {
        let Some(ls) = table.sample(light_random(key, s)) else { continue };
        let to = ls.point - at;
        let dist2 = to.length_squared();
        if !(dist2 > 0.0) {
            continue;
        }
        let wi = to / dist2.sqrt();
        let cos_light = -ls.normal.dot(wi);
        if cos_light <= 0.0 || n.as_dvec3().dot(wi) <= 0.0 {
            continue;
        }
        let response = brdf::sun_response(albedo, ks, shininess, n, d, wi.as_vec3());
        if response == Vec3::ZERO {
            continue;
        }
        let through = match &mut shadows {
            EmitterShadows::Rays(visible) => {
                // End the shadow ray before the emitter's own voxels.
                let end = ls.point + ls.normal * ls.margin;
                let ray = end - start;
                let len = ray.length();
                if !(len > 0.0) || !visible(start, ray / len, len) {
                    continue;
                }
                1.0
            }
            EmitterShadows::Cones(cone) => match memo[..memo_len].iter().find(|m| m.0 == ls.index) {
                Some(m) => m.1,
                None => {
                    let v = shadow_cone_of(&table.emitters[ls.index], at)
                        .map_or(0.0, |(dir, aperture, end)| cone(at, n.as_dvec3(), dir, aperture, end));
                    if memo_len < CONE_MEMO {
                        memo[memo_len] = (ls.index, v);
                        memo_len += 1;
                    }
                    v
                }
            },
        };
        if through <= 0.0 {
            continue;
        }
        let g = cos_light / (dist2 * ls.pdf_area);
        sum += response * ls.emission * (g as f32 * through);
    }
    sum / samples as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit square emitter of radiance L seen from a point on its axis at distance h: the
    /// irradiance has a closed form (Lambert's, for a square: 4 L · atan-sum); the estimate
    /// with many samples must agree, which checks the power pick, the area sampling and the
    /// geometry term together.
    #[test]
    fn square_emitter_matches_closed_form() {
        let square = |z: f64| {
            let c = [
                DVec3::new(-0.5, -0.5, z),
                DVec3::new(0.5, -0.5, z),
                DVec3::new(0.5, 0.5, z),
                DVec3::new(-0.5, 0.5, z),
            ];
            // Two triangles facing −z (towards the origin), different radiances to test the pick.
            let tri = |a: DVec3, b: DVec3, c: DVec3, e: Vec3| {
                let cross = (b - a).cross(c - a);
                WorldEmitter {
                    a,
                    e1: b - a,
                    e2: c - a,
                    normal: cross.normalize(),
                    area: cross.length() / 2.0,
                    emission: e,
                    margin: 0.0,
                }
            };
            vec![tri(c[0], c[2], c[1], Vec3::splat(2.0)), tri(c[0], c[3], c[2], Vec3::splat(6.0))]
        };
        let emitters = square(1.0);
        assert!(emitters.iter().all(|e| e.normal.z < 0.0));
        let mut cdf = vec![];
        let mut s = 0.0;
        for e in &emitters {
            s += e.area * e.emission.x as f64;
            cdf.push(s);
        }
        let table =
            EmitterTable { cdf: cdf.iter().map(|c| c / s).collect(), emitters, power: s * std::f64::consts::PI };
        // White Lambertian receiver at the origin facing +z: outgoing radiance = E / π with E
        // the irradiance. By symmetry each half contributes equally in solid angle, so the
        // mean radiance (4) over the full square gives E = 4 · (form factor integral).
        let est = emitter_light(
            &table,
            200_000,
            7,
            DVec3::ZERO,
            DVec3::ZERO,
            Vec3::Z,
            -Vec3::Z,
            Vec3::ONE,
            0.0,
            1.0,
            EmitterShadows::Rays(&mut |_, _, _| true),
        );
        // Irradiance from a uniform square of side a at height h on its axis:
        // E = 4 L [ x/√(1+x²) atan(x/√(1+x²)) ]·... with x = a / (2h); the form below is the
        // classic rectangle formula for a corner, used four times.
        let corner = |a: f64, b: f64, h: f64| {
            let (x, y) = (a / h, b / h);
            let sx = (1.0 + x * x).sqrt();
            let sy = (1.0 + y * y).sqrt();
            (x / sx * (y / sx).atan() + y / sy * (x / sy).atan()) / (2.0 * std::f64::consts::PI)
        };
        let form = 4.0 * corner(0.5, 0.5, 1.0);
        let want = 4.0 * form; // radiance 4 on average → outgoing = albedo/π · E = 4 · F
        assert!((est.x as f64 - want).abs() < 0.01 * want, "estimate {est} against {want}");
        // The visibility function is honoured.
        let dark = emitter_light(
            &table,
            64,
            7,
            DVec3::ZERO,
            DVec3::ZERO,
            Vec3::Z,
            -Vec3::Z,
            Vec3::ONE,
            0.0,
            1.0,
            EmitterShadows::Rays(&mut |_, _, _| false),
        );
        assert_eq!(dark, Vec3::ZERO);
        // Facing away from the emitter: nothing.
        let away = emitter_light(
            &table,
            64,
            7,
            DVec3::ZERO,
            DVec3::ZERO,
            -Vec3::Z,
            Vec3::Z,
            Vec3::ONE,
            0.0,
            1.0,
            EmitterShadows::Rays(&mut |_, _, _| true),
        );
        assert_eq!(away, Vec3::ZERO);
        // Cone shadows: each triangle's cone is traced once per point however many samples
        // land on it, and dims every sample on it by what it lets through.
        let calls = std::sync::atomic::AtomicU32::new(0);
        let half = |_: DVec3, _: DVec3, _: DVec3, _: f64, end: crate::gi::cone::ConeEnd| {
            calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            assert!((end.distance - 1.0).abs() < 0.3 && end.cos > 0.9, "{end:?}");
            0.5
        };
        let at = |shadows| {
            emitter_light(&table, 4096, 7, DVec3::ZERO, DVec3::ZERO, Vec3::Z, -Vec3::Z, Vec3::ONE, 0.0, 1.0, shadows)
        };
        let mut free = |_, _, _| true;
        let lit = at(EmitterShadows::Rays(&mut free));
        let dimmed = at(EmitterShadows::Cones(&half));
        assert_eq!(calls.load(std::sync::atomic::Ordering::Relaxed), 2);
        assert!((dimmed - lit * 0.5).abs().max_element() < 1e-5, "{dimmed} against {lit}");
    }

    #[test]
    fn light_random_is_uniform() {
        let mut hist = [0u32; 10];
        for k in 0..1000 {
            for s in 0..10 {
                for u in light_random(k, s) {
                    assert!((0.0..1.0).contains(&u));
                    hist[(u * 10.0) as usize] += 1;
                }
            }
        }
        for h in hist {
            assert!((2800..3200).contains(&h), "{hist:?}");
        }
    }
}
