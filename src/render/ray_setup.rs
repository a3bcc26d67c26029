//! A tile's rays set up four at a time: [`UnitRay::from_unit`] of the directions a tile's
//! rays take into one instance's unit cube, from one point (the eye) or from points of their
//! own (a tile's shadow rays, a library caller's rays), in AVX2 vectors where the CPU has
//! them.
//!
//! The rays are the scalar set-up's bit for bit: the map into the cube, the cube entry, the
//! origin's move, the power-of-two rescale and the mirroring are the same IEEE operations
//! in the same order (minima and maxima with the operand order of `from_unit`'s, no fused
//! multiply-add, conversions rounding to nearest). A lane off that path (an axis parallel,
//! non-finite input, a direction tiny or huge) is made by `from_unit` itself.

use super::instances::ToUnit;
use crate::ray::{UnitRay, MAX_UNIT_ORIGIN, PARALLEL_RATIO};
use crate::scene::camera::Basis;
use glam::DVec3;

/// Sets `dirs[k]` to `b.dir(sx[k % 8], sy[k / 8])` for the lanes `k` of `lanes` of an 8×8
/// tile (`sx`, `sy` its columns' and rows' screen slopes): the unit directions of its rays
/// from the eye, four at a time in AVX2 where the CPU has it (the same IEEE operations in
/// the same order as `Basis::dir`, so the same bits). The other lanes of a row's four that
/// holds one of `lanes` may be written too.
///
/// # Panics
/// When `dirs` holds fewer than 64 directions.
pub(crate) fn tile_dirs(b: &Basis, sx: &[f64; 8], sy: &[f64; 8], lanes: u64, dirs: &mut [DVec3]) {
    let dirs = &mut dirs[..64];
    #[cfg(target_arch = "x86_64")]
    if avx2() {
        // SAFETY: the CPU has AVX and AVX2 (checked above).
        unsafe { avx::tile_dirs(b, sx, sy, lanes, dirs) };
        return;
    }
    let mut l = lanes;
    while l != 0 {
        let k = l.trailing_zeros() as usize;
        l &= l - 1;
        dirs[k] = b.dir(sx[k % 8], sy[k / 8]);
    }
}

/// Sets `out[k]` to `from_unit(unit_o, to_unit.vector(dirs[k]))` for `k = ks[j]`, `j < n`
/// (`n ≤ 4`; the lanes past `n` are set up, not written, so `ks` holds valid indices there
/// too). `dirs` should have been written well before: gathered straight after narrower
/// stores, its loads would wait on them.
pub(crate) fn map_four(
    to_unit: &ToUnit,
    unit_o: DVec3,
    dirs: &[DVec3],
    n: usize,
    ks: &[usize; 4],
    out: &mut [Option<UnitRay>],
) {
    let n = n.min(4);
    // The lanes left for the scalar set-up: all of them without AVX2.
    let slow = match () {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the CPU has AVX and AVX2 (checked by the guard).
        () if avx2() => unsafe { avx::map_four(to_unit, unit_o, dirs, n, ks, out) },
        () => (1u32 << n) - 1,
    };
    scalar(to_unit, |_| unit_o, dirs, n, ks, slow, out);
}

/// [`map_four`] for rays from points of their own: lane `k`'s from `origins[k]`, mapped into
/// the cube by `to_unit.point` (the same operations, four at a time).
pub(crate) fn map_four_from(
    to_unit: &ToUnit,
    origins: &[DVec3],
    dirs: &[DVec3],
    n: usize,
    ks: &[usize; 4],
    out: &mut [Option<UnitRay>],
) {
    let n = n.min(4);
    let slow = match () {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the CPU has AVX and AVX2 (checked by the guard).
        () if avx2() => unsafe { avx::map_four_from(to_unit, origins, dirs, n, ks, out) },
        () => (1u32 << n) - 1,
    };
    scalar(to_unit, |j| to_unit.point(origins[ks[j]]), dirs, n, ks, slow, out);
}

/// The lanes `j < n` in `slow` set up one at a time, lane `ks[j]`'s from `unit_o(j)`.
fn scalar(
    to_unit: &ToUnit,
    unit_o: impl Fn(usize) -> DVec3,
    dirs: &[DVec3],
    n: usize,
    ks: &[usize; 4],
    slow: u32,
    out: &mut [Option<UnitRay>],
) {
    for j in (0..n).filter(|j| slow & (1 << j) != 0) {
        out[ks[j]] = UnitRay::from_unit(unit_o(j), to_unit.vector(dirs[ks[j]]));
    }
}

/// Whether the CPU runs [`avx::map_four`] and other AVX2 code (asked once).
#[cfg(target_arch = "x86_64")]
pub(super) fn avx2() -> bool {
    static HAS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *HAS.get_or_init(|| std::arch::is_x86_feature_detected!("avx") && std::arch::is_x86_feature_detected!("avx2"))
}

#[cfg(target_arch = "x86_64")]
mod avx {
    use super::*;
    use std::arch::x86_64::*;

    /// [`super::map_four`] in AVX2 vectors, one lane per ray; returns the lanes (`j < n`)
    /// left for the scalar set-up, writes the others.
    ///
    /// # Safety
    /// The CPU has AVX and AVX2.
    #[target_feature(enable = "avx,avx2")]
    pub(super) unsafe fn map_four(
        to_unit: &ToUnit,
        unit_o: DVec3,
        dirs: &[DVec3],
        n: usize,
        ks: &[usize; 4],
        out: &mut [Option<UnitRay>],
    ) -> u32 {
        if !unit_o.is_finite() {
            return (1u32 << n) - 1;
        }
        let o = [_mm256_set1_pd(unit_o.x), _mm256_set1_pd(unit_o.y), _mm256_set1_pd(unit_o.z)];
        map_four_at(to_unit, o, dirs, n, ks, out)
    }

    /// [`super::map_four_from`] in AVX2 vectors, as [`map_four`].
    ///
    /// # Safety
    /// The CPU has AVX and AVX2.
    #[target_feature(enable = "avx,avx2")]
    pub(super) unsafe fn map_four_from(
        to_unit: &ToUnit,
        origins: &[DVec3],
        dirs: &[DVec3],
        n: usize,
        ks: &[usize; 4],
        out: &mut [Option<UnitRay>],
    ) -> u32 {
        let lanes = (1u32 << n) - 1;
        let p = by_axis(origins, ks);
        let splat = |x: f64| _mm256_set1_pd(x);
        // `ToUnit::point`, component by component as glam forms it.
        let o: [__m256d; 3] = match to_unit {
            ToUnit::Scale { offset, inv_size } => {
                let s = splat(*inv_size);
                [0, 1, 2].map(|c| _mm256_add_pd(splat(offset[c]), _mm256_mul_pd(p[c], s)))
            }
            ToUnit::Affine(m) => {
                let (x, y, z, t) = (m.matrix3.x_axis, m.matrix3.y_axis, m.matrix3.z_axis, m.translation);
                [0, 1, 2].map(|c| {
                    let xy = _mm256_add_pd(_mm256_mul_pd(splat(x[c]), p[0]), _mm256_mul_pd(splat(y[c]), p[1]));
                    _mm256_add_pd(_mm256_add_pd(xy, _mm256_mul_pd(splat(z[c]), p[2])), splat(t[c]))
                })
            }
        };
        // Every lane's origin finite, or all go to the scalar set-up (past `n` a lane may
        // start anywhere: its ray is not written).
        let sign = splat(-0.0);
        let finite = o.iter().fold(_mm256_castsi256_pd(_mm256_set1_epi64x(-1)), |acc, &v| {
            _mm256_and_pd(acc, _mm256_cmp_pd::<_CMP_LT_OQ>(_mm256_andnot_pd(sign, v), splat(f64::INFINITY)))
        });
        if _mm256_movemask_pd(finite) as u32 & lanes != lanes {
            return lanes;
        }
        map_four_at(to_unit, o, dirs, n, ks, out)
    }

    /// [`super::tile_dirs`] in AVX2 vectors, four columns of a row at a time. Each direction
    /// is stored as `by_axis` loads it (its x and y in one 16-byte store, its z alone), so
    /// that the loads that set the rays up are forwarded from these stores.
    ///
    /// # Safety
    /// The CPU has AVX and AVX2.
    #[target_feature(enable = "avx,avx2")]
    pub(super) unsafe fn tile_dirs(b: &Basis, sx: &[f64; 8], sy: &[f64; 8], lanes: u64, dirs: &mut [DVec3]) {
        let splat = |x: f64| _mm256_set1_pd(x);
        let (f, r, u) = (b.forward, b.right, b.up);
        // SAFETY: each half of `sx` is four f64.
        let columns = unsafe { [_mm256_loadu_pd(sx.as_ptr()), _mm256_loadu_pd(sx.as_ptr().add(4))] };
        for q in 0..16 {
            if (lanes >> (4 * q)) & 0xF == 0 {
                continue;
            }
            let (sxv, syv) = (columns[q % 2], splat(sy[q / 2]));
            // `(forward + right * sx) + up * sy`, axis by axis as glam forms it.
            let v = [0, 1, 2].map(|c| {
                let fr = _mm256_add_pd(splat(f[c]), _mm256_mul_pd(splat(r[c]), sxv));
                _mm256_add_pd(fr, _mm256_mul_pd(splat(u[c]), syv))
            });
            // `normalize`: times `1 / sqrt((x·x + y·y) + z·z)`.
            let xy = _mm256_add_pd(_mm256_mul_pd(v[0], v[0]), _mm256_mul_pd(v[1], v[1]));
            let dot = _mm256_add_pd(xy, _mm256_mul_pd(v[2], v[2]));
            let recip = _mm256_div_pd(splat(1.0), _mm256_sqrt_pd(dot));
            let d = v.map(|c| _mm256_mul_pd(c, recip));
            // Lanes 0 and 2 (x, y) in `lo`, 1 and 3 in `hi`.
            let (lo, hi) = (_mm256_unpacklo_pd(d[0], d[1]), _mm256_unpackhi_pd(d[0], d[1]));
            let xy = [
                _mm256_castpd256_pd128(lo),
                _mm256_castpd256_pd128(hi),
                _mm256_extractf128_pd::<1>(lo),
                _mm256_extractf128_pd::<1>(hi),
            ];
            let mut z = [0f64; 4];
            // SAFETY: `z` holds four f64.
            unsafe { _mm256_storeu_pd(z.as_mut_ptr(), d[2]) };
            for (j, (xy, z)) in xy.into_iter().zip(z).enumerate() {
                let at = &mut dirs[4 * q + j];
                // SAFETY: `DVec3` is `repr(C)` (x, y, z): its first 16 bytes are x and y.
                unsafe { _mm_storeu_pd(std::ptr::from_mut(at).cast::<f64>(), xy) };
                at.z = z;
            }
        }
    }

    /// The vectors `v[ks[j]]` by axis, loaded straight from `v`: gathered through an array
    /// on the stack, two of the three vectors' loads straddled its narrower stores and waited
    /// on them (a fifth of [`map_four_at`]'s time).
    ///
    /// # Safety
    /// The CPU has AVX and AVX2.
    #[target_feature(enable = "avx,avx2")]
    #[inline]
    unsafe fn by_axis(v: &[DVec3], ks: &[usize; 4]) -> [__m256d; 3] {
        let w = ks.map(|k| &v[k]);
        // SAFETY: `DVec3` is `repr(C)` (x, y, z): its first 16 bytes are x and y.
        let xy = w.map(|v| unsafe { _mm_loadu_pd(std::ptr::from_ref(v).cast::<f64>()) });
        let (lo, hi) = (_mm256_set_m128d(xy[2], xy[0]), _mm256_set_m128d(xy[3], xy[1]));
        [_mm256_unpacklo_pd(lo, hi), _mm256_unpackhi_pd(lo, hi), _mm256_set_pd(w[3].z, w[2].z, w[1].z, w[0].z)]
    }

    /// The four lanes from the origins `o` (by axis, finite for the lanes `j < n`).
    ///
    /// # Safety
    /// The CPU has AVX and AVX2.
    #[target_feature(enable = "avx,avx2")]
    #[inline]
    unsafe fn map_four_at(
        to_unit: &ToUnit,
        o: [__m256d; 3],
        dirs: &[DVec3],
        n: usize,
        ks: &[usize; 4],
        out: &mut [Option<UnitRay>],
    ) -> u32 {
        let lanes = (1u32 << n) - 1;
        let splat = |x: f64| _mm256_set1_pd(x);
        let [wx, wy, wz] = by_axis(dirs, ks);
        // `ToUnit::vector`, component by component as glam forms it.
        let d: [__m256d; 3] = match to_unit {
            ToUnit::Scale { inv_size, .. } => {
                let s = splat(*inv_size);
                [_mm256_mul_pd(wx, s), _mm256_mul_pd(wy, s), _mm256_mul_pd(wz, s)]
            }
            ToUnit::Affine(m) => {
                let (x, y, z) = (m.matrix3.x_axis, m.matrix3.y_axis, m.matrix3.z_axis);
                [0, 1, 2].map(|c| {
                    let xy = _mm256_add_pd(_mm256_mul_pd(splat(x[c]), wx), _mm256_mul_pd(splat(y[c]), wy));
                    _mm256_add_pd(xy, _mm256_mul_pd(splat(z[c]), wz))
                })
            }
        };
        let sign = splat(-0.0);
        let a = d.map(|v| _mm256_andnot_pd(sign, v));
        // `from_unit`'s `larger(larger(a.x, a.y), a.z)`: `vmaxpd` keeps its first operand
        // only where it is greater, as `larger` does.
        let m = _mm256_max_pd(_mm256_max_pd(a[0], a[1]), a[2]);
        // Finite: every magnitude below infinity (false for NaN).
        let finite = a.iter().fold(_mm256_castsi256_pd(_mm256_set1_epi64x(-1)), |acc, &v| {
            _mm256_and_pd(acc, _mm256_cmp_pd::<_CMP_LT_OQ>(v, splat(f64::INFINITY)))
        });
        let ratio = _mm256_mul_pd(splat(PARALLEL_RATIO as f64), m);
        let parallel =
            a.iter().fold(_mm256_setzero_pd(), |acc, &v| _mm256_or_pd(acc, _mm256_cmp_pd::<_CMP_LT_OQ>(v, ratio)));
        // The rescale 2^-floor(log2 m) from m's biased exponent e: 2^(1023 − e) has biased
        // exponent 2046 − e (e = 2046 would give a subnormal: the scalar set-up takes it).
        let e = _mm256_and_si256(_mm256_srli_epi64::<52>(_mm256_castpd_si256(m)), _mm256_set1_epi64x(0x7FF));
        let huge = _mm256_castsi256_pd(_mm256_cmpeq_epi64(e, _mm256_set1_epi64x(2046)));
        let t_scale = _mm256_castsi256_pd(_mm256_slli_epi64::<52>(_mm256_sub_epi64(_mm256_set1_epi64x(2046), e)));
        let usable = _mm256_andnot_pd(
            _mm256_or_pd(parallel, huge),
            _mm256_and_pd(finite, _mm256_cmp_pd::<_CMP_GE_OQ>(m, splat(1e-300))),
        );
        let slow = !(_mm256_movemask_pd(usable) as u32) & lanes;
        // The cube entry: per axis the two plane crossings, folded as `from_unit` folds them
        // (its starting −∞ and +∞ give way to the first axis's values).
        let mut t_enter = _mm256_setzero_pd();
        let mut t_exit = _mm256_setzero_pd();
        for (i, &di) in d.iter().enumerate() {
            // `-origin` and `1 − origin` as `from_unit` forms them (negation is exact).
            let lo = _mm256_div_pd(_mm256_xor_pd(o[i], splat(-0.0)), di);
            let hi = _mm256_div_pd(_mm256_sub_pd(splat(1.0), o[i]), di);
            let (near, far) = (_mm256_min_pd(lo, hi), _mm256_max_pd(lo, hi));
            (t_enter, t_exit) =
                if i == 0 { (near, far) } else { (_mm256_max_pd(t_enter, near), _mm256_min_pd(t_exit, far)) };
        }
        let entered = _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_LE_OQ>(t_enter, t_exit)) as u32;
        let zero = _mm256_setzero_pd();
        let off = _mm256_or_pd(_mm256_cmp_pd::<_CMP_GT_OQ>(t_enter, zero), _mm256_cmp_pd::<_CMP_LT_OQ>(t_exit, zero));
        let t_offset = _mm256_and_pd(off, t_enter);
        let moved = [0, 1, 2].map(|i| _mm256_add_pd(o[i], _mm256_mul_pd(t_offset, d[i])));
        let scaled = d.map(|v| _mm256_mul_pd(v, t_scale));
        // f32 origins and directions; a negative direction mirrors its axis (its sign bit
        // picks the mirrored values, and its magnitude is the mirrored direction).
        let o32 = moved.map(|v| _mm256_cvtpd_ps(v));
        let d32 = scaled.map(|v| _mm256_cvtpd_ps(v));
        let sign32 = _mm_set1_ps(-0.0);
        let near_cube = o32.iter().fold(0xF, |acc, &v| {
            acc & _mm_movemask_ps(_mm_cmp_ps::<_CMP_LE_OQ>(_mm_andnot_ps(sign32, v), _mm_set1_ps(MAX_UNIT_ORIGIN)))
                as u32
        });
        let mirror = d32.map(|v| _mm_movemask_ps(v) as u32);
        let origin32 = [0, 1, 2].map(|i| _mm_blendv_ps(o32[i], _mm_sub_ps(_mm_set1_ps(1.0), o32[i]), d32[i]));
        let inv32 = d32.map(|v| _mm_div_ps(_mm_set1_ps(1.0), _mm_andnot_ps(sign32, v)));
        let origin64 = [0, 1, 2].map(|i| _mm256_blendv_pd(moved[i], _mm256_sub_pd(splat(1.0), moved[i]), scaled[i]));
        let dir64 = scaled.map(|v| _mm256_andnot_pd(sign, v));
        let f32s = |v: __m128| std::mem::transmute::<__m128, [f32; 4]>(v);
        let f64s = |v: __m256d| std::mem::transmute::<__m256d, [f64; 4]>(v);
        let (origin32, inv32) = (origin32.map(f32s), inv32.map(f32s));
        let (origin64, dir64) = (origin64.map(f64s), dir64.map(f64s));
        let (t_scale, t_offset) = (f64s(t_scale), f64s(t_offset));
        for j in 0..n {
            if slow & (1 << j) != 0 {
                continue;
            }
            out[ks[j]] = (entered & near_cube & (1 << j) != 0).then(|| UnitRay {
                origin: origin32.map(|v| v[j]),
                inv_dir: inv32.map(|v| v[j]),
                mirror: (mirror[0] >> j & 1) | (mirror[1] >> j & 1) << 1 | (mirror[2] >> j & 1) << 2,
                parallel: 0,
                t_scale: t_scale[j],
                t_offset: t_offset[j],
                origin64: origin64.map(|v| v[j]),
                dir64: dir64.map(|v| v[j]),
            });
        }
        slow
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use glam::{DAffine3, DMat3};

    /// Every field's bits (so −0.0 and 0.0 differ), or `None`.
    fn bits(r: &Option<UnitRay>) -> Option<Vec<u64>> {
        r.map(|r| {
            let mut v: Vec<u64> = r.origin.iter().chain(&r.inv_dir).map(|x| x.to_bits() as u64).collect();
            v.extend([r.mirror as u64, r.parallel as u64, r.t_scale.to_bits(), r.t_offset.to_bits()]);
            v.extend(r.origin64.iter().chain(&r.dir64).map(|x| x.to_bits()));
            v
        })
    }

    /// A direction component that tells set-ups apart: ordinary, zero of either sign,
    /// tiny against the others (parallel), huge, not finite.
    fn component(rng: &mut Rng) -> f64 {
        match rng.below(16) {
            0 => 0.0,
            1 => -0.0,
            2 => 1e-13 * (rng.f64() - 0.5),
            3 => 1e-305,
            4 => 1.7e308 * (rng.f64() - 0.5),
            5 => f64::NAN,
            6 => f64::NEG_INFINITY,
            7 => (rng.f64() - 0.5) * 2f64.powi(rng.below(120) as i32 - 60),
            _ => rng.f64() * 2.0 - 1.0,
        }
    }

    /// An origin in the unit cube's frame: inside, outside, far from and on the cube.
    fn origin(round: usize, rng: &mut Rng) -> DVec3 {
        match round % 5 {
            0 => DVec3::new(rng.f64(), rng.f64(), rng.f64()),
            1 => DVec3::new(-3.0 + rng.f64(), 0.5, 2.0 * rng.f64()),
            2 => DVec3::new(rng.f64() * 1e9, -1e9, 0.5),
            3 => DVec3::new(0.0, 1.0, rng.f64()),
            _ => DVec3::new(rng.f64() * 8.0 - 4.0, rng.f64() * 8.0 - 4.0, rng.f64() * 8.0 - 4.0),
        }
    }

    /// A tile's directions four at a time are `Basis::dir`'s bit for bit, for cameras of
    /// every size, field of view and orientation, tiles anywhere on the image (the slopes of
    /// pixels on and past its edges too) and any lanes asked for; the lanes asked for are
    /// all written.
    #[test]
    fn a_tiles_directions_are_basis_dir_bit_for_bit() {
        let mut rng = Rng::new(31);
        let mut compared = 0;
        for round in 0..3000 {
            let eye = DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 200.0 - 100.0;
            let target =
                eye + DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5) * 10f64.powi(round % 7 - 3);
            let up = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5);
            let camera = crate::scene::Camera {
                eye,
                target,
                up,
                vfov_deg: 1.0 + rng.f64() * 170.0,
                width: 1 + rng.below(4000) as u32,
                height: 1 + rng.below(4000) as u32,
            };
            let Ok(()) = camera.validate() else { continue };
            let b = camera.basis();
            let (x0, y0) = (rng.below(camera.width as u64 + 8) as u32, rng.below(camera.height as u64 + 8) as u32);
            let sx: [f64; 8] = std::array::from_fn(|i| camera.screen_x(&b, x0 + i as u32));
            let sy: [f64; 8] = std::array::from_fn(|i| camera.screen_y(&b, y0 + i as u32));
            let lanes = if round % 3 == 0 { u64::MAX } else { rng.next_u64() & rng.next_u64() };
            let mut dirs = [DVec3::splat(f64::NAN); 64];
            tile_dirs(&b, &sx, &sy, lanes, &mut dirs);
            for k in (0..64).filter(|k| lanes & (1 << k) != 0) {
                let want = b.dir(sx[k % 8], sy[k / 8]);
                assert_eq!(
                    dirs[k].to_array().map(f64::to_bits),
                    want.to_array().map(f64::to_bits),
                    "round {round}, lane {k}"
                );
                compared += 1;
            }
        }
        assert!(compared > 50_000, "{compared} directions compared");
    }

    /// Four lanes at a time set up the rays one at a time sets up, bit for bit, for both
    /// kinds of ray map (with an offset or a translation), origins inside, outside, far from
    /// and on the cube (one in the cube for all four lanes, or each lane's own before the
    /// map into it, now and then not finite), and the directions that take the scalar path;
    /// lanes not asked for are left alone.
    #[test]
    fn four_lanes_set_up_the_scalar_rays() {
        let mut rng = Rng::new(97);
        let (mut compared, mut vector_path, mut own_origins) = (0, 0, 0);
        for round in 0..12000 {
            let to_unit = if round % 2 == 0 {
                let offset = DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 4.0 - 2.0;
                ToUnit::Scale { offset, inv_size: 0.1 + rng.f64() * 4.0 }
            } else {
                let m = DMat3::from_cols_array(&[0.0; 9].map(|_| rng.f64() * 2.0 - 1.0));
                let t = DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 4.0 - 2.0;
                ToUnit::Affine(DAffine3::from_mat3_translation(m, t))
            };
            // A point the map takes near `u` in the cube (not finite where the map is singular).
            let back = |u: DVec3| match &to_unit {
                ToUnit::Scale { offset, inv_size } => (u - *offset) / *inv_size,
                ToUnit::Affine(m) => m.inverse().transform_point3(u),
            };
            // One origin in the cube for the four lanes in two rounds of three; in the third,
            // each lane's own, before the map into the cube.
            let own = round % 3 == 2;
            let mut shared = origin(round, &mut rng);
            let mut world: Vec<DVec3> = (0..8).map(|_| back(origin(rng.below(5) as usize, &mut rng))).collect();

            let dirs: Vec<DVec3> = (0..8)
                .map(|_| {
                    if rng.below(4) == 0 {
                        DVec3::new(component(&mut rng), component(&mut rng), component(&mut rng))
                    } else {
                        DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5)
                    }
                })
                .collect();
            let n = 1 + rng.below(4) as usize;
            let mut ks = [0usize; 4].map(|_| rng.below(8) as usize);
            ks[..n].sort_unstable();
            let mut unique = ks[..n].to_vec();
            unique.dedup();
            if unique.len() < n {
                continue;
            }
            if round % 97 == 0 {
                match own {
                    true => world[ks[rng.below(n as u64) as usize]] = DVec3::new(f64::NAN, 0.0, 0.0),
                    false => shared = DVec3::new(f64::NAN, 0.0, 0.0),
                }
            }
            let unit_o = |k: usize| if own { to_unit.point(world[k]) } else { shared };
            let marker = Some(UnitRay::from_unit(DVec3::splat(0.5), DVec3::X).expect("a ray"));
            let mut out = vec![marker; 8];
            match own {
                true => map_four_from(&to_unit, &world, &dirs, n, &ks, &mut out),
                false => map_four(&to_unit, shared, &dirs, n, &ks, &mut out),
            }
            let origins_finite = ks[..n].iter().all(|&k| unit_o(k).is_finite());
            for k in 0..8 {
                let asked = ks[..n].contains(&k);
                let expect = match asked {
                    true => UnitRay::from_unit(unit_o(k), to_unit.vector(dirs[k])),
                    false => marker,
                };
                let from = asked.then(|| unit_o(k));
                assert_eq!(bits(&out[k]), bits(&expect), "round {round}, lane {k}: {:?} from {from:?}", dirs[k]);
                compared += 1;
                let vector = expect.is_some_and(|r| r.parallel == 0) && origins_finite;
                vector_path += (asked && vector) as usize;
                own_origins += (asked && vector && own) as usize;
            }
        }
        assert!(
            compared > 60_000 && vector_path > 5_000 && own_origins > 1_000,
            "{compared} lanes, {vector_path} through the vectors, {own_origins} of them from origins of their own"
        );
    }
}
