//! `cast::SceneCaster` against the brute-force DDA oracle of every instance, and against the
//! plain "trace every instance" search bit for bit; batches against single rays; bad rays
//! and scenes.

mod common;

use glam::{DQuat, DVec3, Vec3};
use std::sync::Arc;
use voxray::cast::{CastError, CastRay, SceneCaster};
use voxray::oracle::{dda, Contact, VoxelSet};
use voxray::render::instances::prepare_into;
use voxray::render::visibility::{nearest, FrameInstances, Search};
use voxray::rng::Rng;
use voxray::scene::{Instance, Scene, Transform};
use voxray::stability::{check, scene_blobs, Ray64, TOUCH_TOLERANCE};
use voxray::svo::{self, Cube};
use voxray::voxelize::VoxelGrid;

const DEPTH: u32 = 6;

/// `n` instances of one blobby part on a grid 4 units apart, each turned, scaled by 0.5–1.5
/// per axis and one in three mirrored (their spheres, at most 1.3 across, never overlap);
/// with the part's voxels.
fn scene(n: usize, seed: u64) -> (Scene, Vec<[u32; 3]>) {
    let coords = scene_blobs(DEPTH, 5);
    let grid = VoxelGrid::from_coords(DEPTH, Cube { min: Vec3::ZERO, size: 1.0 }, coords.iter().copied(), Vec3::ONE);
    let mut scene = Scene::new(vec![Arc::new(svo::build(&grid).unwrap())]);
    let mut rng = Rng::new(seed);
    for i in 0..n {
        let mut scale = DVec3::new(0.5 + rng.f64(), 0.5 + rng.f64(), 0.5 + rng.f64());
        if i % 3 == 1 {
            scale.y = -scale.y;
        }
        let rotation = DQuat::from_axis_angle(rng.unit_vector().as_dvec3(), rng.f64() * std::f64::consts::TAU);
        let at = DVec3::new((i % 4) as f64, (i / 4 % 4) as f64, (i / 16) as f64) * 4.0;
        // The part's centre (0.5, 0.5, 0.5) placed at `at`.
        let translation = at - rotation * (scale * 0.5);
        let local = Transform::new(translation, rotation, scale).unwrap();
        scene.add(Instance { part: 0, parent: None, local }).unwrap();
    }
    scene.update().unwrap();
    (scene, coords)
}

/// Rays from around the grid: half aimed at an occupied voxel's centre of a random instance,
/// half in random directions (mostly misses).
fn rays(scene: &Scene, coords: &[[u32; 3]], count: usize, seed: u64) -> Vec<CastRay> {
    let mut rng = Rng::new(seed);
    let n = scene.instances().len();
    let reach = DVec3::new(16.0, 16.0, 4.0 * n.div_ceil(16) as f64);
    (0..count)
        .map(|k| {
            let origin = DVec3::new(rng.f64(), rng.f64(), rng.f64()) * (reach + 12.0) - 6.0;
            if k % 2 == 0 {
                let i = rng.below(n as u64) as usize;
                let c = coords[rng.below(coords.len() as u64) as usize];
                let centre = (glam::UVec3::from(c).as_dvec3() + 0.5) / (1u64 << DEPTH) as f64;
                CastRay::new(origin, scene.world(i).transform_point3(centre) - origin)
            } else {
                CastRay::new(origin, rng.unit_vector().as_dvec3() * (0.1 + 3.0 * rng.f64()))
            }
        })
        .collect()
}

/// Instance `i`'s view of a world ray (unit direction): the ray in its unit cube, the same t.
fn in_instance(scene: &Scene, i: usize, origin: DVec3, d: DVec3) -> Ray64 {
    let to_unit = scene.world(i).inverse();
    Ray64 {
        origin: to_unit.transform_point3(origin),
        dir: to_unit.transform_vector3(d),
        t_min: 0.0,
        t_max: f64::INFINITY,
    }
}

/// Every ray's answer against the oracle: a hit is the voxel the DDA finds in its instance
/// (within the stability suite's tolerance), and no instance holds a voxel the ray meets
/// clearly nearer; a miss meets no voxel of any instance.
fn check_against_the_oracle(n: usize, seed: u64) {
    let (scene, coords) = scene(n, seed);
    let rays = rays(&scene, &coords, 3000, seed + 1);
    check_rays(&scene, &coords, &rays);
}

/// [`check_against_the_oracle`] of given rays.
fn check_rays(scene: &Scene, coords: &[[u32; 3]], rays: &[CastRay]) {
    let n = scene.instances().len();
    let set = VoxelSet::new(DEPTH, coords.iter().copied());
    let caster = SceneCaster::new(scene).unwrap();
    let (mut hits, mut mismatches) = (0, Vec::new());
    for (k, r) in rays.iter().enumerate() {
        let d = r.dir.normalize();
        let got = caster.nearest(r.origin, r.dir);
        for i in 0..n {
            let ray = in_instance(scene, i, r.origin, d);
            let report = match got {
                Some(h) if h.instance == i => check(&set, &ray, Some(h.voxel), 0, false),
                // Another instance's voxel must not come clearly before the hit (or at all,
                // for a miss): a touch shorter than the suite's tolerance does not count.
                _ => {
                    let limit = got.map_or(f64::INFINITY, |h| h.t * (1.0 - 1e-5) - 1e-6);
                    let overlap = TOUCH_TOLERANCE * (1.0 / ray.dir.abs().max_element());
                    let nearer = dda(&set, ray.origin, ray.dir, 0.0, limit, Contact::MinOverlap(overlap));
                    if let Some(o) = nearer {
                        mismatches.push(format!("ray {k}: instance {i} at t {} before {got:?}", o.t));
                    }
                    continue;
                }
            };
            if report.mismatches > 0 {
                mismatches.push(format!("ray {k}: {:?}", report.first_mismatch));
            }
        }
        if let Some(h) = got {
            hits += 1;
            assert!((h.position - (r.origin + d * h.t)).length() < 1e-9 * (1.0 + h.t), "ray {k}: position");
            assert!((h.normal.length() - 1.0).abs() < 1e-9, "ray {k}: normal {:?}", h.normal);
            assert_eq!(h.part, 0);
        }
    }
    assert!(
        mismatches.is_empty(),
        "{} of {} rays: {:?}",
        mismatches.len(),
        rays.len(),
        &mismatches[..3.min(mismatches.len())]
    );
    // Aimed rays mostly hit, random ones mostly miss: both kinds were tested.
    assert!(hits > rays.len() / 4 && hits < rays.len() * 3 / 4, "{hits} hits of {}", rays.len());
}

#[test]
fn hits_through_the_instance_bvh_are_the_oracles() {
    check_against_the_oracle(48, 7);
}

#[test]
fn hits_among_few_instances_are_the_oracles() {
    check_against_the_oracle(6, 11);
}

/// Instances far from each other and from the reference point (the scene's centre, half a
/// million units from either): rays from a few units away still hit what the oracle hits.
#[test]
fn far_apart_instances_are_hit_as_the_oracle_says() {
    let (mut scene, coords) = scene(2, 13);
    let far = [DVec3::ZERO, DVec3::new(1.0e6, -3.0e4, 2.5e5)];
    for (i, at) in far.iter().enumerate() {
        let mut local = scene.instances()[i].local;
        local.translation += *at;
        scene.set_local(i, local).unwrap();
    }
    scene.update().unwrap();
    let mut rng = Rng::new(17);
    let rays: Vec<CastRay> = (0..2000)
        .map(|k| {
            let target = scene.world(k % 2).transform_point3(DVec3::new(rng.f64(), rng.f64(), rng.f64()));
            let origin = target + rng.unit_vector().as_dvec3() * (2.0 + 5.0 * rng.f64());
            CastRay::new(origin, target - origin)
        })
        .collect();
    check_rays(&scene, &coords, &rays);
}

/// The batches give each ray's single answer, and every answer is bit for bit the plain
/// search's (every instance traced over the whole ray), as the renderer's searches are:
/// through the instance BVH (48 instances, each ray alone) and among few instances (runs of
/// rays as packets).
#[test]
fn batches_and_the_plain_search_give_the_same_hits() {
    check_batches(48, 3);
}

#[test]
fn packets_of_few_instances_and_the_plain_search_give_the_same_hits() {
    check_batches(7, 5);
}

/// Rays for the batches: [`rays`] (each from a point of its own), then fans of camera rays
/// from one point over the grid (runs of one origin, a few without a direction among them),
/// and from one far point (50 times the grid's size away: the instance BVH's f32 walk does not
/// answer for it, the binary walk does) rays at the instances' voxels, in a count that leaves
/// a last run short.
fn batch_rays(scene: &Scene, coords: &[[u32; 3]], seed: u64) -> Vec<CastRay> {
    let mut all = rays(scene, coords, 2000, seed);
    let (lo, hi) = scene.bounds();
    let mut rng = Rng::new(seed + 1);
    for view in 0..3 {
        let eye = (lo + hi) * 0.5 + rng.unit_vector().as_dvec3() * (hi - lo).length();
        let ahead = ((lo + hi) * 0.5 - eye).normalize();
        let side = ahead.cross(DVec3::Z).normalize();
        let up = side.cross(ahead);
        for y in 0..24 {
            for x in 0..40 {
                let (sx, sy) = (x as f64 / 40.0 - 0.5, y as f64 / 24.0 - 0.5);
                let dir = if (x + y + view) % 97 == 0 { DVec3::ZERO } else { ahead + side * sx + up * sy * 0.6 };
                all.push(CastRay::new(eye, dir));
            }
        }
    }
    let far = (lo + hi) * 0.5 + rng.unit_vector().as_dvec3() * (hi - lo).length() * 50.0;
    for k in 0..960 {
        let i = rng.below(scene.instances().len() as u64) as usize;
        let c = coords[rng.below(coords.len() as u64) as usize];
        let centre = (glam::UVec3::from(c).as_dvec3() + 0.5) / (1u64 << DEPTH) as f64;
        let dir = if k % 97 == 0 { DVec3::ZERO } else { scene.world(i).transform_point3(centre) - far };
        all.push(CastRay::new(far, dir));
    }
    all.truncate(all.len() - 13);
    all
}

/// [`batches_and_the_plain_search_give_the_same_hits`] over `n` instances.
fn check_batches(n: usize, seed: u64) {
    let (scene, coords) = scene(n, seed);
    let reference = DVec3::new(1.0, 2.0, 3.0);
    let caster = SceneCaster::with(&scene, reference, u32::MAX).unwrap();
    assert_eq!(caster.instances(), n);
    let rays = batch_rays(&scene, &coords, seed + 1);
    let all = caster.nearest_all(&rays);
    // Into a buffer that held another batch's answers: the same.
    let mut kept = caster.nearest_all(&rays[..777]);
    caster.nearest_into(&rays, &mut kept);
    assert!(kept == all, "nearest_into differs from nearest_all");
    let mut prepared = Vec::new();
    prepare_into(&scene, reference, true, u32::MAX, &mut prepared);
    let fi = FrameInstances { parts: &scene.parts, prepared: &prepared, bvh: None, starts: None };
    let opts = voxray::traverse::TraceOptions::default();
    for (k, (r, batch)) in rays.iter().zip(&all).enumerate() {
        assert_eq!(*batch, caster.nearest(r.origin, r.dir), "ray {k}");
        let plain = nearest(&fi, r.origin - reference, r.dir.normalize(), Search::Plain, &opts);
        assert_eq!(batch.map(|h| (h.instance, h.voxel)), plain.map(|p| (p.instance, p.hit)), "ray {k}");
    }
    // Occlusion: a hit blocks past its distance, not short of it; a miss blocks nothing.
    let far = caster.occluded_all(&rays);
    let mut kept = vec![true; 5];
    caster.occluded_into(&rays, &mut kept);
    assert!(kept == far, "occluded_into differs from occluded_all");
    for (k, (h, blocked)) in all.iter().zip(&far).enumerate() {
        assert_eq!(*blocked, h.is_some(), "ray {k}");
    }
    assert!(all.iter().filter(|h| h.is_some()).count() > rays.len() / 5, "too few hits to tell");
    // (The far rays, the last 947, hit too.)
    assert!(all[rays.len() - 947..].iter().filter(|h| h.is_some()).count() > 300, "too few far hits");
    let hit_rays: Vec<(CastRay, f64)> =
        rays.iter().zip(&all).filter_map(|(r, h)| h.filter(|h| h.t > 1e-3).map(|h| (*r, h.t))).collect();
    assert!(hit_rays.len() > 100);
    for (r, t) in &hit_rays {
        assert!(caster.occluded(r.origin, r.dir, t * 1.001 + 1e-6), "{r:?} within {t}");
        assert!(!caster.occluded(r.origin, r.dir, t * 0.999), "{r:?} short of {t}");
    }
    // Each ray's own reach, in batches: short of its hit, nothing; past it, the same hit;
    // within reaches mixed with ones that are not above 0 or not a number, the single answers.
    let short: Vec<CastRay> = hit_rays.iter().map(|(r, t)| r.up_to(t * 0.999)).collect();
    let long: Vec<CastRay> = hit_rays.iter().map(|(r, t)| r.up_to(t * 1.001 + 1e-6)).collect();
    assert!(caster.occluded_all(&short).iter().all(|&b| !b));
    assert!(caster.occluded_all(&long).iter().all(|&b| b));
    let reaches = [f64::NAN, 0.0, -1.0, 0.5, 3.0, f64::INFINITY];
    let mixed: Vec<CastRay> = rays.iter().enumerate().map(|(k, r)| r.up_to(reaches[k % reaches.len()])).collect();
    for (k, (r, blocked)) in mixed.iter().zip(caster.occluded_all(&mixed)).enumerate() {
        assert_eq!(blocked, caster.occluded(r.origin, r.dir, r.t_max), "ray {k}: {r:?}");
    }
    assert!(caster.nearest_all(&short).iter().all(Option::is_none));
    for ((r, t), h) in hit_rays.iter().zip(caster.nearest_all(&long)) {
        assert_eq!(h.map(|h| h.t), Some(*t), "{r:?}");
    }
}

#[test]
fn rays_without_a_direction_hit_nothing_and_bad_scenes_are_refused() {
    let (mut scene, _) = scene(4, 9);
    let caster = SceneCaster::new(&scene).unwrap();
    let centre = scene.world(0).transform_point3(DVec3::splat(0.5));
    let bad = [
        CastRay::new(DVec3::NAN, DVec3::X),
        CastRay::new(DVec3::ZERO, DVec3::ZERO),
        CastRay::new(DVec3::ZERO, DVec3::new(f64::INFINITY, 0.0, 0.0)),
        CastRay::new(DVec3::new(f64::INFINITY, 0.0, 0.0), -DVec3::X),
    ];
    assert!(caster.nearest_all(&bad).iter().all(Option::is_none));
    assert!(caster.occluded_all(&bad).iter().all(|&b| !b));
    // A good ray, with a distance limit that is not a number or not above 0.
    let origin = centre + DVec3::new(0.0, 30.0, 0.0);
    assert!(caster.occluded(origin, -DVec3::Y, f64::INFINITY));
    for t_max in [f64::NAN, 0.0, -1.0] {
        assert!(!caster.occluded(origin, -DVec3::Y, t_max), "{t_max}");
    }
    // Casting at a scene posed but not updated would use the last pose's transforms.
    scene.set_local(0, Transform::from_translation(DVec3::splat(100.0))).unwrap();
    assert_eq!(SceneCaster::new(&scene).err(), Some(CastError::NotUpdated));
    scene.update().unwrap();
    assert!(SceneCaster::new(&scene).is_ok());
    let e = SceneCaster::with(&scene, DVec3::new(0.0, f64::NAN, 0.0), u32::MAX).err().unwrap();
    assert!(e.to_string().contains("reference point"), "{e}");
}

/// `gpu::cast::GpuSceneCaster` against the CPU's caster: the same hits up to f32 rounding.
#[cfg(feature = "gpu")]
mod on_the_gpu {
    use super::common::gpu_context as context;
    use super::*;
    use voxray::gpu::cast::GpuSceneCaster;
    use voxray::stability::check_with;

    /// GPU t is computed in f32 from an f32 ray (the CPU maps it in f64): 10⁻⁴ relative, as
    /// `tests/gpu.rs` allows the renderer's rays.
    const GPU_T_TOLERANCE: f64 = 1e-4;

    /// Through the BVH (48 instances) and the sorted spheres (6): at least 99.9 % of the
    /// answers are the CPU's (instance, voxel, t within the tolerance), and every other one
    /// is valid against the oracle; occlusion agrees with the nearest hits; rays without a
    /// direction hit nothing.
    #[test]
    fn the_gpu_caster_gives_the_cpus_hits() {
        let Some(ctx) = context() else { return };
        for (n, seed) in [(48, 21), (6, 22)] {
            let (scene, coords) = scene(n, seed);
            let set = VoxelSet::new(DEPTH, coords.iter().copied());
            let mut rays = rays(&scene, &coords, 3000, seed + 1);
            rays.push(CastRay::new(DVec3::NAN, DVec3::X));
            rays.push(CastRay::new(DVec3::ZERO, DVec3::ZERO));
            let cpu = SceneCaster::new(&scene).unwrap().nearest_all(&rays);
            let caster = GpuSceneCaster::new(ctx.clone(), &scene).unwrap();
            assert_eq!(caster.instances(), n);
            let gpu = caster.nearest_all(&rays).unwrap();
            let (mut same, mut invalid, mut hits) = (0, Vec::new(), 0);
            for (k, ((r, c), g)) in rays.iter().zip(&cpu).zip(&gpu).enumerate() {
                hits += g.is_some() as usize;
                let agree = match (c, g) {
                    (None, None) => true,
                    (Some(c), Some(g)) => {
                        c.instance == g.instance
                            && c.voxel.coord == g.voxel.coord
                            && (c.t - g.t).abs() <= GPU_T_TOLERANCE * c.t.max(1.0)
                    }
                    _ => false,
                };
                if agree {
                    same += 1;
                    continue;
                }
                // Where they differ, the GPU's answer must itself be valid.
                let d = r.dir.normalize();
                for i in 0..n {
                    let ray = in_instance(&scene, i, r.origin, d);
                    let got = g.filter(|h| h.instance == i).map(|h| h.voxel);
                    if g.is_some() && got.is_none() {
                        continue;
                    }
                    let report = check_with(&set, &ray, got, 0, false, GPU_T_TOLERANCE);
                    if report.mismatches > 0 {
                        invalid.push(format!("ray {k}, instance {i}: {:?}", report.first_mismatch));
                    }
                }
            }
            assert!(invalid.is_empty(), "{n} instances: {invalid:?}");
            assert!(same * 1000 >= rays.len() * 999, "{n} instances: only {same} of {} the CPU's", rays.len());
            assert!(hits > rays.len() / 4, "{hits} hits");
            assert!(gpu[rays.len() - 2..].iter().all(Option::is_none));
            // Occlusion on the GPU: blocked exactly where the nearest search found a hit.
            let blocked = caster.occluded_all(&rays).unwrap();
            for (k, (b, g)) in blocked.iter().zip(&gpu).enumerate() {
                assert_eq!(*b, g.is_some(), "{n} instances, ray {k}");
            }
            eprintln!("{n} instances: {same} of {} rays the CPU's, {hits} hits", rays.len());
            // Each ray's own reach: short of its hit (by more than the f32 rounding) nothing
            // blocks it nor is hit; past it, the same hit.
            let hit: Vec<(CastRay, f64)> =
                rays.iter().zip(&gpu).filter_map(|(r, g)| g.filter(|h| h.t > 1e-2).map(|h| (*r, h.t))).collect();
            let short: Vec<CastRay> = hit.iter().map(|(r, t)| r.up_to(t * 0.99)).collect();
            let long: Vec<CastRay> = hit.iter().map(|(r, t)| r.up_to(t * 1.01)).collect();
            assert!(caster.occluded_all(&short).unwrap().iter().all(|&b| !b));
            assert!(caster.occluded_all(&long).unwrap().iter().all(|&b| b));
            assert!(caster.nearest_all(&short).unwrap().iter().all(Option::is_none));
            for ((r, t), h) in hit.iter().zip(caster.nearest_all(&long).unwrap()) {
                assert_eq!(h.map(|h| h.t), Some(*t), "{r:?}");
            }
        }
    }
}
