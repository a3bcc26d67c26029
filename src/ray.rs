//! Rays and their preparation for octree traversal: mapping into the unit cube of one SVO,
//! the robust handling of zero, −0.0, denormal and tiny direction components, and the
//! Revelles mirroring.

use crate::svo::Cube;
use glam::{DVec3, Vec3};

/// A ray `origin + t·dir`. `dir` need not be unit length: after an affine inverse transform
/// it is deliberately left unnormalized so that `t` means the same in every space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Start point.
    pub origin: Vec3,
    /// Direction (any non-zero length).
    pub dir: Vec3,
}

impl Ray {
    /// Creates a ray.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Ray { origin, dir }
    }
    /// The point at parameter `t`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// A direction component whose magnitude is below this fraction of the largest component is
/// treated as exactly parallel to its axis (Revelles §3.3): its t-values would be ±∞ or
/// overflow, and a ray that moves less than 2⁻⁴⁰ of a cube width sideways while crossing it
/// cannot change voxel at any supported depth (≤ 2⁻²⁰) except by sitting on a boundary.
pub const PARALLEL_RATIO: f32 = 1.0 / (1u64 << 40) as f32;

/// After moving the origin to the cube (see [`UnitRay::from_unit`]) its coordinates are
/// within a few units of it; anything beyond this (only possible on parallel axes, which
/// are not moved) is refused as a miss.
pub const MAX_UNIT_ORIGIN: f32 = (1u64 << 40) as f32;

/// 2^-floor(log2 m) for a positive finite m, read off the exponent bits (this runs per ray
/// and part; `log2` was a fifth of the render time).
fn inverse_pow2_floor(m: f64) -> f64 {
    let biased = ((m.to_bits() >> 52) & 0x7FF) as i64;
    if (1..2046).contains(&biased) {
        // m = 1.f × 2^(biased − 1023)  →  2^(1023 − biased) has biased exponent 2046 − biased.
        f64::from_bits(((2046 - biased) as u64) << 52)
    } else if biased == 2046 {
        // 2^-1023 is subnormal (bit 51 alone). `powi(-1024)` below, which the log2 of m ≥
        // (2 − 2⁻⁵²)·2¹⁰²³ rounds to, would give 0 and make every t infinite.
        f64::from_bits(1 << 51)
    } else {
        2f64.powi(-(m.log2().floor() as i32))
    }
}

/// The smaller of two numbers that are not NaN (`f64::min` without its NaN handling).
#[inline(always)]
fn smaller(a: f64, b: f64) -> f64 {
    if a < b {
        a
    } else {
        b
    }
}

/// The larger of two numbers that are not NaN (`f64::max` without its NaN handling).
#[inline(always)]
fn larger(a: f64, b: f64) -> f64 {
    if a > b {
        a
    } else {
        b
    }
}

/// Bit i set: direction component i counts as parallel (see [`PARALLEL_RATIO`]). Shared by
/// the traversal and the DDA oracle so both classify a ray the same way.
pub fn parallel_axes(dir: DVec3) -> u32 {
    parallel_below(dir, dir.abs().max_element())
}

/// [`parallel_axes`] of a finite direction, its largest magnitude found by plain
/// comparisons (the same classification without `f64::max`'s NaN handling).
#[inline(always)]
pub(crate) fn parallel_axes_finite(dir: DVec3) -> u32 {
    let a = dir.abs();
    parallel_below(dir, larger(larger(a.x, a.y), a.z))
}

/// [`parallel_axes`] given `m`, the largest of `dir`'s magnitudes.
#[inline(always)]
fn parallel_below(dir: DVec3, m: f64) -> u32 {
    let mut mask = 0;
    for i in 0..3 {
        if dir[i].abs() < PARALLEL_RATIO as f64 * m {
            mask |= 1 << i;
        }
    }
    mask
}

/// A ray prepared for the traversal of one SVO.
///
/// In the unit cube of the SVO, with the direction rescaled by a power of two so that its
/// largest component lies in [1, 2) (exact, and it keeps every t-value finite), and mirrored
/// so that every non-parallel component is positive (Revelles' `a` mask, taken from the
/// sign bit so that −0.0 behaves like +0.0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UnitRay {
    /// Origin in the unit cube, mirrored on the axes in `mirror`.
    pub origin: [f32; 3],
    /// Reciprocal of the (rescaled, mirrored, positive) direction; 0 on parallel axes.
    pub inv_dir: [f32; 3],
    /// Bit i: axis i is mirrored (the original direction had its sign bit set).
    pub mirror: u32,
    /// Bit i: axis i is treated as parallel (no motion along it).
    pub parallel: u32,
    /// The direction was multiplied by this power of two, so internal t = (world t −
    /// `t_offset`) / `t_scale`.
    pub t_scale: f64,
    /// The origin was moved this far along the ray (to where it enters the cube).
    pub t_offset: f64,
    /// `origin` before rounding to f32 (mirrored, moved to the cube): the reported hit t is
    /// computed from it, so rounding the origin never shows in t.
    pub origin64: [f64; 3],
    /// The rescaled, mirrored direction in f64 (0 on parallel axes).
    pub dir64: [f64; 3],
}

impl UnitRay {
    /// Prepares a ray given in SVO object space.
    pub fn from_object(cube: &Cube, ray: &Ray) -> Option<Self> {
        Self::from_unit(cube.to_unit(ray.origin.as_dvec3()), ray.dir.as_dvec3() / cube.size as f64)
    }

    /// Prepares a ray already mapped to the unit cube. The origin comes in f64 so callers can
    /// subtract large offsets before rounding (camera-relative precision). Returns `None` for
    /// non-finite input, a zero direction, or an origin too far away (see
    /// [`MAX_UNIT_ORIGIN`]); such rays miss.
    ///
    /// Always inlined: returned through the stack, the 120-byte ray was copied into the
    /// caller's packet lane by loads that waited on this function's narrower stores (5 % of a
    /// close-up frame; docs/benchmarks.md, step 35).
    #[inline(always)]
    pub fn from_unit(origin: DVec3, dir: DVec3) -> Option<Self> {
        if !origin.is_finite() || !dir.is_finite() {
            return None;
        }
        // The inputs are finite from here on, so no minimum or maximum below meets a NaN:
        // plain comparisons pick what `f64::min` and `max` would (their NaN handling was a
        // fifth of the setup's samples; docs/benchmarks.md, step 44).
        let a = dir.abs();
        let m = larger(larger(a.x, a.y), a.z);
        // Below 1e-300 the rescale would leave f64's normal range; such a ray does not move.
        if !(m >= 1e-300) {
            return None;
        }
        let parallel = parallel_below(dir, m);
        // Move the origin (in f64) to where the line enters the cube, so that rays from far
        // away keep f32's precision inside it; a line that misses the cube misses.
        let (mut t_enter, mut t_exit) = (f64::NEG_INFINITY, f64::INFINITY);
        for i in 0..3 {
            if parallel & (1 << i) != 0 {
                if !(origin[i] >= 0.0 && origin[i] < 1.0) {
                    return None;
                }
            } else {
                // Both finite or infinite, never NaN: dir[i] is not zero on this axis.
                let (a, b) = (-origin[i] / dir[i], (1.0 - origin[i]) / dir[i]);
                t_enter = larger(t_enter, smaller(a, b));
                t_exit = smaller(t_exit, larger(a, b));
            }
        }
        if !(t_enter <= t_exit) {
            return None;
        }
        let t_offset = if t_enter > 0.0 || t_exit < 0.0 { t_enter } else { 0.0 };
        let mut origin = origin;
        for i in 0..3 {
            if parallel & (1 << i) == 0 {
                origin[i] += t_offset * dir[i];
            }
        }
        // Power-of-two rescale: exact, so t converts back without rounding.
        let t_scale = inverse_pow2_floor(m);
        let d = dir * t_scale;
        let mut out = UnitRay {
            origin: [0.0; 3],
            inv_dir: [0.0; 3],
            mirror: 0,
            parallel: 0,
            t_scale,
            t_offset,
            origin64: [0.0; 3],
            dir64: [0.0; 3],
        };
        for i in 0..3 {
            let o = origin[i] as f32;
            if !(o.abs() <= MAX_UNIT_ORIGIN) {
                return None;
            }
            let di = d[i] as f32;
            if parallel & (1 << i) != 0 {
                out.parallel |= 1 << i;
                out.origin[i] = o;
                out.origin64[i] = origin[i];
            } else if di.is_sign_negative() {
                out.mirror |= 1 << i;
                out.origin[i] = 1.0 - o;
                out.inv_dir[i] = 1.0 / -di;
                out.origin64[i] = 1.0 - origin[i];
                out.dir64[i] = -d[i];
            } else {
                out.origin[i] = o;
                out.inv_dir[i] = 1.0 / di;
                out.origin64[i] = origin[i];
                out.dir64[i] = d[i];
            }
        }
        Some(out)
    }

    /// Converts a world/object t to this ray's internal t.
    pub fn to_internal(&self, t: f32) -> f32 {
        ((t as f64 - self.t_offset) / self.t_scale) as f32
    }
    /// Converts an internal t back to world/object t.
    pub fn to_world(&self, t: f32) -> f32 {
        (self.t_offset + t as f64 * self.t_scale) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn signed_zero_and_denormals_are_parallel_and_unmirrored() {
        let r = UnitRay::from_unit(DVec3::splat(0.5), DVec3::new(1.0, -0.0, 1e-42)).unwrap();
        assert_eq!(r.parallel, 0b110);
        assert_eq!(r.mirror, 0);
        let r = UnitRay::from_unit(DVec3::splat(0.5), DVec3::new(-0.0, -1.0, 0.0)).unwrap();
        assert_eq!((r.parallel, r.mirror), (0b101, 0b010));
    }

    #[test]
    fn degenerate_rays_are_refused() {
        assert!(UnitRay::from_unit(DVec3::ZERO, DVec3::ZERO).is_none());
        assert!(UnitRay::from_unit(DVec3::NAN, DVec3::X).is_none());
        assert!(UnitRay::from_unit(DVec3::ZERO, DVec3::new(f64::INFINITY, 0.0, 0.0)).is_none());
        // Far away but aimed at the cube: moved to the cube, not refused.
        let far = UnitRay::from_unit(DVec3::new(-1e13, 0.5, 0.5), DVec3::X).unwrap();
        assert!(far.origin[0].abs() < 1e-3 && far.t_offset > 9.9e12);
        // Far away and beside it: a miss.
        assert!(UnitRay::from_unit(DVec3::splat(1e13), DVec3::X).is_none());
        assert!(UnitRay::from_unit(DVec3::ZERO, DVec3::new(1e-310, 0.0, 0.0)).is_none());
    }

    #[test]
    fn inverse_pow2_matches_log2() {
        for m in [1.0, 1.5, 0.75, 3e-30, 7e20, 2f64.powi(-1021), 1e-300, 1e300, 0.999_999_999] {
            assert_eq!(inverse_pow2_floor(m), 2f64.powi(-(m.log2().floor() as i32)), "{m}");
            assert!((1.0..2.0).contains(&(m * inverse_pow2_floor(m))), "{m}");
        }
        for m in [f64::MAX, 2f64.powi(1023), 1.999 * 2f64.powi(1023)] {
            assert_eq!(inverse_pow2_floor(m), f64::from_bits(1 << 51), "{m}");
            assert!((1.0..2.0).contains(&(m * inverse_pow2_floor(m))), "{m}");
        }
    }

    #[test]
    fn the_largest_directions_keep_finite_t() {
        // |d| near f64::MAX: the rescale is 2^-1023 (it was 0 once, and every t infinite).
        let r = UnitRay::from_unit(DVec3::new(-1.0, 0.5, 0.5), DVec3::new(f64::MAX, 0.0, 0.0)).unwrap();
        assert!(r.t_scale > 0.0 && r.inv_dir[0] > 0.0 && r.inv_dir[0].is_finite());
        // It enters the cube at world t = 1 / f64::MAX (about 5.6e-309); the rescaled
        // direction is about 2 long, so the origin is half a unit of internal t behind.
        assert!((r.t_offset - 1.0 / f64::MAX).abs() <= 1e-323);
        assert_eq!(r.to_internal(0.0), -0.5);
    }

    /// The slab test's entry offset as `f64::min` and `max` give it (None: the line misses).
    fn offset_with_std_min_max(origin: DVec3, dir: DVec3) -> Option<f64> {
        let parallel = parallel_axes(dir);
        let (mut t_enter, mut t_exit) = (f64::NEG_INFINITY, f64::INFINITY);
        for i in 0..3 {
            if parallel & (1 << i) != 0 {
                if !(origin[i] >= 0.0 && origin[i] < 1.0) {
                    return None;
                }
            } else {
                let (a, b) = (-origin[i] / dir[i], (1.0 - origin[i]) / dir[i]);
                t_enter = t_enter.max(a.min(b));
                t_exit = t_exit.min(a.max(b));
            }
        }
        (t_enter <= t_exit).then_some(if t_enter > 0.0 || t_exit < 0.0 { t_enter } else { 0.0 })
    }

    #[test]
    fn the_slab_test_without_nan_handling_agrees_with_std_min_max() {
        // Origins on faces, edges and corners (entry at ±0), inside, far away; directions
        // along axes, with ±0 and tiny components, and random ones.
        let mut rng = crate::rng::Rng::new(7);
        let coords = [0.0, -0.0, 1.0, 0.5, -0.25, 1.75, 1e-300, -3.0, 1e9, -1e12];
        let comps = [1.0, -1.0, 0.0, -0.0, 1e-14, -1e-13, 0.3, -0.7, 1e-300, 2.0];
        let (mut rays, mut hits) = (0, 0);
        for _ in 0..40_000 {
            let pick = |rng: &mut crate::rng::Rng, from: &[f64]| {
                if rng.below(3) == 0 {
                    rng.f64() * 4.0 - 1.5
                } else {
                    from[rng.below(from.len() as u64) as usize]
                }
            };
            let o = DVec3::new(pick(&mut rng, &coords), pick(&mut rng, &coords), pick(&mut rng, &coords));
            let d = DVec3::new(pick(&mut rng, &comps), pick(&mut rng, &comps), pick(&mut rng, &comps));
            if d.abs().max_element() < 1e-300 {
                continue;
            }
            let want = offset_with_std_min_max(o, d);
            let got = UnitRay::from_unit(o, d);
            rays += 1;
            match (want, got) {
                (Some(w), Some(g)) => {
                    hits += 1;
                    assert_eq!(w.to_bits(), g.t_offset.to_bits(), "{o} {d}");
                }
                // Refused after the slab test: an origin left too far off the cube (a parallel
                // axis, or a move that overflowed).
                (Some(_), None) => {}
                (None, g) => assert!(g.is_none(), "{o} {d}"),
            }
        }
        assert!(hits > rays / 10 && hits < rays, "{hits} of {rays} rays cross the cube");
    }

    #[test]
    fn rescale_is_a_power_of_two() {
        let r = UnitRay::from_unit(DVec3::ZERO, DVec3::new(3e-30, 0.0, 0.0)).unwrap();
        assert_eq!(r.t_scale.log2().fract(), 0.0);
        assert!((1.0..2.0).contains(&(1.0 / r.inv_dir[0])));
    }
}
