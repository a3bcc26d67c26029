//! A hit voxel's normal in world space, as [`super::cpu::hit_record`] forms it (the stored
//! normal decoded, mapped by the instance and normalized in f64), remembered per thread.
//! Formed anew for every hit, with two square roots and divisions, it cost a whole close-up
//! frame 3–4 % (docs/benchmarks.md, steps 129 and 130), and neighbouring pixels mostly hit
//! voxels with the same stored normal on the same instance.
//!
//! An instance that is not turned ([`ToUnit::Scale`](super::instances::ToUnit)) leaves the
//! normal's direction alone, so its normal depends on the stored code only ([`unturned`]).
//! A turned one's depends on its map too, which changes from frame to frame: [`turned`]
//! keys it by the instance and a key that only one frame has ([`frame_key`]).

use crate::svo::format::Attr;
use glam::Vec3;
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

/// Slots of the per-thread table (direct-mapped by the normal's code and instance).
const SLOTS: usize = 64;

/// The frame key of an unturned instance's normals, which hold in every frame ([`frame_key`]
/// never reaches it).
const ANY_FRAME: u64 = u64::MAX;

/// A remembered normal.
#[derive(Clone, Copy)]
struct Remembered {
    /// [`frame_key`] of the frame, or [`ANY_FRAME`] (0: none).
    frame: u64,
    instance: usize,
    code: u32,
    normal: [f32; 3],
}

thread_local! {
    static SEEN: [Cell<Remembered>; SLOTS] = const {
        [const { Cell::new(Remembered { frame: 0, instance: 0, code: 0, normal: [0.0; 3] }) }; SLOTS]
    };
}

/// The last frame key given out.
static FRAMES: AtomicU64 = AtomicU64::new(0);

/// A key that no other call has had (never 0): a frame takes one once its instances are
/// prepared, and they stay as they are while it traces.
pub(crate) fn frame_key() -> u64 {
    FRAMES.fetch_add(1, Ordering::Relaxed) + 1
}

/// `attr.normal().as_dvec3().normalize_or_zero().as_vec3()`, bit for bit.
#[inline]
pub(crate) fn unturned(attr: Attr) -> Vec3 {
    remembered(ANY_FRAME, 0, attr, || direct(attr))
}

/// `to_world(attr.normal())` for instance `instance` of the frame with key `frame`
/// ([`frame_key`]), where `to_world` is that instance's map of normals in that frame.
#[inline]
pub(crate) fn turned(frame: u64, instance: usize, attr: Attr, to_world: impl FnOnce(Vec3) -> Vec3) -> Vec3 {
    remembered(frame, instance, attr, || to_world(attr.normal()))
}

/// `normal()` of `attr`'s stored code on `instance` in frame `frame`, remembered.
#[inline]
fn remembered(frame: u64, instance: usize, attr: Attr, normal: impl FnOnce() -> Vec3) -> Vec3 {
    // The decoded normal reads the low 24 bits (two 12-bit fields); the others hold the
    // material.
    let code = attr.normal & 0x00FF_FFFF;
    let mixed = code ^ (instance as u32).wrapping_mul(0x85EB_CA6B);
    let slot = (mixed.wrapping_mul(0x9E37_79B1) >> (32 - SLOTS.trailing_zeros())) as usize;
    SEEN.with(|seen| {
        let r = seen[slot].get();
        if r.frame == frame && r.instance == instance && r.code == code {
            return Vec3::from_array(r.normal);
        }
        let n = normal();
        seen[slot].set(Remembered { frame, instance, code, normal: n.to_array() });
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

    /// A turned instance's remembered normals are its map's, frame by frame: a later frame
    /// whose maps differ gets its own, whichever instance and code come back.
    #[test]
    fn turned_normals_follow_each_frames_maps() {
        let mut rng = Rng::new(8);
        let codes: Vec<u32> = (0..100).map(|_| rng.below(1 << 24) as u32).collect();
        let bits = |v: Vec3| v.to_array().map(f32::to_bits);
        for round in 0..6 {
            let frame = frame_key();
            // Each frame turns each of its three instances its own way.
            let angle = |instance: usize| 0.3 * round as f32 + instance as f32;
            let map = |instance: usize, n: Vec3| glam::Quat::from_rotation_y(angle(instance)) * n;
            for _ in 0..3_000 {
                let (instance, code) = (rng.below(3) as usize, codes[rng.below(codes.len() as u64) as usize]);
                let attr = Attr { albedo: 0, normal: code | (rng.below(256) as u32) << 24, emission: 0 };
                let got = turned(frame, instance, attr, |n| map(instance, n));
                assert_eq!(bits(got), bits(map(instance, attr.normal())), "frame {round}, instance {instance}");
            }
        }
    }
}
