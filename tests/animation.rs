//! Rigid-body animation: every optimization (culling, depth-sorted early-out, BVH, hit
//! buffer) against the plain oracle path, instances against brute-force oriented boxes, far
//! from the origin, and bad transforms.

use glam::{DAffine3, DQuat, DVec3, Vec3};
use std::sync::{Arc, OnceLock};
use voxray::pipeline::build_parts;
use voxray::render::instances::prepare;
use voxray::render::visibility::{nearest, FrameInstances, Search};
use voxray::render::{render, Features, Frame, FramePlan, HitBuffer, RenderOptions};
use voxray::rng::Rng;
use voxray::scene::car::{add_car, pose, Car};
use voxray::scene::{Camera, Instance, Lights, Scene, SceneError, Transform, TransformError};
use voxray::svo::{self, Cube, Svo};
use voxray::traverse::TraceOptions;
use voxray::voxelize::{Resolution, VoxelGrid};

/// The default car's parts at a coarse voxel size (built once per test binary).
fn car_parts() -> Vec<Arc<Svo>> {
    static PARTS: OnceLock<Vec<Arc<Svo>>> = OnceLock::new();
    PARTS.get_or_init(|| build_parts(&voxray::model::car::mesh(), Resolution::Depth(6)).unwrap()).clone()
}

/// A parked car at the origin and `n_driving` cars driving figure-eights centred in front of
/// it (towards +z, where the camera is), so they cross in front of the parked one.
fn cars_scene(n_driving: usize) -> (Scene, Vec<Car>) {
    let mut scene = Scene::new(car_parts());
    let mut cars = vec![add_car(&mut scene, 0, DVec3::ZERO, 0.0, false).unwrap()];
    for k in 0..n_driving {
        cars.push(add_car(&mut scene, 0, DVec3::new(0.0, 0.0, 8.0 + 3.0 * k as f64), 1.3 * k as f64, true).unwrap());
    }
    scene.update().unwrap();
    (scene, cars)
}

fn camera() -> Camera {
    Camera {
        eye: DVec3::new(0.0, 4.0, 28.0),
        target: DVec3::new(0.0, 0.5, 0.0),
        up: DVec3::Y,
        vfov_deg: 45.0,
        width: 64,
        height: 40,
    }
}

/// Renders `frames` frames at 30 fps with the given features, carrying a hit buffer.
fn clip(scene: &mut Scene, cars: &[Car], features: Features, frames: usize, orbit_deg_per_s: f64) -> Vec<Frame> {
    let lights = Lights::default();
    let mut hits = HitBuffer::new();
    (0..frames)
        .map(|f| {
            let t = f as f64 / 30.0;
            for c in cars {
                pose(scene, c, t).unwrap();
            }
            scene.update().unwrap();
            let base = camera();
            let q = DQuat::from_rotation_y((orbit_deg_per_s * t).to_radians());
            let cam = Camera { eye: base.target + q * (base.eye - base.target), ..base };
            let plan = FramePlan::new(scene, &cam, &lights, &features, (f > 0).then_some(&hits));
            render(scene, &cam, &lights, &plan, &RenderOptions::default(), Some(&mut hits), &|_, _| {}).unwrap()
        })
        .collect()
}

fn assert_same_hits(a: &[Frame], b: &[Frame]) {
    for (f, (x, y)) in a.iter().zip(b).enumerate() {
        for k in 0..x.t.len() {
            assert_eq!(x.t[k].to_bits(), y.t[k].to_bits(), "frame {f} pixel {k}: t");
            assert_eq!(x.instance[k], y.instance[k], "frame {f} pixel {k}: instance");
            assert_eq!(
                x.normal[k].to_array().map(f32::to_bits),
                y.normal[k].to_array().map(f32::to_bits),
                "frame {f} pixel {k}: normal"
            );
        }
        assert_eq!(x.radiance, y.radiance, "frame {f}: image");
    }
}

#[test]
fn all_optimizations_match_the_plain_path_static_camera() {
    let (mut s1, cars) = cars_scene(1);
    let fast = clip(&mut s1, &cars, Features::default(), 60, 0.0);
    let (mut s2, cars2) = cars_scene(1);
    let plain = clip(&mut s2, &cars2, Features::NONE.with_shadows(), 60, 0.0);
    assert_same_hits(&fast, &plain);
    let reused: u64 = fast.iter().map(|f| f.reused).sum();
    let pixels = (fast.len() * fast[0].t.len()) as u64;
    assert!(reused > pixels / 4, "the static camera should reuse many pixels ({reused} of {pixels})");
    assert!(reused < pixels, "moving parts must force some pixels to be traced again");
    // Pixels behind a moved sphere whose hit is on a parked part search the moved parts only.
    let moved_only: u64 = fast.iter().map(|f| f.moved_only).sum();
    assert!(moved_only > 0 && moved_only < pixels - reused, "{moved_only} moved-only rays");
    // Kept colours: never more than the kept hits, often nearly all of them.
    let kept: u64 = fast.iter().map(|f| f.shade_reused).sum();
    assert!(kept > pixels / 4 && kept <= pixels, "{kept} of {pixels} colours kept");
    // The driving car really crosses in front of the parked one: some pixel shows a parked
    // instance (0..8) in one frame and a driving one (8..16) in another.
    let crossed = (0..fast[0].t.len()).any(|k| {
        fast.iter().any(|f| (0..8).contains(&f.instance[k])) && fast.iter().any(|f| (8..16).contains(&f.instance[k]))
    });
    assert!(crossed, "no moving part crossed in front of a static one");
}

#[test]
fn all_optimizations_match_the_plain_path_moving_camera() {
    let (mut s1, cars) = cars_scene(1);
    let fast = clip(&mut s1, &cars, Features::default(), 60, 20.0);
    let (mut s2, cars2) = cars_scene(1);
    let plain = clip(&mut s2, &cars2, Features::NONE.with_shadows(), 60, 20.0);
    assert_same_hits(&fast, &plain);
    assert_eq!(fast.iter().map(|f| f.reused).sum::<u64>(), 0, "a moving camera turns the hit buffer off");
}

#[test]
fn bvh_matches_the_plain_path_with_many_instances() {
    let (mut s1, cars) = cars_scene(5); // 48 instances: the plan turns the BVH on
    let plan = FramePlan::new(&s1, &camera(), &Lights::default(), &Features::default(), None);
    assert!(plan.bvh, "{}", plan.explain());
    let fast = clip(&mut s1, &cars, Features::default(), 8, 0.0);
    let (mut s2, cars2) = cars_scene(5);
    let plain = clip(&mut s2, &cars2, Features::NONE.with_shadows(), 8, 0.0);
    assert_same_hits(&fast, &plain);
}

/// Nearest voxel by brute force: every voxel's oriented box, in f64.
fn brute_force(set: &[[u32; 3]], cube: &Cube, depth: u32, m: &DAffine3, o: DVec3, d: DVec3) -> Option<(f64, [u32; 3])> {
    let inv = m.inverse();
    let (oo, dd) = (inv.transform_point3(o), inv.transform_vector3(d));
    let v = cube.size as f64 / (1u64 << depth) as f64;
    let mut best: Option<(f64, [u32; 3])> = None;
    for &c in set {
        let lo = cube.min.as_dvec3() + DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * v;
        let hi = lo + DVec3::splat(v);
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for i in 0..3 {
            if dd[i] == 0.0 {
                if oo[i] < lo[i] || oo[i] > hi[i] {
                    t0 = f64::INFINITY;
                }
            } else {
                let (a, b) = ((lo[i] - oo[i]) / dd[i], (hi[i] - oo[i]) / dd[i]);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        if t0 <= t1 && best.is_none_or(|(t, _)| t0 < t) {
            best = Some((t0, c));
        }
    }
    best
}

fn interval(cube: &Cube, depth: u32, m: &DAffine3, o: DVec3, d: DVec3, c: [u32; 3]) -> (f64, f64) {
    let inv = m.inverse();
    let (oo, dd) = (inv.transform_point3(o), inv.transform_vector3(d));
    let v = cube.size as f64 / (1u64 << depth) as f64;
    let lo = cube.min.as_dvec3() + DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * v;
    let hi = lo + DVec3::splat(v);
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for i in 0..3 {
        let (a, b) = ((lo[i] - oo[i]) / dd[i], (hi[i] - oo[i]) / dd[i]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t0, t1)
}

#[test]
fn transformed_instances_hit_where_brute_force_oriented_boxes_say() {
    let mut rng = Rng::new(77);
    let depth = 4;
    let coords: Vec<[u32; 3]> = (0..80).map(|_| [0; 3].map(|_: u32| rng.below(16) as u32)).collect();
    let cube = Cube { min: Vec3::new(-1.0, -0.5, -2.0), size: 2.0 };
    let part = Arc::new(svo::build(&VoxelGrid::from_coords(depth, cube, coords.iter().copied(), Vec3::ONE)).unwrap());
    let (mut hits, mut checked) = (0, 0);
    for _ in 0..60 {
        let scale = DVec3::new(
            10f64.powf(rng.f64() * 6.0 - 3.0),
            10f64.powf(rng.f64() * 6.0 - 3.0),
            10f64.powf(rng.f64() * 6.0 - 3.0),
        );
        let axis = rng.unit_vector().as_dvec3();
        let rot = DQuat::from_axis_angle(axis, rng.f64() * std::f64::consts::TAU);
        let tr = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5) * 200.0;
        let t = Transform::new(tr, rot, scale).unwrap();
        let mut scene = Scene::new(vec![part.clone()]);
        scene.add(Instance { part: 0, parent: None, local: t }).unwrap();
        scene.update().unwrap();
        let m = scene.world(0);
        for _ in 0..50 {
            // Aim at a random voxel from outside the instance's bounding sphere.
            let c = coords[rng.below(coords.len() as u64) as usize];
            let v = cube.size as f64 / 16.0;
            let target_obj = cube.min.as_dvec3()
                + (DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) + DVec3::new(rng.f64(), rng.f64(), rng.f64())) * v;
            let target = m.transform_point3(target_obj);
            let radius = scale.max_element() * 2.0;
            let o = target + rng.unit_vector().as_dvec3() * radius * 3.0;
            let d = (target - o).normalize();
            let prepared = prepare(&scene, o, true);
            let fi = FrameInstances { parts: &scene.parts, prepared: &prepared, bvh: None, starts: None };
            let got = nearest(&fi, DVec3::ZERO, d, Search::Plain, &TraceOptions::default());
            let want = brute_force(&coords, &cube, depth, &m, o, d);
            checked += 1;
            match (got, want) {
                (Some(g), Some((t, voxel))) => {
                    hits += 1;
                    let rel = (g.hit.t as f64 - t).abs() / t;
                    assert!(rel <= 1e-5, "scale {scale}: t {} vs {t} (rel {rel:e})", g.hit.t);
                    if g.hit.coord != voxel {
                        // Only acceptable for a voxel entered at the same t (edge/corner contact).
                        let other = brute_force(&[g.hit.coord], &cube, depth, &m, o, d).expect("hit voxel is crossed");
                        assert!((other.0 - t).abs() <= 1e-5 * t, "scale {scale}: voxel {:?} vs {voxel:?}", g.hit.coord);
                    }
                }
                (None, None) => {}
                (g, w) => {
                    let (t0, t1) =
                        interval(&cube, depth, &m, o, d, w.map_or(g.map_or([0; 3], |g| g.hit.coord), |w| w.1));
                    panic!(
                        "scale {scale}: traversal {:?} vs brute force {w:?}; interval {t0} {t1} len {:e}; o {o} d {d}",
                        g.map(|g| (g.hit.t, g.hit.coord)),
                        t1 - t0
                    )
                }
            }
        }
    }
    assert!(hits * 10 >= checked * 9, "rays are aimed at voxels: {hits} of {checked} hit");
}

#[test]
fn a_car_a_million_units_away_renders_like_one_at_the_origin() {
    let lights = Lights::default();
    let render_at = |offset: DVec3| {
        let mut scene = Scene::new(car_parts());
        let car = add_car(&mut scene, 0, offset, 0.0, false).unwrap();
        pose(&mut scene, &car, 2.0).unwrap();
        scene.update().unwrap();
        let base = camera();
        let cam = Camera {
            eye: DVec3::new(5.0, 2.0, -4.5) + offset,
            target: DVec3::new(0.0, 0.7, 0.0) + offset,
            width: 96,
            height: 64,
            ..base
        };
        let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
        render(&scene, &cam, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap()
    };
    let a = render_at(DVec3::ZERO);
    let b = render_at(DVec3::new(1e6, 0.0, -1e6));
    let n = a.t.len();
    let same_instance = a.instance.iter().zip(&b.instance).filter(|(x, y)| x == y).count();
    let max_diff = a.radiance.iter().zip(&b.radiance).map(|(x, y)| (*x - *y).abs().max_element()).fold(0.0, f32::max);
    let mean_diff: f32 =
        a.radiance.iter().zip(&b.radiance).map(|(x, y)| (*x - *y).abs().max_element()).sum::<f32>() / n as f32;
    // Camera-relative f64 transforms: the same pixels hit the same parts; shading may differ
    // by f32 rounding only.
    assert!(same_instance * 1000 >= n * 999, "{same_instance} of {n} pixels hit the same instance");
    assert!(mean_diff < 1e-3 && max_diff < 0.05, "mean {mean_diff}, max {max_diff}");
    assert!(a.instance.iter().filter(|&&i| i >= 0).count() > n / 10, "the car should fill part of the image");
}

#[test]
fn singular_and_nan_transforms_are_refused_and_leave_no_nan() {
    let mut scene = Scene::new(car_parts());
    let body = scene.add(Instance { part: 0, parent: None, local: Transform::IDENTITY }).unwrap();
    let wheel = scene.add(Instance { part: 1, parent: Some(body), local: Transform::IDENTITY }).unwrap();
    scene.update().unwrap();
    let bad = [
        Transform { translation: DVec3::NAN, ..Transform::IDENTITY },
        Transform { scale: DVec3::new(1.0, 0.0, 1.0), ..Transform::IDENTITY },
        Transform { scale: DVec3::splat(f64::INFINITY), ..Transform::IDENTITY },
        Transform { rotation: DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0), ..Transform::IDENTITY },
        Transform { rotation: DQuat::from_xyzw(f64::NAN, 0.0, 0.0, 1.0), ..Transform::IDENTITY },
    ];
    for t in bad {
        assert!(matches!(scene.set_local(wheel, t), Err(SceneError::Transform(_))), "{t:?} accepted");
    }
    assert!(matches!(
        scene.add(Instance { part: 99, parent: None, local: Transform::IDENTITY }),
        Err(SceneError::Part(99))
    ));
    assert!(matches!(
        scene.add(Instance { part: 0, parent: Some(7), local: Transform::IDENTITY }),
        Err(SceneError::Instance(7))
    ));
    // Each scale alone is acceptable, the product through the hierarchy is near-singular.
    let tiny = Transform { scale: DVec3::splat(2e-6), ..Transform::IDENTITY };
    scene.set_local(body, tiny).unwrap();
    scene.set_local(wheel, tiny).unwrap();
    assert_eq!(scene.update(), Err(SceneError::Transform(TransformError::Singular(wheel))));
    // The scene keeps its last good transforms: rendering gives no NaN.
    assert_eq!(scene.world(wheel), DAffine3::IDENTITY);
    let cam = camera();
    let lights = Lights::default();
    let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
    let f = render(&scene, &cam, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap();
    assert!(f.radiance.iter().all(|r| r.is_finite()) && f.t.iter().all(|t| !t.is_nan()));
}

#[test]
fn wheels_follow_the_body_through_the_hierarchy() {
    let mut scene = Scene::new(car_parts());
    let car = add_car(&mut scene, 0, DVec3::new(100.0, 0.0, 0.0), 0.0, true).unwrap();
    for t in [0.0, 3.7, 11.2] {
        pose(&mut scene, &car, t).unwrap();
        scene.update().unwrap();
        let body = scene.world(car.body);
        let pivot = voxray::model::car::rig()[1].0.as_dvec3();
        // The front-left axle stays where the body carries it, whatever the wheel's spin/steer.
        let expect = body.transform_point3(pivot);
        let got = scene.world(car.wheels[0]).transform_point3(pivot);
        assert!((expect - got).length() < 1e-9, "t {t}: {expect} vs {got}");
    }
}

#[test]
fn screen_rectangles_contain_every_pixel_a_sphere_can_touch() {
    use voxray::render::hitbuffer::screen_rect;
    use voxray::render::instances::sphere_interval;
    let mut rng = Rng::new(5);
    let mut tight = 0;
    for _ in 0..200 {
        let cam = Camera {
            eye: DVec3::ZERO,
            target: rng.unit_vector().as_dvec3(),
            up: DVec3::Y,
            vfov_deg: 20.0 + rng.f64() * 100.0,
            width: 40 + rng.below(40) as u32,
            height: 30 + rng.below(30) as u32,
        };
        let b = cam.basis();
        let centre = b.forward * (rng.f64() * 20.0 - 2.0) + rng.unit_vector().as_dvec3() * rng.f64() * 10.0;
        let radius = 0.1 + rng.f64() * 3.0;
        let [x0, y0, x1, y1] = screen_rect(&cam, centre, radius);
        if (x1 + 1 - x0.min(x1 + 1)) * (y1 + 1 - y0.min(y1 + 1)) < cam.width * cam.height / 2 {
            tight += 1;
        }
        for y in 0..cam.height {
            for x in 0..cam.width {
                if sphere_interval(centre, radius, DVec3::ZERO, cam.ray_dir(&b, x, y)).is_some() {
                    assert!(x >= x0 && x <= x1 && y >= y0 && y <= y1, "pixel {x},{y} outside {:?}", [x0, y0, x1, y1]);
                }
            }
        }
    }
    assert!(tight > 50, "rectangles should usually be much smaller than the image ({tight} of 200)");
}

#[test]
fn work_counters_add_up_and_fall_with_each_optimization() {
    let (mut scene, cars) = cars_scene(4); // 5 cars, 40 instances
    let n = scene.instances().len() as u64;
    let plain = Features { shadows: false, ..Features::NONE };
    let cull = Features { cull: true, ..plain };
    let sort = Features { sort: true, ..cull };
    let bvh = Features { bvh: true, ..sort };
    let f_plain = &clip(&mut scene, &cars, plain, 1, 0.0)[0];
    let f_cull = &clip(&mut scene, &cars, cull, 1, 0.0)[0];
    let f_sort = &clip(&mut scene, &cars, sort, 1, 0.0)[0];
    let f_bvh = &clip(&mut scene, &cars, bvh, 1, 0.0)[0];
    let rays = f_plain.primary_rays;
    // Plain: every ray traverses every instance, nothing is culled.
    assert_eq!((f_plain.instances_traced, f_plain.spheres_culled), (rays * n, 0));
    // Culling: each instance is either traversed or culled, and most are culled.
    assert_eq!(f_cull.instances_traced + f_cull.spheres_culled, rays * n);
    assert!(f_cull.spheres_culled > f_cull.instances_traced, "{f_cull:?}");
    // Sorting only stops early: same culls, fewer or equal traversals.
    assert_eq!(f_sort.spheres_culled, f_cull.spheres_culled);
    assert!(
        f_sort.instances_traced < f_cull.instances_traced,
        "{} vs {}",
        f_sort.instances_traced,
        f_cull.instances_traced
    );
    // The BVH traverses a subset of what culling alone traverses (it can visit a leaf's
    // instances out of depth order, so it may traverse more than sorting), and it tests far
    // fewer spheres: whole boxes are skipped.
    assert!(f_bvh.instances_traced <= f_cull.instances_traced);
    assert!(f_bvh.spheres_culled < f_sort.spheres_culled);
    println!(
        "traversed per ray: plain {:.2}, cull {:.2}, sort {:.2}, bvh {:.2}",
        f_plain.instances_traced as f64 / rays as f64,
        f_cull.instances_traced as f64 / rays as f64,
        f_sort.instances_traced as f64 / rays as f64,
        f_bvh.instances_traced as f64 / rays as f64
    );
}

#[test]
fn changing_the_level_of_detail_invalidates_the_hit_buffer() {
    let (mut scene, cars) = cars_scene(0);
    for c in &cars {
        pose(&mut scene, c, 0.0).unwrap();
    }
    scene.update().unwrap();
    let (cam, lights) = (camera(), Lights::default());
    let features = Features::default();
    let coarse = RenderOptions { max_level: 2, ..Default::default() };
    let mut hits = HitBuffer::new();
    let plan = FramePlan::new(&scene, &cam, &lights, &features, None);
    render(&scene, &cam, &lights, &plan, &RenderOptions::default(), Some(&mut hits), &|_, _| {}).unwrap();
    // Same camera, nothing moved, but a coarser level: nothing may be reused.
    let plan = FramePlan::new(&scene, &cam, &lights, &features, Some(&hits));
    assert!(plan.hit_buffer);
    let second = render(&scene, &cam, &lights, &plan, &coarse, Some(&mut hits), &|_, _| {}).unwrap();
    let fresh = render(
        &scene,
        &cam,
        &lights,
        &FramePlan::new(&scene, &cam, &lights, &features, None),
        &coarse,
        None,
        &|_, _| {},
    )
    .unwrap();
    assert_eq!(second.reused, 0);
    assert_eq!(second.t, fresh.t);
    assert_eq!(second.instance, fresh.instance);
    // And at the same level again, everything is reused.
    let plan = FramePlan::new(&scene, &cam, &lights, &features, Some(&hits));
    let third = render(&scene, &cam, &lights, &plan, &coarse, Some(&mut hits), &|_, _| {}).unwrap();
    assert_eq!(third.reused, third.primary_rays);
}

/// The instance BVH is refitted from frame to frame while the cars drive, with the answers
/// of the plain path, also after every instance jumps somewhere else.
#[test]
fn the_refitted_bvh_gives_the_plain_answers() {
    let (mut scene, cars) = cars_scene(5);
    let lights = Lights::default();
    let features = Features { hit_buffer: false, ..Features::default() };
    let mut hits = HitBuffer::new();
    for f in 0..6 {
        for c in &cars {
            pose(&mut scene, c, f as f64 / 30.0).unwrap();
        }
        scene.update().unwrap();
        let plan = FramePlan::new(&scene, &camera(), &lights, &features, None);
        assert!(plan.bvh);
        let fast =
            render(&scene, &camera(), &lights, &plan, &RenderOptions::default(), Some(&mut hits), &|_, _| {}).unwrap();
        let plain = FramePlan::new(&scene, &camera(), &lights, &Features::NONE.with_shadows(), None);
        let slow = render(&scene, &camera(), &lights, &plain, &RenderOptions::default(), None, &|_, _| {}).unwrap();
        assert_same_hits(&[fast], &[slow]);
    }
    assert_eq!(hits.bvh_builds, 1, "driving cars refit the first tree");
    assert_eq!(hits.bvh.as_ref().map(|b| b.refits), Some(5));

    // Scatter every instance, wheels and doors too, far from the others: leaves that held
    // one car's parts now span the scatter.
    let mut rng = Rng::new(8);
    for i in 0..scene.instances().len() {
        let mut t = scene.instances()[i].local;
        t.translation = DVec3::new(rng.range(-300.0, 300.0) as f64, 0.0, rng.range(-300.0, 300.0) as f64);
        scene.set_local(i, t).unwrap();
    }
    scene.update().unwrap();
    let plan = FramePlan::new(&scene, &camera(), &lights, &features, None);
    let fast =
        render(&scene, &camera(), &lights, &plan, &RenderOptions::default(), Some(&mut hits), &|_, _| {}).unwrap();
    let plain = FramePlan::new(&scene, &camera(), &lights, &Features::NONE.with_shadows(), None);
    let slow = render(&scene, &camera(), &lights, &plain, &RenderOptions::default(), None, &|_, _| {}).unwrap();
    assert_same_hits(&[fast], &[slow]);
    // Refitted or rebuilt (src/render/bvh.rs tests the rule), the answers are the plain ones.
    assert!(hits.bvh_builds <= 2);
}

/// Two cars driving over a ground lit by a low sun, and a camera framing their clip (96×64).
fn two_cars_on_ground_under_sun() -> (voxray::scene::Staged, Lights, Camera) {
    use voxray::scene::lights::Sun;
    let st = voxray::scene::stage_cars(&car_parts(), 2, true, true).unwrap();
    let lights = Lights {
        sun: Some(Sun { to_sun: glam::Vec3::new(0.6, 0.5, 0.3).normalize(), irradiance: glam::Vec3::splat(3.0) }),
        ..Lights::default()
    };
    let (lo, hi) = st.bounds;
    let cam = Camera::framing(lo.as_vec3(), hi.as_vec3(), 96, 64);
    (st, lights, cam)
}

/// A driving car's shadow sweeps over the ground, which does not move: those ground pixels
/// keep their hits but must not keep their colours. Kept colours equal recomputed ones.
#[test]
fn kept_colours_follow_moving_shadows() {
    let (mut st, lights, cam) = two_cars_on_ground_under_sun();
    let mut hits = HitBuffer::new();
    let mut kept_on_ground = 0;
    for f in 0..8 {
        voxray::scene::car::pose_all(&mut st.scene, &st.cars, f as f64 * 0.2).unwrap();
        st.scene.update().unwrap();
        let plan = FramePlan::new(&st.scene, &cam, &lights, &Features::default(), (f > 0).then_some(&hits));
        let fast =
            render(&st.scene, &cam, &lights, &plan, &RenderOptions::default(), Some(&mut hits), &|_, _| {}).unwrap();
        let plain = FramePlan::new(&st.scene, &cam, &lights, &Features::NONE.with_shadows(), None);
        let slow = render(&st.scene, &cam, &lights, &plain, &RenderOptions::default(), None, &|_, _| {}).unwrap();
        assert_same_hits(std::slice::from_ref(&fast), &[slow]);
        let ground = st.scene.instances().len() as i32 - 1;
        kept_on_ground +=
            fast.instance.iter().filter(|&&i| i == ground).count() as u64 * (fast.shade_reused > 0) as u64;
    }
    assert!(kept_on_ground > 0);
}

/// A kept record whose sun shadow ray an instance blocked, which then moves away, is asked
/// about every instance again, not the moved ones alone: another instance that stayed put
/// may block it too. Here a body (instance 0) and its still copy (instance 1) hang in the
/// same place over the ground under a sun straight above; the first moves away, and the
/// ground below must stay in the copy's shadow.
#[test]
fn a_shadow_whose_blocker_leaves_asks_every_instance_again() {
    use voxray::scene::lights::Sun;
    let mut scene = Scene::new(vec![car_parts()[0].clone()]);
    let hung = Transform { translation: DVec3::new(0.0, 3.0, 0.0), ..Transform::IDENTITY };
    for _ in 0..2 {
        scene.add(Instance { part: 0, parent: None, local: hung }).unwrap();
    }
    voxray::scene::stage::add_ground(&mut scene, (DVec3::new(-3.0, 0.0, -3.0), DVec3::new(3.0, 1.0, 3.0))).unwrap();
    scene.update().unwrap();
    let lights =
        Lights { sun: Some(Sun { to_sun: glam::Vec3::Y, irradiance: glam::Vec3::splat(3.0) }), ..Lights::default() };
    // Low, to see the ground under the bodies.
    let cam = Camera {
        eye: DVec3::new(0.0, 1.2, 14.0),
        target: DVec3::new(0.0, 0.6, 0.0),
        up: DVec3::Y,
        vfov_deg: 40.0,
        width: 96,
        height: 64,
    };
    let mut hits = HitBuffer::new();
    for f in 0..3 {
        if f == 1 {
            let away = Transform { translation: DVec3::new(40.0, 3.0, 0.0), ..Transform::IDENTITY };
            scene.set_local(0, away).unwrap();
            scene.update().unwrap();
        }
        let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), (f > 0).then_some(&hits));
        let fast =
            render(&scene, &cam, &lights, &plan, &RenderOptions::default(), Some(&mut hits), &|_, _| {}).unwrap();
        let plain = FramePlan::new(&scene, &cam, &lights, &Features::NONE.with_shadows(), None);
        let slow = render(&scene, &cam, &lights, &plain, &RenderOptions::default(), None, &|_, _| {}).unwrap();
        assert_same_hits(std::slice::from_ref(&fast), &[slow]);
        // The ground in shadow is in view, and its records are kept after the move.
        let ground = 2;
        let lit = fast.radiance.iter().zip(&fast.instance).filter(|(_, &i)| i == ground).map(|(r, _)| r.x);
        let (dark, bright) = lit.fold((f32::INFINITY, 0f32), |(lo, hi), v| (lo.min(v), hi.max(v)));
        assert!(dark < 0.5 * bright, "frame {f}: no ground in shadow ({dark} against {bright})");
        if f > 0 {
            assert!(fast.reused > 0 && fast.shade_reused > 0, "frame {f}: nothing kept");
        }
    }
}

/// A frame of `scene` from `camera()` with every optimization and the hit buffer `hits`
/// (read when `reuse`), held hit for hit to the same frame rendered afresh by the plain path.
fn frame_as_fresh(scene: &Scene, lights: &Lights, hits: &mut HitBuffer, reuse: bool) -> Frame {
    let plan = FramePlan::new(scene, &camera(), lights, &Features::default(), reuse.then_some(&*hits));
    let fast = render(scene, &camera(), lights, &plan, &RenderOptions::default(), Some(hits), &|_, _| {}).unwrap();
    let plain = FramePlan::new(scene, &camera(), lights, &Features::NONE.with_shadows(), None);
    let slow = render(scene, &camera(), lights, &plain, &RenderOptions::default(), None, &|_, _| {}).unwrap();
    assert_same_hits(std::slice::from_ref(&fast), &[slow]);
    fast
}

#[test]
fn a_moved_instance_landing_on_a_still_one_ties_to_the_lower_index() {
    // Two instances of the body; one moves onto the other, so every pixel they cover has two
    // hits at exactly the same t. The full search gives the lower index; the moved-only
    // search of the hit buffer must too, whichever of the two is the one that moved.
    let body = car_parts()[0].clone();
    let lights = Lights::default();
    let away = Transform { translation: DVec3::new(9.0, 0.0, 0.0), ..Transform::IDENTITY };
    for mover in [0usize, 1] {
        let mut scene = Scene::new(vec![body.clone()]);
        for i in 0..2 {
            let local = if i == mover { away } else { Transform::IDENTITY };
            scene.add(Instance { part: 0, parent: None, local }).unwrap();
        }
        scene.update().unwrap();
        let mut hits = HitBuffer::new();
        let mut moved_only = 0;
        for f in 0..3 {
            if f == 2 {
                scene.set_local(mover, Transform::IDENTITY).unwrap();
                scene.update().unwrap();
            }
            let fast = frame_as_fresh(&scene, &lights, &mut hits, f > 0);
            moved_only += fast.moved_only;
            if f == 2 {
                assert!(fast.instance.contains(&0) && !fast.instance.contains(&1), "mover {mover}: ties to instance 0");
            }
        }
        assert!(moved_only > 0, "mover {mover}: the moved-only search never ran");
    }
}

/// A pixel whose stored hit is on an instance that moves searches every instance again, and
/// must find the ones that stayed put however close behind that hit they lie. Here a moving
/// copy of the body lies exactly on a still one (the tie went to the mover, instance 0), or
/// a hair in front of it, and then leaves: every pixel it covered must find the still body
/// at the stored t or just behind it, as a fresh frame does. (It fails when the still
/// instances are searched from 2⁻²⁰ of the distance past the stored hit.)
#[test]
fn pixels_a_moved_instance_leaves_find_the_still_one_just_behind() {
    let body = car_parts()[0].clone();
    let lights = Lights::default();
    for ahead in [0.0, 1e-3] {
        let mut scene = Scene::new(vec![body.clone()]);
        let front = Transform { translation: DVec3::new(0.0, 0.0, ahead), ..Transform::IDENTITY };
        scene.add(Instance { part: 0, parent: None, local: front }).unwrap();
        scene.add(Instance { part: 0, parent: None, local: Transform::IDENTITY }).unwrap();
        scene.update().unwrap();
        let mut hits = HitBuffer::new();
        for f in 0..3 {
            if f == 2 {
                let away = Transform { translation: DVec3::new(0.0, 9.0, ahead), ..Transform::IDENTITY };
                scene.set_local(0, away).unwrap();
                scene.update().unwrap();
            }
            let fast = frame_as_fresh(&scene, &lights, &mut hits, f > 0);
            match f {
                1 => assert!(
                    fast.instance.contains(&0) && !fast.instance.contains(&1),
                    "ahead {ahead}: the mover in front"
                ),
                2 => {
                    assert!(fast.instance.contains(&1), "ahead {ahead}: the still body behind");
                    assert!(fast.reused > 0, "ahead {ahead}: the hit buffer kept nothing");
                }
                _ => {}
            }
        }
    }
}

/// Past the beams' limit each pixel searches its own sphere list; with the hit buffer, a
/// pixel whose stored hit is on a still instance (or a miss), crossed by a moved sphere,
/// searches only the moved instances of its list against that hit. Here three cars drive
/// figure-eights in front of two rows of eight parked ones (never posed: still; 152
/// instances, past the beams' limit, 24 of them moving), and every frame must equal one
/// rendered afresh, hit for hit.
#[test]
fn a_crowds_moved_pixels_search_the_moved_instances_of_their_lists() {
    let mut scene = Scene::new(car_parts());
    for k in 0..16 {
        let (x, z) = ((k % 8) as f64, (k / 8) as f64);
        add_car(&mut scene, 0, DVec3::new(-17.5 + 5.0 * x, 0.0, -6.0 * z), 0.0, false).unwrap();
    }
    let driving: Vec<Car> = (0..3)
        .map(|k| add_car(&mut scene, 0, DVec3::new(-4.0 + 4.0 * k as f64, 0.0, 6.0), 1.7 * k as f64, true).unwrap())
        .collect();
    scene.update().unwrap();
    assert!(scene.instances().len() > voxray::render::beam::MAX_INSTANCES);
    let lights = Lights::default();
    let features = Features { shadows: false, ..Features::default() };
    let cam = Camera { width: 96, height: 48, ..camera() };
    let mut hits = HitBuffer::new();
    let mut moved_only = 0;
    for f in 0..8 {
        for c in &driving {
            pose(&mut scene, c, 0.6 * f as f64).unwrap();
        }
        scene.update().unwrap();
        let plan = FramePlan::new(&scene, &cam, &lights, &features, (f > 0).then_some(&hits));
        assert!(plan.sphere_lists, "{}", plan.explain());
        let fast =
            render(&scene, &cam, &lights, &plan, &RenderOptions::default(), Some(&mut hits), &|_, _| {}).unwrap();
        let plain = FramePlan::new(&scene, &cam, &lights, &Features::NONE, None);
        let slow = render(&scene, &cam, &lights, &plain, &RenderOptions::default(), None, &|_, _| {}).unwrap();
        assert_same_hits(std::slice::from_ref(&fast), &[slow]);
        moved_only += fast.moved_only;
    }
    assert!(moved_only > 100, "the moved-only search ran for {moved_only} pixels");
}

/// Every per-pixel buffer of `a` and `b`, bit for bit.
fn assert_same_pixels(a: &Frame, b: &Frame, what: &str) {
    let bits = |v: &[Vec3]| v.iter().flat_map(|c| c.to_array().map(f32::to_bits)).collect::<Vec<_>>();
    let bits1 = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a.radiance), bits(&b.radiance), "{what}: image");
    assert_eq!(bits1(&a.t), bits1(&b.t), "{what}: t");
    assert_eq!(a.instance, b.instance, "{what}: instance");
    assert_eq!(bits(&a.normal), bits(&b.normal), "{what}: normal");
    assert_eq!(bits(&a.albedo), bits(&b.albedo), "{what}: albedo");
    assert_eq!(bits1(&a.specular), bits1(&b.specular), "{what}: specular");
    assert_eq!(bits1(&a.shininess), bits1(&b.shininess), "{what}: shininess");
}

/// A session hands its own last frame back to the renderer, which then writes only the
/// pixels that changed into it; every frame must still equal one rendered afresh, with and
/// without shadow rays, and a frame the caller changed (taken and given back) must be
/// rewritten in full.
#[test]
fn session_frames_written_only_where_pixels_changed_match_fresh_frames() {
    use voxray::backend::Backend;
    use voxray::session::Session;
    let (mut st, lights, cam) = two_cars_on_ground_under_sun();
    for shadows in [false, true] {
        let features = Features { shadows, ..Features::default() };
        let mut session = Session::new(Backend::Cpu(Box::default()), "CPU".into());
        let mut kept = 0;
        for f in 0..10 {
            voxray::scene::car::pose_all(&mut st.scene, &st.cars, f as f64 * 0.1).unwrap();
            st.scene.update().unwrap();
            session.frame(&st.scene, &cam, &lights, &features, &RenderOptions::default(), &|_, _| {}).unwrap();
            let plain = FramePlan::new(&st.scene, &cam, &lights, &Features { shadows, ..Features::NONE }, None);
            let fresh = render(&st.scene, &cam, &lights, &plain, &RenderOptions::default(), None, &|_, _| {}).unwrap();
            let frame = session.last_frame().unwrap();
            assert_same_pixels(frame, &fresh, &format!("shadows {shadows}, frame {f}"));
            kept += frame.shade_reused;
            if f == 5 {
                // The caller scribbles over the frame: nothing of it may show in the next one.
                let mut taken = session.take_frame().unwrap();
                taken.radiance.fill(Vec3::splat(-1.0));
                taken.t.fill(0.0);
                taken.instance.fill(7);
                taken.albedo.fill(Vec3::ONE);
                session.give_back(taken);
            }
        }
        assert!(kept > 0, "shadows {shadows}: no colour was kept");
    }
}

/// Over the sky: cars drive across an empty background, under a static and an orbiting
/// camera, and the sky changes colour halfway. Pixels stored as misses without a search (a
/// beam met nothing: two cars with their pixels kept; pixel lists hold no sphere: two cars a
/// few pixels wide traced afresh, and a crowd past the beams' limit, with and without the
/// hit buffer) are not rewritten in a session's own frame when they showed the same sky
/// before; every frame must equal a fresh one, where a car has just left a pixel too. The two
/// cars go from lists to beams and back as the hit buffer's frames come and go.
#[test]
fn session_frames_over_the_sky_match_fresh_frames() {
    use voxray::backend::Backend;
    use voxray::scene::lights::Ambient;
    use voxray::session::Session;
    let crowd = voxray::render::beam::MAX_INSTANCES / 8 + 4;
    for (cars, hit_buffer) in [(2, true), (crowd, true), (crowd, false)] {
        let mut st = voxray::scene::stage_cars(&car_parts(), cars, true, false).unwrap();
        let (lo, hi) = st.bounds;
        let base = Camera::framing(lo.as_vec3(), hi.as_vec3(), 96, 64);
        let features = Features { hit_buffer, ..Features::default() };
        // Frames searched with lists and with beams.
        let mut searched = [0, 0];
        for orbit in [0.0, 20.0] {
            let what = format!("{cars} cars, hit buffer {hit_buffer}, orbit {orbit}");
            let mut session = Session::new(Backend::Cpu(Box::default()), "CPU".into());
            let mut uncovered = 0;
            let mut before: Option<Frame> = None;
            for f in 0..10 {
                // Long steps: a car leaves whole tiles (and their beams) between two frames.
                let t = f as f64 * 1.1;
                voxray::scene::car::pose_all(&mut st.scene, &st.cars, t).unwrap();
                st.scene.update().unwrap();
                let q = DQuat::from_rotation_y((orbit * t).to_radians());
                let cam = Camera { eye: base.target + q * (base.eye - base.target), ..base };
                let sky = if f < 5 { Vec3::new(0.5, 0.6, 0.8) } else { Vec3::new(0.8, 0.4, 0.2) };
                let lights = Lights { ambient: Some(Ambient { radiance: sky }), ..Lights::default() };
                let report =
                    session.frame(&st.scene, &cam, &lights, &features, &RenderOptions::default(), &|_, _| {}).unwrap();
                // Lists past the beams' limit, and for two cars a few pixels wide in a frame
                // that traces every pixel.
                let small = !report.plan.hit_buffer
                    && voxray::render::pixel_spheres::mean_instance_area(&st.scene, &cam)
                        .is_some_and(|a| a < voxray::render::beam::MIN_MEAN_AREA);
                assert_eq!(report.plan.sphere_lists, cars == crowd || small, "{what}: {}", report.plan.explain());
                assert_eq!(report.plan.beams, cars != crowd && !small, "{what}: {}", report.plan.explain());
                searched[report.plan.beams as usize] += 1;
                let plain = FramePlan::new(&st.scene, &cam, &lights, &Features::NONE.with_shadows(), None);
                let fresh =
                    render(&st.scene, &cam, &lights, &plain, &RenderOptions::default(), None, &|_, _| {}).unwrap();
                assert_same_pixels(session.last_frame().unwrap(), &fresh, &format!("{what}, frame {f}"));
                if let Some(b) = &before {
                    uncovered += b.instance.iter().zip(&fresh.instance).filter(|(a, b)| **a >= 0 && **b < 0).count();
                }
                before = Some(fresh);
            }
            assert!(uncovered > 50, "{what}: cars uncovered only {uncovered} pixels of sky");
        }
        if cars == 2 {
            assert!(searched[0] > 1 && searched[1] > 1, "two cars: frames with lists and beams {searched:?}");
        }
    }
}

/// A tile is kept without looking at its records only when none of them is on a moved
/// instance: here the buffer's stored spheres of the parts, which then move, are shrunk to a
/// point far away, so no moved sphere covers the pixels that still show the parts where they
/// were. They must be traced again all the same.
#[test]
fn a_kept_tile_has_no_record_on_a_moved_instance() {
    let (mut scene, cars) = cars_scene(0);
    let lights = Lights::default();
    let cam = camera();
    let features = Features { shadows: false, ..Features::default() };
    let mut hits = HitBuffer::new();
    let plan = FramePlan::new(&scene, &cam, &lights, &features, None);
    render(&scene, &cam, &lights, &plan, &RenderOptions::default(), Some(&mut hits), &|_, _| {}).unwrap();
    // The car (the body and its children) leaves the picture: its old pixels show the sky.
    let body = &cars[0];
    let lifted = scene.instances()[body.body].local;
    // Far ahead and high above: in front of the eye (a sphere reaching behind it would cover
    // the whole image) and above the picture.
    let ahead = (cam.target - cam.eye).normalize() * 1000.0 + DVec3::Y * 1000.0;
    let moved = voxray::scene::Transform { translation: lifted.translation + ahead, ..lifted };
    scene.set_local(body.body, moved).unwrap();
    scene.update().unwrap();
    // (Camera-relative centres, in front of the eye and above the picture like the new ones.)
    for s in &mut hits.spheres {
        *s = (ahead * 10.0, 1e-3);
    }
    let plan = FramePlan::new(&scene, &cam, &lights, &features, Some(&hits));
    let fast = render(&scene, &cam, &lights, &plan, &RenderOptions::default(), Some(&mut hits), &|_, _| {}).unwrap();
    let plain = FramePlan::new(&scene, &cam, &lights, &Features::NONE, None);
    let fresh = render(&scene, &cam, &lights, &plain, &RenderOptions::default(), None, &|_, _| {}).unwrap();
    assert!(fast.reused > 0);
    assert_same_pixels(&fast, &fresh, "lifted body");
}
