//! The SIMD vectors a packet ([`super::packet`]) tests its rays in: four lanes (`wide::f32x4`,
//! SSE on x86-64's baseline) everywhere, and eight (AVX) where the CPU has them, picked at
//! run time so that one binary runs on every x86-64 CPU.
//!
//! Both widths do the same IEEE operations lane by lane (maximum and minimum with SSE's
//! operand order, ordered `≤`, add, subtract, multiply; no fused multiply-add), so a packet
//! answers bit for bit alike on either; the tests run both.

use std::ops::{Add, Index, IndexMut, Mul, Sub};
use wide::f32x4;

/// What a packet needs of a vector of `W` f32 lanes.
pub(crate) trait Lanes: Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> {
    /// Lanes per vector.
    const W: usize;
    /// One vector per group of `W` rays of a 64-ray packet.
    type Groups: Copy + Index<usize, Output = Self> + IndexMut<usize>;
    /// Every group zero.
    const ZERO_GROUPS: Self::Groups;
    /// Every lane `x`.
    fn splat(x: f32) -> Self;
    /// Lane-wise maximum; where a lane is NaN, `other`'s (SSE's `maxps`).
    fn fast_max(self, other: Self) -> Self;
    /// Lane-wise minimum; where a lane is NaN, `other`'s (SSE's `minps`).
    fn fast_min(self, other: Self) -> Self;
    /// Bit k set where lane k of `self ≤ other` (false for NaN).
    fn le_bits(self, other: Self) -> u64;
    /// Lane `k`.
    fn lane(self, k: usize) -> f32;
    /// Sets lane `k` to `x`.
    fn set_lane(&mut self, k: usize, x: f32);
}

impl Lanes for f32x4 {
    const W: usize = 4;
    type Groups = [f32x4; 16];
    const ZERO_GROUPS: Self::Groups = [f32x4::ZERO; 16];
    #[inline(always)]
    fn splat(x: f32) -> Self {
        f32x4::splat(x)
    }
    #[inline(always)]
    fn fast_max(self, other: Self) -> Self {
        f32x4::fast_max(self, other)
    }
    #[inline(always)]
    fn fast_min(self, other: Self) -> Self {
        f32x4::fast_min(self, other)
    }
    #[inline(always)]
    fn le_bits(self, other: Self) -> u64 {
        self.simd_le(other).to_bitmask() as u64
    }
    #[inline(always)]
    fn lane(self, k: usize) -> f32 {
        self.to_array()[k]
    }
    #[inline(always)]
    fn set_lane(&mut self, k: usize, x: f32) {
        bytemuck::cast_mut::<f32x4, [f32; 4]>(self)[k] = x;
    }
}

/// Eight lanes in an AVX register.
///
/// Only made on paths entered after [`avx8_supported`] said yes (the packet keeps its frames
/// of this type only then), which is what makes the intrinsics below sound. Every method is
/// always inlined, into functions compiled with AVX enabled.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
#[repr(transparent)]
pub(crate) struct Avx8(std::arch::x86_64::__m256);

/// Whether this CPU runs the eight-lane packet: AVX, and the bit instructions of the same
/// generation that its function attributes enable (the `target_feature` lists of
/// `Kernel for Avx8` in `traverse::packet` must name no feature that is not checked here).
#[cfg(target_arch = "x86_64")]
pub(crate) fn avx8_supported() -> bool {
    std::arch::is_x86_feature_detected!("avx")
        && std::arch::is_x86_feature_detected!("avx2")
        && std::arch::is_x86_feature_detected!("bmi1")
        && std::arch::is_x86_feature_detected!("bmi2")
        && std::arch::is_x86_feature_detected!("lzcnt")
        && std::arch::is_x86_feature_detected!("popcnt")
}

#[cfg(target_arch = "x86_64")]
mod avx {
    use super::{Avx8, Lanes};
    use std::arch::x86_64::*;
    use std::ops::{Add, Mul, Sub};

    // SAFETY (every `unsafe` block in this module): an `Avx8` exists only where the CPU has
    // AVX (see the type's notes); the intrinsics need nothing else.

    impl Lanes for Avx8 {
        const W: usize = 8;
        type Groups = [Avx8; 8];
        // SAFETY: `__m256` is eight f32 lanes; zero bits are 0.0 in each.
        const ZERO_GROUPS: Self::Groups = [Avx8(unsafe { std::mem::transmute::<[f32; 8], __m256>([0.0; 8]) }); 8];
        #[inline(always)]
        fn splat(x: f32) -> Self {
            Avx8(unsafe { _mm256_set1_ps(x) })
        }
        #[inline(always)]
        fn fast_max(self, other: Self) -> Self {
            Avx8(unsafe { _mm256_max_ps(self.0, other.0) })
        }
        #[inline(always)]
        fn fast_min(self, other: Self) -> Self {
            Avx8(unsafe { _mm256_min_ps(self.0, other.0) })
        }
        #[inline(always)]
        fn le_bits(self, other: Self) -> u64 {
            // `_CMP_LE_OS` is SSE's `cmpleps`.
            (unsafe { _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OS>(self.0, other.0)) } as u32) as u64
        }
        #[inline(always)]
        fn lane(self, k: usize) -> f32 {
            // SAFETY: `__m256` and `[f32; 8]` have the same size and every bit pattern is valid.
            let a = unsafe { std::mem::transmute::<__m256, [f32; 8]>(self.0) };
            a[k]
        }
        #[inline(always)]
        fn set_lane(&mut self, k: usize, x: f32) {
            // SAFETY: as for `lane`, and the array is this vector's own bytes.
            let a = unsafe { &mut *(&mut self.0 as *mut __m256).cast::<[f32; 8]>() };
            a[k] = x;
        }
    }

    impl Add for Avx8 {
        type Output = Self;
        #[inline(always)]
        fn add(self, other: Self) -> Self {
            Avx8(unsafe { _mm256_add_ps(self.0, other.0) })
        }
    }

    impl Sub for Avx8 {
        type Output = Self;
        #[inline(always)]
        fn sub(self, other: Self) -> Self {
            Avx8(unsafe { _mm256_sub_ps(self.0, other.0) })
        }
    }

    impl Mul for Avx8 {
        type Output = Self;
        #[inline(always)]
        fn mul(self, other: Self) -> Self {
            Avx8(unsafe { _mm256_mul_ps(self.0, other.0) })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The eight-lane vector against the four-lane one on values that tell the operations
    /// apart: NaN in either operand (which operand wins), ±0, infinities, ties.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn eight_lanes_answer_as_four() {
        if !avx8_supported() {
            return;
        }
        let vals = [0.0f32, -0.0, 1.0, -1.0, 0.5, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 3.0e-39, 7.25];
        let mut pairs = Vec::new();
        for &a in &vals {
            for &b in &vals {
                pairs.push((a, b));
            }
        }
        // Whole vectors: the last one padded with zeros.
        pairs.resize(pairs.len().div_ceil(8) * 8, (0.0, 0.0));
        for chunk in pairs.chunks(8) {
            let (mut a8, mut b8) = (Avx8::splat(0.0), Avx8::splat(0.0));
            let (mut a4, mut b4) = ([f32x4::ZERO; 2], [f32x4::ZERO; 2]);
            for (k, &(a, b)) in chunk.iter().enumerate() {
                a8.set_lane(k, a);
                b8.set_lane(k, b);
                a4[k / 4].set_lane(k % 4, a);
                b4[k / 4].set_lane(k % 4, b);
            }
            let bits = |x: f32| x.to_bits();
            let four = |f: &dyn Fn(f32x4, f32x4) -> f32x4, k: usize| f(a4[k / 4], b4[k / 4]).lane(k % 4);
            for k in 0..8 {
                assert_eq!(bits(a8.fast_max(b8).lane(k)), bits(four(&|x, y| x.fast_max(y), k)), "{:?}", chunk[k]);
                assert_eq!(bits(a8.fast_min(b8).lane(k)), bits(four(&|x, y| x.fast_min(y), k)), "{:?}", chunk[k]);
                assert_eq!(bits((a8 + b8).lane(k)), bits(four(&|x, y| x + y, k)), "{:?}", chunk[k]);
                assert_eq!(bits((a8 - b8).lane(k)), bits(four(&|x, y| x - y, k)), "{:?}", chunk[k]);
                assert_eq!(bits((a8 * b8).lane(k)), bits(four(&|x, y| x * y, k)), "{:?}", chunk[k]);
                let le8 = a8.le_bits(b8) >> k & 1;
                let le4 = a4[k / 4].le_bits(b4[k / 4]) >> (k % 4) & 1;
                assert_eq!(le8, le4, "{:?}", chunk[k]);
            }
        }
    }
}
