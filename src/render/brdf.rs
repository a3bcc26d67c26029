//! The surface model every image is made with — the tracer (CPU and `wgsl/trace.wgsl`), GI's
//! cones and the path-traced reference: two-sided Lambertian diffuse (albedo, MTL `Kd`) plus an
//! optional normalized Phong lobe (specular reflectance `ks` from MTL `Ks`, exponent from
//! `Ns`):
//!
//! f(l, v) = albedo / π + ks · (n + 2) / (2π) · max(0, r·l)ⁿ, r = v mirrored about the normal.
//!
//! The (n + 2)/(2π) factor makes the lobe reflect at most `ks` of the light arriving from any
//! one direction, so with `max(Kd) + ks ≤ 1` (the loader enforces it) no surface reflects more
//! than it receives and paths in closed rooms stay finite.
//!
//! Glossiness `g ∈ [0, 1]` is the exponent on a log scale, `n = 2^(10 g)` (1 … 1024), the way
//! it is stored per voxel (four bits).

use crate::rng::Rng;
use glam::{DVec3, Vec3};

/// Glossiness of Phong exponent `shininess` (MTL `Ns`): `log2(Ns) / 10` in [0, 1].
pub fn gloss_of_shininess(shininess: f32) -> f32 {
    // NaN fails the comparison and counts as dull; +∞ is the sharpest lobe.
    if shininess > 1.0 {
        (shininess.log2() / 10.0).min(1.0)
    } else {
        0.0
    }
}

/// Phong exponent of glossiness `gloss`: `2^(10 g)`, 1 … 1024.
pub fn shininess_of_gloss(gloss: f32) -> f32 {
    (10.0 * gloss.clamp(0.0, 1.0)).exp2()
}

/// [`shininess_of_gloss`] of a stored 4-bit glossiness G (gloss G/15), from a table: it is
/// asked for every pixel of every frame.
pub fn shininess_of_gloss_bits(g: u32) -> f32 {
    static TABLE: std::sync::OnceLock<[f32; 16]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|g| shininess_of_gloss(g as f32 / 15.0)))[g as usize & 15]
}

/// The normalized Phong lobe `(n + 2)/(2π) · max(0, cos α)ⁿ`.
pub fn phong(shininess: f32, cos_alpha: f32) -> f32 {
    // Below `zero_below`, `powf` gives 0 too, but through its slow underflow path: a glossy
    // surface's sun lobe underflows at most pixels.
    if cos_alpha <= 0.0 || cos_alpha < zero_below(shininess) {
        return 0.0;
    }
    (shininess + 2.0) / std::f32::consts::TAU * cos_alpha.min(1.0).powf(shininess)
}

/// A cosine under which `cosⁿ` (n = `shininess`) is below 2⁻¹⁶⁰, a two-thousandth of the least
/// f32 subnormal, so that `powf` rounds it to 0: 2^(−160/n), lowered by a millionth; 0 (no
/// cosine) for an exponent that is not finite and positive. Remembered per thread in 16
/// slots by the exponent (a frame's surfaces share a few: the stored glossinesses give 16),
/// so that neighbouring pixels of different materials do not compute it again and again.
fn zero_below(shininess: f32) -> f32 {
    thread_local! {
        // (exponent's bits, cosine); NaN's bits: no exponent yet.
        static SEEN: [std::cell::Cell<(u32, f32)>; 16] = const { [const { std::cell::Cell::new((u32::MAX, 0.0)) }; 16] };
    }
    let bits = shininess.to_bits();
    SEEN.with(|seen| {
        let slot = &seen[(bits.wrapping_mul(0x9E37_79B1) >> 28) as usize];
        let (seen_bits, cut) = slot.get();
        if seen_bits == bits {
            return cut;
        }
        let cut = match shininess.is_finite() && shininess > 0.0 {
            true => (2f64.powf(-160.0 / shininess as f64) * (1.0 - 1e-6)) as f32,
            false => 0.0,
        };
        slot.set((bits, cut));
        cut
    })
}

/// `d` mirrored about unit normal `n` (`d` points at the surface, the result away from it).
pub fn reflect(d: DVec3, n: DVec3) -> DVec3 {
    d - n * (2.0 * d.dot(n))
}

/// Full aperture (radians) of the one cone that stands for the lobe of exponent `shininess`
/// in GI: twice the angle at which the lobe falls to half its peak, `acos(0.5^(1/n))` —
/// 120° for n = 1, 13.5° for n = 100, 4.2° for n = 1024.
pub fn cone_aperture(shininess: f32) -> f64 {
    let n = (shininess as f64).clamp(1.0, 1e6);
    2.0 * 0.5f64.powf(1.0 / n).acos()
}

/// Radiance leaving towards the viewer per unit of sun irradiance: the sun at `to_sun`
/// lighting a surface with unit normal `n` (facing the viewer) seen along unit `d` (from
/// the eye towards the surface). Zero when the sun is behind the surface.
pub fn sun_response(albedo: Vec3, ks: f32, shininess: f32, n: Vec3, d: Vec3, to_sun: Vec3) -> Vec3 {
    let cos = n.dot(to_sun);
    if cos <= 0.0 {
        return Vec3::ZERO;
    }
    facing_response(albedo, ks, shininess, n, d, to_sun, cos)
}

/// [`sun_response`] where the surface faces the light: `cos` is `n · to_sun`, above 0.
#[inline(always)]
pub fn facing_response(albedo: Vec3, ks: f32, shininess: f32, n: Vec3, d: Vec3, to_sun: Vec3, cos: f32) -> Vec3 {
    let mut f = albedo * (cos / std::f32::consts::PI);
    if ks > 0.0 {
        let r = reflect(d.as_dvec3(), n.as_dvec3()).as_vec3();
        f += Vec3::splat(ks * phong(shininess, r.dot(to_sun)) * cos);
    }
    f
}

/// One sampled bounce: the new direction and the path weight `f · cos / pdf`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounce {
    /// Unit direction leaving the surface.
    pub dir: DVec3,
    /// Throughput factor of the bounce.
    pub weight: DVec3,
}

/// Samples the surface model at a surface with unit normal `n` (facing `d`'s origin), seen
/// along unit `d`: the lobe is picked in proportion to its reflectance (diffuse by max(Kd),
/// specular by `ks`), then a cosine-weighted or Phong-lobe direction is drawn; the weight
/// makes the estimate unbiased. `None`: the path is absorbed (a specular sample below the
/// surface, or a black surface).
pub fn sample(albedo: Vec3, ks: f32, shininess: f32, n: DVec3, d: DVec3, rng: &mut Rng) -> Option<Bounce> {
    let kd = albedo.max_element().max(0.0) as f64;
    let ks = ks.max(0.0) as f64;
    if kd + ks <= 0.0 {
        return None;
    }
    let p_spec = ks / (kd + ks);
    if ks == 0.0 || rng.f64() >= p_spec {
        let dir = cosine_sample(n, rng);
        return Some(Bounce { dir, weight: albedo.as_dvec3() / (1.0 - p_spec) });
    }
    // Phong lobe: pdf (n + 1)/(2π) cos^n α about r; f·cos/pdf = ks (n + 2)/(n + 1) cos θ.
    let e = shininess.max(0.0) as f64;
    let r = reflect(d, n).normalize();
    let (t, b) = r.any_orthonormal_pair();
    let (u1, u2) = (rng.f64(), rng.f64());
    let cos_a = u2.powf(1.0 / (e + 1.0));
    let sin_a = (1.0 - cos_a * cos_a).max(0.0).sqrt();
    let phi = std::f64::consts::TAU * u1;
    let dir = (r * cos_a + (t * phi.cos() + b * phi.sin()) * sin_a).normalize();
    let cos_t = dir.dot(n);
    if cos_t <= 0.0 {
        return None;
    }
    Some(Bounce { dir, weight: DVec3::splat(ks * (e + 2.0) / (e + 1.0) * cos_t / p_spec) })
}

/// A cosine-weighted direction about unit `n`.
pub fn cosine_sample(n: DVec3, rng: &mut Rng) -> DVec3 {
    let (t, b) = n.any_orthonormal_pair();
    let (u1, u2) = (rng.f64(), rng.f64());
    let r = u2.sqrt();
    let phi = std::f64::consts::TAU * u1;
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u2).max(0.0).sqrt()).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ∫ f(l) cos θ dω over the upper hemisphere about +Z, by the midpoint rule.
    fn hemisphere(steps: usize, f: impl Fn(DVec3) -> f64) -> f64 {
        let (dt, dp) = (std::f64::consts::FRAC_PI_2 / steps as f64, std::f64::consts::TAU / steps as f64);
        let mut sum = 0.0;
        for i in 0..steps {
            let theta = (i as f64 + 0.5) * dt;
            for j in 0..steps {
                let phi = (j as f64 + 0.5) * dp;
                let l = DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
                sum += f(l) * theta.cos() * theta.sin() * dt * dp;
            }
        }
        sum
    }

    /// The lobe integrated over the hemisphere (times cos θ) is at most 1 and close to 1 for
    /// a mirror direction near the normal — the normalization the whole model relies on.
    #[test]
    fn phong_lobe_reflects_at_most_what_arrives() {
        for &e in &[1.0f32, 10.0, 100.0, 1000.0] {
            let n = DVec3::Z;
            let d = -DVec3::Z;
            let r = reflect(d, n);
            let sum = hemisphere(800, |l| phong(e, r.dot(l) as f32) as f64);
            assert!(sum <= 1.0 + 1e-3 && sum > 0.6, "exponent {e}: ∫ f cos = {sum}");
        }
    }

    /// Where the lobe skips `powf`, `powf` gives 0 as well: for the stored glossinesses and
    /// other exponents, at cosines spread over (0, 1] and packed around where `cosⁿ` reaches
    /// the least subnormals (the lobe the same bit for bit as computed in full).
    #[test]
    fn skipped_lobes_are_the_computed_ones() {
        let full = |e: f32, c: f32| {
            if c <= 0.0 {
                0.0
            } else {
                (e + 2.0) / std::f32::consts::TAU * c.min(1.0).powf(e)
            }
        };
        let mut rng = Rng::new(3);
        let mut exponents: Vec<f32> = (0..16).map(shininess_of_gloss_bits).collect();
        exponents.extend((0..40).map(|_| (rng.f64() * 12.0).exp2() as f32));
        let (mut skipped, mut tiny) = (0, 0);
        for &e in &exponents {
            // Where cosⁿ is 2⁻¹⁴⁹, the least subnormal.
            let edge = 2f64.powf(-149.0 / e as f64);
            for i in 0..4000 {
                let c = match i % 2 {
                    0 => rng.f64() as f32,
                    _ => (edge * 2f64.powf((rng.f64() - 0.7) * 40.0 / e as f64)) as f32,
                };
                let (got, want) = (phong(e, c), full(e, c));
                assert_eq!(got.to_bits(), want.to_bits(), "exponent {e}, cosine {c}");
                skipped += (c > 0.0 && c < zero_below(e)) as u32;
                tiny += (want > 0.0 && want < 1e-30) as u32;
            }
        }
        assert!(skipped > 10_000 && tiny > 1_000, "skipped {skipped}, tiny {tiny}");
    }

    /// Sampling is unbiased: the mean weight of many samples equals the directional albedo
    /// computed by quadrature.
    #[test]
    fn sampling_matches_the_integral() {
        let (albedo, ks, e) = (Vec3::new(0.5, 0.3, 0.1), 0.4f32, 20.0f32);
        let n = DVec3::Z;
        let d = DVec3::new(0.6, 0.0, -0.8);
        let mut rng = Rng::new(7);
        let count = 400_000;
        let mut mean = DVec3::ZERO;
        for _ in 0..count {
            if let Some(b) = sample(albedo, ks, e, n, d, &mut rng) {
                mean += b.weight;
            }
        }
        mean /= count as f64;
        let r = reflect(d, n);
        let spec = hemisphere(600, |l| (ks * phong(e, r.dot(l) as f32)) as f64);
        let want = albedo.as_dvec3() + DVec3::splat(spec);
        assert!((mean - want).abs().max_element() < 0.01, "mean weight {mean} against {want}");
    }

    #[test]
    fn gloss_round_trips_and_apertures_narrow() {
        for &ns in &[1.0f32, 4.0, 100.0, 1024.0] {
            assert!((shininess_of_gloss(gloss_of_shininess(ns)) - ns).abs() < ns * 1e-4);
        }
        assert_eq!(gloss_of_shininess(0.0), 0.0);
        assert_eq!(gloss_of_shininess(f32::NAN), 0.0);
        assert_eq!(gloss_of_shininess(f32::INFINITY), 1.0);
        assert!((cone_aperture(1.0).to_degrees() - 120.0).abs() < 1e-6);
        assert!(cone_aperture(1024.0) < cone_aperture(100.0) && cone_aperture(100.0) < cone_aperture(1.0));
    }
}
