//! Where GI's diffuse cones are gathered for the pixels: at every pixel, or at one pixel of
//! each 2×2 block with an edge-aware upsampling (the voxel-transformation paper gathers its
//! cones at half resolution too). A pixel between samples takes the bilinear blend of those
//! of its (up to four) nearest samples that lie on its own surface — a normal within about
//! 25° and a point within one voxel of its tangent plane — and gathers its own cones where
//! none does, so silhouettes and creases are never blurred across; a pixel on a sample is
//! that sample. The third way evaluates cones at a few radiance caches placed by clustering
//! the G-buffer's normals ([`super::radiance_cache`]).

use super::cpu::par_map;
use super::hitbuffer::HitRecord;
use super::radiance_cache::{CacheSettings, CacheStages};
use crate::scene::camera::Basis;
use crate::scene::Camera;
use glam::{DVec3, Vec3, Vec4};

/// How the diffuse cones are gathered for the pixels (`--gi-gather`). The default is the
/// radiance caches: in docs/accuracy.md's sweep they err less than the per-pixel cones on the
/// box and the panel room in about the same GI time, but flicker more on a moving scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Gather {
    /// Every pixel gathers its own cones.
    Pixels,
    /// One pixel in four gathers; the others blend the samples on their own surface.
    Half,
    /// Cones at clustered radiance caches, blended at the pixels (diffuse and glossy).
    Caches(CacheSettings),
}

impl Default for Gather {
    fn default() -> Self {
        Gather::Caches(CacheSettings::default())
    }
}

impl std::str::FromStr for Gather {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "pixels" => Ok(Gather::Pixels),
            "half" => Ok(Gather::Half),
            "caches" => Ok(Gather::Caches(CacheSettings::default())),
            other => Err(format!("unknown GI gather '{other}' (use pixels, half or caches)")),
        }
    }
}

/// Smallest cosine between a pixel's normal and a sample's it blends (about 25°).
pub(crate) const SAME_NORMAL: f32 = 0.9;

/// The diffuse light of every pixel that needs it, and the fraction of its cones that
/// escaped (ambient occlusion; 1 where nothing was gathered).
pub(crate) struct Gathered {
    /// Diffuse cone light before the albedo, per pixel.
    pub light: Vec<Vec3>,
    /// Unoccluded fraction of the cones, per pixel.
    pub open: Vec<f32>,
    /// Points where cones were gathered (samples and pixels that gathered their own).
    pub gathers: u64,
    /// With caches: each pixel's glossy light from them (None: trace its own specular cone).
    pub glossy: Vec<Option<Vec3>>,
    /// With caches: where their time went.
    pub stages: Option<CacheStages>,
}

/// What a cone needs and gives: `cone(origin, normal, direction, full aperture)` is the
/// radiance arriving (the sky where the cone escapes) and, in w, the fraction that escaped.
pub type ConeFn<'a> = &'a (dyn Fn(DVec3, DVec3, DVec3, f64) -> Vec4 + Sync);

/// The solid angle (steradians) of a cone of full aperture `aperture` (radians).
pub fn cone_solid_angle(aperture: f64) -> f64 {
    std::f64::consts::TAU * (1.0 - (0.5 * aperture).cos())
}

/// Gathers the diffuse light at the pixels for which `needed(x, y)` holds (hits to be
/// shaded), with `diffuse(record, point)` giving the cones' light and open fraction.
pub(crate) fn gather(
    mode: Gather,
    records: &[HitRecord],
    camera: &Camera,
    basis: &Basis,
    diffuse: &(dyn Fn(&HitRecord, DVec3) -> (Vec3, f32) + Sync),
    cone: Option<ConeFn<'_>>,
    needed: &(dyn Fn(usize, usize) -> bool + Sync),
) -> Gathered {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let point = |x: usize, y: usize| {
        let r = &records[y * w + x];
        camera.eye + camera.ray_dir(basis, x as u32, y as u32) * r.t as f64
    };
    let own = |x: usize, y: usize| diffuse(&records[y * w + x], point(x, y));
    match mode {
        Gather::Pixels => {
            let out = par_map(w * h, |k| needed(k % w, k / w).then(|| own(k % w, k / w)));
            let gathers = out.iter().filter(|o| o.is_some()).count() as u64;
            let (light, open) = out.into_iter().map(|o| o.unwrap_or((Vec3::ZERO, 1.0))).unzip();
            Gathered { light, open, gathers, glossy: Vec::new(), stages: None }
        }
        Gather::Caches(s) => {
            let Some(cone) = cone else {
                return gather(Gather::Pixels, records, camera, basis, diffuse, None, needed);
            };
            let hit = |x: u32, y: u32| {
                let (x, y) = (x as usize, y as usize);
                needed(x, y).then(|| (point(x, y), records[y * w + x].normal.as_dvec3().normalize_or(DVec3::Y)))
            };
            let mut stages = CacheStages::default();
            let caches = super::radiance_cache::build(&s, camera, &hit, cone, &mut stages);
            let start = std::time::Instant::now();
            let out = par_map(w * h, |k| {
                let (x, y) = (k % w, k / w);
                if !needed(x, y) {
                    return None;
                }
                let r = &records[k];
                let (p, n) = (point(x, y), r.normal.as_dvec3().normalize_or(DVec3::Y));
                let footprint = super::radiance_cache::footprint(camera, basis, r.t as f64);
                let (e, weight) = caches.blend(s.radius, x as u32, y as u32, p, n, footprint);
                let (light, open, own) = if weight > 0.0 {
                    (e.truncate(), e.w, false)
                } else {
                    let (l, o) = own(x, y);
                    (l, o, true)
                };
                let glossy = (r.attr.specular() > 0.0).then(|| {
                    let d = camera.ray_dir(basis, x as u32, y as u32);
                    let reflected = super::brdf::reflect(d, n).normalize();
                    let shininess = super::brdf::shininess_of_gloss_bits(r.attr.gloss_bits());
                    let omega = cone_solid_angle(super::brdf::cone_aperture(shininess));
                    caches.glossy(s.radius, x as u32, y as u32, p, n, footprint, reflected, omega)
                });
                Some((light, open, own, glossy.flatten()))
            });
            stages.gathering_ms = start.elapsed().as_secs_f64() * 1e3;
            let gathers = out.iter().filter(|o| o.as_ref().is_some_and(|o| o.2)).count() as u64;
            let mut light = Vec::with_capacity(w * h);
            let mut open = Vec::with_capacity(w * h);
            let mut glossy = Vec::with_capacity(w * h);
            for o in out {
                let (l, a, _, g) = o.unwrap_or((Vec3::ZERO, 1.0, false, None));
                light.push(l);
                open.push(a);
                glossy.push(g);
            }
            Gathered { light, open, gathers, glossy, stages: Some(stages) }
        }
        Gather::Half => {
            let (lw, lh) = (w.div_ceil(2), h.div_ceil(2));
            // Sample (i, j) sits on pixel (2i, 2j) and serves the pixels next to it.
            let samples = par_map(lw * lh, |s| {
                let (x, y) = (2 * (s % lw), 2 * (s / lw));
                let serves = (x.saturating_sub(1)..=(x + 1).min(w - 1))
                    .any(|px| (y.saturating_sub(1)..=(y + 1).min(h - 1)).any(|py| needed(px, py)));
                (serves && records[y * w + x].instance >= 0).then(|| (own(x, y), point(x, y)))
            });
            let mut gathers = samples.iter().filter(|s| s.is_some()).count() as u64;
            let out = par_map(w * h, |k| {
                let (x, y) = (k % w, k / w);
                if !needed(x, y) {
                    return None;
                }
                let r = &records[k];
                let (p, n) = (point(x, y), r.normal);
                let tolerance = r.voxel as f64;
                let near =
                    |c: usize, limit: usize| if c % 2 == 0 { c / 2..c / 2 + 1 } else { c / 2..(c / 2 + 2).min(limit) };
                let (mut light, mut open, mut weight) = (Vec3::ZERO, 0.0f32, 0.0f32);
                for j in near(y, lh) {
                    for i in near(x, lw) {
                        let Some(((l, o), q)) = samples[j * lw + i] else { continue };
                        let sn = records[2 * j * w + 2 * i].normal;
                        if n.dot(sn) >= SAME_NORMAL && n.as_dvec3().dot(q - p).abs() <= tolerance {
                            light += l;
                            open += o;
                            weight += 1.0;
                        }
                    }
                }
                Some(if weight > 0.0 { Ok((light / weight, open / weight)) } else { Err(own(x, y)) })
            });
            gathers += out.iter().filter(|o| matches!(o, Some(Err(_)))).count() as u64;
            let (light, open) = out
                .into_iter()
                .map(|o| match o {
                    Some(Ok(v) | Err(v)) => v,
                    None => (Vec3::ZERO, 1.0),
                })
                .unzip();
            Gathered { light, open, gathers, glossy: Vec::new(), stages: None }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two walls facing the camera, at depths 5 and 8, meeting at an odd column (so blocks
    /// straddle the step), with the sky above; the light is constant on each wall.
    fn step_scene(w: u32, h: u32) -> (Camera, Vec<HitRecord>) {
        let camera = Camera { eye: DVec3::ZERO, target: DVec3::Z, up: DVec3::Y, vfov_deg: 60.0, width: w, height: h };
        let basis = camera.basis();
        let records = (0..w * h)
            .map(|k| {
                let (x, y) = (k % w, k / w);
                if y < 3 {
                    return HitRecord::MISS;
                }
                let (depth, instance) = if x < 2 * (w / 4) + 1 { (5.0, 0) } else { (8.0, 1) };
                let d = camera.ray_dir(&basis, x, y);
                HitRecord { t: (depth / d.z) as f32, instance, normal: -Vec3::Z, voxel: 0.01, ..HitRecord::MISS }
            })
            .collect();
        (camera, records)
    }

    #[test]
    fn half_gathers_a_quarter_and_never_blends_across_a_step() {
        let (w, h) = (34, 23);
        let (camera, records) = step_scene(w, h);
        let basis = camera.basis();
        let light = |r: &HitRecord, _: DVec3| (Vec3::splat(1.0 + r.instance as f32), 0.25 + 0.5 * r.instance as f32);
        let needed = |x: usize, y: usize| records[y * w as usize + x].instance >= 0;
        let full = gather(Gather::Pixels, &records, &camera, &basis, &light, None, &needed);
        let half = gather(Gather::Half, &records, &camera, &basis, &light, None, &needed);
        let hits = records.iter().filter(|r| r.instance >= 0).count() as u64;
        assert_eq!(full.gathers, hits);
        // A quarter of the pixels, plus those beside the step that no sample on their own wall
        // serves (the odd column's block straddles it) and gather their own.
        assert!(half.gathers < hits * 3 / 10, "{} gathers for {hits} hits", half.gathers);
        // Every pixel gets its own wall's light exactly: nothing is blended across the step.
        assert_eq!(half.light, full.light);
        assert_eq!(half.open, full.open);
        assert!(records.iter().zip(&half.open).all(|(r, &o)| r.instance >= 0 || o == 1.0));
    }

    #[test]
    fn half_blends_a_smooth_light_between_its_samples() {
        // Light that varies linearly across one wall: the blend of the two or four samples
        // around a pixel is its own value (up to rounding), the samples' pixels exactly.
        let (w, h) = (16, 12);
        let camera = Camera { eye: DVec3::ZERO, target: DVec3::Z, up: DVec3::Y, vfov_deg: 40.0, width: w, height: h };
        let basis = camera.basis();
        let records: Vec<HitRecord> = (0..w * h)
            .map(|k| {
                let d = camera.ray_dir(&basis, k % w, k / w);
                HitRecord { t: (5.0 / d.z) as f32, instance: 0, normal: -Vec3::Z, voxel: 0.01, ..HitRecord::MISS }
            })
            .collect();
        let light = |_: &HitRecord, p: DVec3| (Vec3::splat(2.0 + p.x as f32), 1.0);
        let needed = |_: usize, _: usize| true;
        let full = gather(Gather::Pixels, &records, &camera, &basis, &light, None, &needed);
        let half = gather(Gather::Half, &records, &camera, &basis, &light, None, &needed);
        for k in 0..(w * h) as usize {
            let (x, y) = (k % w as usize, k / w as usize);
            let last = x == w as usize - 1 && x % 2 == 1 || y == h as usize - 1 && y % 2 == 1;
            if x % 2 == 0 && y % 2 == 0 {
                assert_eq!(half.light[k], full.light[k], "sample pixel ({x}, {y})");
            } else if !last {
                assert!((half.light[k] - full.light[k]).abs().max_element() < 1e-4, "({x}, {y})");
            }
        }
        assert_eq!(half.gathers, ((w / 2) * (h / 2)) as u64);
    }
}
