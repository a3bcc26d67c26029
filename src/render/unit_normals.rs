//! A hit voxel's normal in world space for an instance that is not turned
//! ([`ToUnit::Scale`](super::instances::ToUnit)): the stored normal decoded, then normalized
//! in f64 as [`super::cpu::hit_record`] does for every instance. Remembered per thread: the
//! two square roots and divisions were a seventh of a close-up frame, and neighbouring pixels
//! mostly hit voxels with the same stored normal.

use crate::svo::format::Attr;
use glam::Vec3;
use std::cell::Cell;

/// Slots of the per-thread table (direct-mapped by the normal's code).
const SLOTS: usize = 64;

/// No code: stored codes have 24 bits.
const EMPTY: u32 = u32::MAX;

thread_local! {
    static SEEN: [Cell<(u32, [f32; 3])>; SLOTS] = const { [const { Cell::new((EMPTY, [0.0; 3])) }; SLOTS] };
}

/// `attr.normal().as_dvec3().normalize_or_zero().as_vec3()`, bit for bit.
#[inline]
pub(crate) fn unturned(attr: Attr) -> Vec3 {
    // The decoded normal reads the low 24 bits (two 12-bit fields); the others hold the
    // material.
    let code = attr.normal & 0x00FF_FFFF;
    let slot = (code.wrapping_mul(0x9E37_79B1) >> (32 - SLOTS.trailing_zeros())) as usize;
    SEEN.with(|seen| {
        let (key, n) = seen[slot].get();
        if key == code {
            return Vec3::from_array(n);
        }
        let n = direct(attr);
        seen[slot].set((code, n.to_array()));
        n
    })
}

/// What [`unturned`] remembers.
fn direct(attr: Attr) -> Vec3 {
    attr.normal().as_dvec3().normalize_or_zero().as_vec3()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// Remembered normals are computed ones, bit for bit, whatever the material bits, as
    /// codes come back, collide in their slots and are evicted.
    #[test]
    fn remembered_normals_are_the_computed_ones() {
        let mut rng = Rng::new(5);
        // A few hundred codes, so that slots are shared and codes come back.
        let codes: Vec<u32> = (0..300).map(|_| rng.below(1 << 24) as u32).collect();
        for _ in 0..20_000 {
            let code = codes[rng.below(codes.len() as u64) as usize];
            let material = (rng.below(256) as u32) << 24;
            let attr = Attr { albedo: 0, normal: code | material, emission: 0 };
            let bits = |v: Vec3| v.to_array().map(f32::to_bits);
            assert_eq!(bits(unturned(attr)), bits(direct(attr)), "code {code:x}");
        }
    }
}
