//! Beams (`render::beam`): primary rays started at their tile's conservative start t find
//! exactly the hits they find from the eye, over rotated, anisotropically scaled, tiny and
//! huge instances, cameras inside and grazing the parts, narrow and wide fields of view,
//! images whose sides are not multiples of the tile, and levels of detail. With beams on, a
//! tile's rays also go through each octree as one packet (its primary rays, and the sun's
//! shadow rays of its pixels), so these comparisons check the packets against the rays one
//! by one as well.

mod common;
use common::assert_same_frames;
use glam::{DQuat, DVec3};
use std::sync::{Arc, OnceLock};
use voxray::pipeline::build_parts;
use voxray::render::{render, Features, Frame, FramePlan, RenderOptions};
use voxray::scene::{Camera, Instance, Lights, Scene, Transform};
use voxray::svo::Svo;
use voxray::voxelize::Resolution;

fn car_parts() -> Vec<Arc<Svo>> {
    static PARTS: OnceLock<Vec<Arc<Svo>>> = OnceLock::new();
    PARTS.get_or_init(|| build_parts(&voxray::model::car::mesh(), Resolution::Depth(7)).unwrap()).clone()
}

/// Every car part three times: in place, rotated and stretched (5 × 0.3 × 1), and shrunk or
/// blown up, spread along x.
fn scene() -> Scene {
    let parts = car_parts();
    let mut s = Scene::new(parts.clone());
    for part in 0..parts.len() {
        s.add(Instance { part, parent: None, local: Transform::IDENTITY }).unwrap();
        let q = DQuat::from_euler(glam::EulerRot::XYZ, 0.3 + part as f64, 1.1, -0.4 * part as f64);
        let stretched = Transform::new(DVec3::new(6.0, 0.5, 0.0), q, DVec3::new(5.0, 0.3, 1.0)).unwrap();
        s.add(Instance { part, parent: None, local: stretched }).unwrap();
        let k = if part % 2 == 0 { 0.01 } else { 40.0 };
        let scaled =
            Transform::new(DVec3::new(-8.0 - 30.0 * (part % 2) as f64, 0.0, -3.0), q.inverse(), DVec3::splat(k));
        s.add(Instance { part, parent: None, local: scaled.unwrap() }).unwrap();
    }
    s.update().unwrap();
    s
}

/// How a frame's primary rays find their instances.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Primary {
    /// Beams and packets (forced where the plan takes sphere lists for instances a few pixels
    /// wide).
    Beams,
    /// Per-pixel sphere lists (forced).
    Lists,
    /// Neither: each ray from the eye.
    Plain,
}

fn frame_with(s: &Scene, cam: &Camera, primary: Primary, max_level: u32) -> Frame {
    frame_under(s, cam, primary, max_level, &Lights::default())
}

fn frame_under(s: &Scene, cam: &Camera, primary: Primary, max_level: u32, lights: &Lights) -> Frame {
    let features = Features { beams: primary != Primary::Plain, hit_buffer: false, ..Features::default() };
    let mut plan = FramePlan::new(s, cam, lights, &features, None);
    match primary {
        Primary::Beams => (plan.beams, plan.bvh_beams, plan.sphere_lists) = (true, false, false),
        Primary::Lists => (plan.beams, plan.sphere_lists) = (false, true),
        Primary::Plain => assert!(!plan.beams && !plan.sphere_lists, "{}", plan.explain()),
    }
    render(s, cam, lights, &plan, &RenderOptions { max_level, ..Default::default() }, None, &|_, _| {}).unwrap()
}

/// A camera `from` a car placed at `car`, looking at the car's middle.
fn close_to(car: DVec3, from: DVec3, vfov_deg: f64, width: u32, height: u32) -> Camera {
    Camera { eye: car + from, target: car + DVec3::new(0.0, 0.6, 0.0), up: DVec3::Y, vfov_deg, width, height }
}

fn frame(s: &Scene, cam: &Camera, beams: bool, max_level: u32) -> Frame {
    frame_with(s, cam, if beams { Primary::Beams } else { Primary::Plain }, max_level)
}

#[test]
fn beams_find_exactly_the_hits_rays_from_the_eye_find() {
    let s = scene();
    let cam = |eye: DVec3, target: DVec3, vfov_deg: f64, width: u32, height: u32| Camera {
        eye,
        target,
        up: DVec3::Y,
        vfov_deg,
        width,
        height,
    };
    let cameras = [
        ("overview", cam(DVec3::new(3.0, 6.0, 22.0), DVec3::new(0.0, 0.5, 0.0), 50.0, 96, 64)),
        ("close, odd size", cam(DVec3::new(1.2, 1.0, 2.4), DVec3::new(0.0, 0.6, 0.0), 60.0, 67, 41)),
        ("inside the body", cam(DVec3::new(0.1, 0.7, 0.2), DVec3::new(2.0, 0.5, 1.0), 90.0, 48, 40)),
        ("grazing the stretched parts", cam(DVec3::new(14.0, 0.52, 0.3), DVec3::new(0.0, 0.5, 0.0), 30.0, 80, 24)),
        ("narrow", cam(DVec3::new(-2.0, 3.0, 15.0), DVec3::new(0.0, 0.6, 0.0), 1.5, 40, 40)),
        ("wide", cam(DVec3::new(0.0, 2.0, 6.0), DVec3::new(0.0, 0.5, 0.0), 150.0, 64, 48)),
        ("the blown-up part", cam(DVec3::new(-30.0, 30.0, 60.0), DVec3::new(-38.0, 0.0, -3.0), 40.0, 64, 48)),
    ];
    let mut skipped = 0;
    for (name, c) in &cameras {
        for max_level in [u32::MAX, 3] {
            let with = frame(&s, c, true, max_level);
            let without = frame(&s, c, false, max_level);
            assert_same_frames(&with, &without, &format!("{name}, level {max_level}"));
            assert!(with.instances_traced <= without.instances_traced, "{name}: beams traced more");
            skipped += without.instances_traced - with.instances_traced;
        }
    }
    // The beams must actually rule instances out (else this test proves nothing).
    assert!(skipped > 10_000, "beams skipped only {skipped} instance traversals");
}

/// With beams, a frame's sun shadow rays go as packets before the shading, and the shading
/// takes their answers for the sun's rays only: the other suns', the points' and the spots'
/// shadow rays are its own. Frames lit by all of them, with beams and without (every shadow
/// ray then traced alone), are the same.
#[test]
fn only_the_suns_shadow_rays_take_the_sun_pass_answers() {
    use glam::Vec3;
    use voxray::scene::lights::{PointLight, SpotLight, Sun};
    let s = scene();
    let sun =
        |x: f32, y: f32, z: f32, e: f32| Sun { to_sun: Vec3::new(x, y, z).normalize(), irradiance: Vec3::splat(e) };
    let lights = Lights {
        sun: Some(sun(0.5, 0.7, 0.3, 2.0)),
        // Low and from the other side: its shadows fall elsewhere than the sun's.
        suns: vec![sun(-0.8, 0.3, -0.4, 1.5)],
        points: vec![PointLight { position: DVec3::new(-1.5, 2.5, 2.0), intensity: Vec3::new(4.0, 3.0, 2.0) }],
        spots: vec![SpotLight {
            position: DVec3::new(2.0, 3.0, -1.0),
            direction: Vec3::new(-0.5, -1.0, 0.3).normalize(),
            intensity: Vec3::new(3.0, 4.0, 6.0),
            inner_deg: 15.0,
            outer_deg: 30.0,
        }],
        ..Lights::default()
    };
    let c = close_to(DVec3::ZERO, DVec3::new(2.5, 2.0, 4.0), 50.0, 80, 56);
    let with = frame_under(&s, &c, Primary::Beams, u32::MAX, &lights);
    let without = frame_under(&s, &c, Primary::Plain, u32::MAX, &lights);
    assert_same_frames(&with, &without, "sun, another sun, a point and a spot");
    assert!(with.shadow_rays > 0 && without.shadow_rays > 0, "no shadow rays were asked for");
}

/// Sixty small instances seen from afar, each a few pixels wide at a random place in its
/// tile: a cone even slightly narrower than the tile's rays, or a start slightly late, loses
/// some of them.
#[test]
fn beams_keep_the_specks_at_tile_corners() {
    let parts = car_parts();
    let mut s = Scene::new(parts.clone());
    let mut rng = voxray::rng::Rng::new(17);
    for k in 0..60 {
        let part = k % parts.len();
        let at = DVec3::new(rng.range(-6.0, 6.0) as f64, rng.range(-4.0, 4.0) as f64, rng.range(-3.0, 3.0) as f64);
        let q = DQuat::from_rotation_y(rng.range(0.0, 6.0) as f64);
        let t = Transform::new(at, q, DVec3::splat(rng.range(0.2, 0.6) as f64)).unwrap();
        s.add(Instance { part, parent: None, local: t }).unwrap();
    }
    s.update().unwrap();
    let mut hits = 0;
    for (k, eye) in
        [DVec3::new(0.0, 2.0, 30.0), DVec3::new(25.0, 10.0, 12.0), DVec3::new(-3.0, -20.0, 18.0)].iter().enumerate()
    {
        let c =
            Camera { eye: *eye, target: DVec3::ZERO, up: DVec3::Y, vfov_deg: 35.0, width: 120 + k as u32, height: 90 };
        let (with, without) = (frame(&s, &c, true, u32::MAX), frame(&s, &c, false, u32::MAX));
        assert_eq!(with.instance, without.instance, "camera {k}: instances");
        assert_eq!(with.t, without.t, "camera {k}: t");
        // Specks this small take the sphere lists: the same hits.
        let plan = FramePlan::new(&s, &c, &Lights::default(), &Features::default(), None);
        assert!(plan.sphere_lists && !plan.beams, "camera {k}: {}", plan.explain());
        let listed = frame_with(&s, &c, Primary::Lists, u32::MAX);
        assert_same_frames(&listed, &without, &format!("camera {k}, sphere lists"));
        hits += with.instance.iter().filter(|&&i| i >= 0).count();
    }
    assert!(hits > 500, "the specks should show ({hits} pixels)");
}

/// Whether beams or sphere lists serve a few instances depends on how many pixels they cover
/// ([`voxray::render::beam::MIN_MEAN_AREA`]): two cars a few pixels wide take the lists, the
/// same close up or over a ground (whose sphere spans the image) take beams, and so does a
/// frame whose hit buffer keeps pixels. With shadows, every choice gives the frame the plain
/// search gives, bit for bit.
#[test]
fn few_instances_take_lists_when_small_on_screen() {
    let parts = car_parts();
    for (ground, far, hit_buffer, lists) in [
        (false, true, false, true),
        (false, false, false, false),
        (true, true, false, false),
        (false, true, true, false),
    ] {
        let what = format!("ground {ground}, far {far}, hit buffer {hit_buffer}");
        let mut st = voxray::scene::stage_cars(&parts, 2, true, ground).unwrap();
        voxray::scene::car::pose_all(&mut st.scene, &st.cars, 0.8).unwrap();
        st.scene.update().unwrap();
        let (lo, hi) = (st.bounds.0.as_vec3(), st.bounds.1.as_vec3());
        let cam = if far {
            Camera::framing(lo, hi, 128, 80)
        } else {
            close_to(st.scene.world(0).translation, DVec3::new(2.5, 1.5, 4.0), 50.0, 128, 80)
        };
        let lights = Lights::default();
        let features = Features { hit_buffer, ..Features::default() };
        let plain = FramePlan::new(&st.scene, &cam, &lights, &Features::NONE.with_shadows(), None);
        let want = render(&st.scene, &cam, &lights, &plain, &RenderOptions::default(), None, &|_, _| {}).unwrap();
        let mut kept = voxray::render::HitBuffer::new();
        for f in 0..2 {
            let plan = FramePlan::new(&st.scene, &cam, &lights, &features, (f > 0).then_some(&kept));
            // (A first frame keeps nothing.)
            let lists = lists || (hit_buffer && f == 0);
            assert_eq!((plan.sphere_lists, plan.beams), (lists, !lists), "{what}, frame {f}: {}", plan.explain());
            assert!(plan.shadows, "{}", plan.explain());
            let got = render(&st.scene, &cam, &lights, &plan, &RenderOptions::default(), Some(&mut kept), &|_, _| {})
                .unwrap();
            assert_same_frames(&got, &want, &format!("{what}, frame {f}"));
            let covered = got.instance.iter().filter(|&&i| i >= 0).count();
            assert!(covered > 40, "{what}: the cars cover only {covered} pixels");
        }
    }
}

/// A crowd at the beams' instance limit (`beam::MAX_INSTANCES`: 16 driving cars, 128
/// instances, with shadows): beams on and off give the same hits, normals and image bit for
/// bit, and the crowd one car more is past the limit.
#[test]
fn beams_stay_exact_for_a_crowd_under_the_instance_limit() {
    let parts = car_parts();
    let cars = voxray::render::beam::MAX_INSTANCES / parts.len();
    let mut st = voxray::scene::stage_cars(&parts, cars, true, false).unwrap();
    voxray::scene::car::pose_all(&mut st.scene, &st.cars, 0.37).unwrap();
    st.scene.update().unwrap();
    assert!(st.scene.instances().len() <= voxray::render::beam::MAX_INSTANCES);
    // The whole crowd from afar, and one car from close by with others behind it (where a
    // late start shows: its surfaces lie just past the tiles' bounds).
    let (lo, hi) = (st.bounds.0.as_vec3(), st.bounds.1.as_vec3());
    let close = close_to(st.scene.world(0).translation, DVec3::new(1.2, 1.0, 2.4), 60.0, 96, 64);
    for (name, cam) in [("crowd", Camera::framing(lo, hi, 192, 128)), ("one car close", close)] {
        check_crowd_frame(&st.scene, &cam, name);
    }
    let more = voxray::scene::stage_cars(&parts, cars + 1, true, false).unwrap();
    let plan = FramePlan::new(&more.scene, &close, &Lights::default(), &Features::default(), None);
    assert!(!plan.beams, "{}", plan.explain());
}

/// A crowd past the instance limit (20 driving cars, 160 instances) searches per-pixel sphere
/// lists (`render::pixel_spheres`) instead of walking the instance BVH, or, with the lists off,
/// gets beams through the BVH: tiles whose rays' pyramid meets no instance store misses
/// untraced. Over a clip of moving cars and a turning camera, with a hit buffer carried from
/// frame to frame (a beam's miss already stored is not written again), with the hit buffer on
/// and off, every frame of both equals the one rendered with beams off, bit for bit, and tiles
/// are settled. On the ground, whose cars' shadows the sun's rays find through the instance
/// BVH as packets, the frames also equal the plain search's (every ray against every
/// instance, one at a time).
#[test]
fn bvh_beams_stay_exact_for_a_crowd_past_the_instance_limit() {
    let parts = car_parts();
    let cars = voxray::render::beam::MAX_INSTANCES / parts.len() + 4;
    let lights = Lights::default();
    // Without a ground (most tiles settle), and on one (the cars' shadows move over it, so
    // kept pixels' shadow rays meet the moved spheres; the ground's sphere reaches every tile).
    for (ground, hit_buffer) in [(false, false), (false, true), (true, true)] {
        let mut st = voxray::scene::stage_cars(&parts, cars, true, ground).unwrap();
        let (lo, hi) = (st.bounds.0.as_vec3(), st.bounds.1.as_vec3());
        let base = Camera::framing(lo, hi, 192, 112);
        let mut kept: [voxray::render::HitBuffer; 3] = Default::default();
        for f in 0..4 {
            // Three seconds a frame: cars leave tiles that held them.
            let t = 0.2 + f as f64 * 3.0;
            voxray::scene::car::pose_all(&mut st.scene, &st.cars, t).unwrap();
            st.scene.update().unwrap();
            // The camera holds still for frames 1 and 2 (the hit buffer's case), then turns.
            let turn = DQuat::from_rotation_y(if f == 3 { 0.05 } else { 0.0 });
            let cam = Camera { eye: base.target + turn * (base.eye - base.target), ..base };
            let mut frames = Vec::new();
            // Sphere lists, beams through the BVH without them, neither.
            for (k, (beams, lists)) in [(true, true), (true, false), (false, false)].into_iter().enumerate() {
                let features = Features { beams, hit_buffer, ..Features::default() };
                let mut plan = FramePlan::new(&st.scene, &cam, &lights, &features, (f > 0).then_some(&kept[k]));
                assert_eq!((plan.bvh_beams, plan.sphere_lists), (beams, beams), "{}", plan.explain());
                assert!(!plan.beams && plan.bvh, "{}", plan.explain());
                plan.sphere_lists = lists;
                let opts = RenderOptions::default();
                frames.push(render(&st.scene, &cam, &lights, &plan, &opts, Some(&mut kept[k]), &|_, _| {}).unwrap());
            }
            let what = format!("ground {ground}, hit buffer {hit_buffer}, frame {f}");
            let covered = frames[0].instance.iter().filter(|&&i| i >= 0).count();
            assert!(covered > 100, "{what}: the crowd covers only {covered} pixels");
            assert_same_frames(&frames[0], &frames[2], &format!("{what}, sphere lists"));
            assert_same_frames(&frames[1], &frames[2], &format!("{what}, beams through the BVH"));
            if ground {
                let plain = FramePlan::new(&st.scene, &cam, &lights, &Features::NONE.with_shadows(), None);
                let opts = RenderOptions::default();
                let oracle = render(&st.scene, &cam, &lights, &plain, &opts, None, &|_, _| {}).unwrap();
                assert_same_frames(&frames[2], &oracle, &format!("{what}, against the plain search"));
            }
            if hit_buffer {
                // The kept hits and colours (with the sun's shadow rays checked against the
                // 320 moved spheres through their BVH) against a frame rendered afresh.
                let features = Features { hit_buffer: false, ..Features::default() };
                let plan = FramePlan::new(&st.scene, &cam, &lights, &features, None);
                let fresh =
                    render(&st.scene, &cam, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap();
                assert_same_frames(&frames[0], &fresh, &format!("{what}, against no reuse"));
                assert!(plan.shadows, "{}", plan.explain());
                if f == 2 {
                    assert!(frames[0].shade_reused > 0, "{what}: no colour kept");
                }
            }
            if f == 0 && !ground {
                // Rays of settled tiles test no leaf's spheres.
                assert!(
                    frames[1].spheres_culled < frames[2].spheres_culled,
                    "{what}: no tile settled ({} spheres culled with, {} without)",
                    frames[1].spheres_culled,
                    frames[2].spheres_culled
                );
                // The lists were built (they are, unless the spheres overlap deeply): a ray
                // traces the instances of its list, as the depth-sorted search does.
                let prepared = voxray::render::instances::prepare(&st.scene, cam.eye, true);
                let spheres: Vec<_> = prepared.iter().map(|p| (p.centre, p.radius)).collect();
                let lists = voxray::render::pixel_spheres::PixelSpheres::build(&cam, &spheres);
                assert!(lists.is_some_and(|l| !l.is_empty()), "{what}: no sphere lists");
            }
        }
    }
}

fn check_crowd_frame(scene: &Scene, cam: &Camera, name: &str) {
    let with = frame(scene, cam, true, u32::MAX);
    let without = frame(scene, cam, false, u32::MAX);
    assert_same_frames(&frame_with(scene, cam, Primary::Lists, u32::MAX), &without, &format!("{name}, sphere lists"));
    let covered = with.instance.iter().filter(|&&i| i >= 0).count();
    assert!(covered > 200, "{name}: the crowd covers only {covered} pixels");
    assert_same_frames(&with, &without, name);
    assert!(with.instances_traced < without.instances_traced, "{name}: beams ruled no instance out");
}

/// A crowd frame without shadow rays searches its sphere lists and leaves the instance BVH
/// as it was (nothing else in it walks the tree); the next frame with shadows refits the kept
/// tree, every box of it, to its own spheres. Every frame equals one rendered afresh.
#[test]
fn a_frame_without_shadow_rays_leaves_the_bvh_for_the_next() {
    let parts = car_parts();
    let cars = voxray::render::beam::MAX_INSTANCES / parts.len() + 4;
    let lights = Lights::default();
    let mut st = voxray::scene::stage_cars(&parts, cars, true, true).unwrap();
    let cam = Camera::framing(st.bounds.0.as_vec3(), st.bounds.1.as_vec3(), 192, 112);
    let mut kept = voxray::render::HitBuffer::new();
    for f in 0..4 {
        voxray::scene::car::pose_all(&mut st.scene, &st.cars, 0.2 + f as f64 * 3.0).unwrap();
        st.scene.update().unwrap();
        let features = Features { shadows: f % 2 == 1, hit_buffer: false, ..Features::default() };
        let plan = FramePlan::new(&st.scene, &cam, &lights, &features, (f > 0).then_some(&kept));
        assert!(plan.sphere_lists && plan.bvh, "{}", plan.explain());
        let opts = RenderOptions::default();
        let with = render(&st.scene, &cam, &lights, &plan, &opts, Some(&mut kept), &|_, _| {}).unwrap();
        let plan = FramePlan::new(&st.scene, &cam, &lights, &features, None);
        let fresh = render(&st.scene, &cam, &lights, &plan, &opts, None, &|_, _| {}).unwrap();
        assert_same_frames(&with, &fresh, &format!("frame {f}"));
        // Frame 0 built no tree; frame 1 built one; frame 2 left it; frame 3 refitted it.
        assert_eq!(kept.bvh.is_some(), f > 0, "frame {f}");
    }
}
