//! The renderer session against doing its steps by hand: plan, then render on the backend
//! (on the CPU with GI, the frame lit by the cones); and a GPU session whose frames stay on
//! the GPU.

use glam::DVec3;
use voxray::backend::Backend;
use voxray::gi::{self, GiCaches, GiReuse, GiSettings};
use voxray::pipeline::build_parts;
use voxray::render::plan::GiPlan;
use voxray::render::{render, Features, FramePlan, HitBuffer, RenderOptions};
use voxray::scene::car::{add_car, pose};
use voxray::scene::{Camera, Lights, Scene};
use voxray::session::Session;
use voxray::voxelize::Resolution;

/// The car (`driving` or parked), posed, with a camera and the default lights.
fn car_frame(driving: bool) -> (Scene, Camera, Lights) {
    let parts = build_parts(&voxray::model::car::mesh(), Resolution::Depth(5)).unwrap();
    let mut scene = Scene::new(parts);
    let car = add_car(&mut scene, 0, DVec3::ZERO, 0.0, driving).unwrap();
    pose(&mut scene, &car, 0.5).unwrap();
    scene.update().unwrap();
    let cam = Camera {
        eye: DVec3::new(4.0, 3.0, 9.0),
        target: DVec3::new(0.0, 0.5, 0.0),
        up: DVec3::Y,
        vfov_deg: 45.0,
        width: 48,
        height: 32,
    };
    (scene, cam, Lights::default())
}

/// The frame without the radiance caches' stage timings (which two runs never share).
fn untimed(f: &voxray::render::Frame) -> voxray::render::Frame {
    let mut f = f.clone();
    if let Some(s) = &mut f.cache_stages {
        *s = voxray::render::radiance_cache::CacheStages { caches: s.caches, ..Default::default() };
    }
    f
}

#[test]
fn a_session_frame_is_the_plan_the_render_and_gi_done_by_hand() {
    let (scene, cam, lights) = car_frame(false);
    let features = Features::default();
    let opts = RenderOptions::default();
    let g = GiSettings { res: 32, ..GiSettings::default() };

    let mut session = Session::new(Backend::Cpu(Box::default()), "CPU".into());
    session.set_gi(Some(g)).unwrap();
    let first = session.frame(&scene, &cam, &lights, &features, &opts, &|_, _| {}).unwrap();
    let a = session.last_frame().unwrap().clone();
    let second = session.frame(&scene, &cam, &lights, &features, &opts, &|_, _| {}).unwrap();
    let b = session.last_frame().unwrap().clone();

    // By hand, with the same state carried between the two frames.
    let (mut hits, mut caches) = (HitBuffer::new(), GiCaches::new());
    let mut by_hand = |first: bool| {
        let mut plan = FramePlan::new(&scene, &cam, &lights, &features, (!first).then_some(&hits));
        let (f, stats) =
            gi::render_with_gi(&scene, &cam, &lights, &plan, &opts, Some(&mut hits), &g, &mut caches, &|_, _| {})
                .unwrap();
        plan.with_gi(GiPlan { reuse: stats.reuse, layout: stats.layout.unwrap_or_default() });
        (plan, f, stats)
    };
    let (plan_a, hand_a, stats_a) = by_hand(true);
    let (plan_b, hand_b, stats_b) = by_hand(false);
    assert_eq!((&first.plan, &second.plan), (&plan_a, &plan_b));
    assert_eq!(untimed(&a), untimed(&hand_a), "first frame");
    assert_eq!(untimed(&b), untimed(&hand_b), "second frame");
    assert!(a.cache_stages.is_some_and(|s| s.caches > 0), "the default gather is the radiance caches");
    assert_eq!(first.gi.map(|s| s.reuse), Some(stats_a.reuse));
    assert_eq!(second.gi_reuse, Some(stats_b.reuse));
    // Nothing moved: the second frame reuses the hits and GI's level chain.
    assert!(second.plan.hit_buffer && b.reused > 0);
    assert_eq!(second.gi_reuse, Some(GiReuse::Levels));
    // One plan says it all, GI included (`--explain`).
    assert!(second.plan.explain().contains("gi: volume and levels reused"), "{}", second.plan.explain());
    assert!(a.radiance.iter().zip(&b.radiance).all(|(x, y)| x == y));

    // GI off, and a restart: the next frame reuses nothing.
    session.set_gi(None).unwrap();
    session.restart();
    let third = session.frame(&scene, &cam, &lights, &features, &opts, &|_, _| {}).unwrap();
    assert!(!third.plan.hit_buffer && third.gi.is_none() && third.gi_reuse.is_none() && third.plan.gi.is_none());
    let plain = FramePlan::new(&scene, &cam, &lights, &features, None);
    let c = render(&scene, &cam, &lights, &plain, &opts, None, &|_, _| {}).unwrap();
    assert_eq!(session.last_frame(), Some(&c));
}

/// A GPU session whose frames stay on the GPU: the report counts no bytes read back once
/// warm, the kept frame has no pixels, and its image, read on request, is the image of the
/// same frames rendered with read-back on.
#[cfg(feature = "gpu")]
#[test]
fn a_gpu_session_keeps_frames_on_the_gpu_and_reads_the_image_on_request() {
    use voxray::gpu::{GpuContext, GpuRenderer};
    let ctx = match GpuContext::headless() {
        Ok(c) => std::sync::Arc::new(c),
        Err(e) if std::env::var("CI").is_ok_and(|v| v == "true") => panic!("CI needs a GPU adapter: {e}"),
        Err(_) => return,
    };
    let (scene, cam, lights) = car_frame(true);
    let features = Features::default();
    let opts = RenderOptions::default();
    let mut kept = Session::new(Backend::Gpu(Box::new(GpuRenderer::new(ctx.clone()))), "GPU".into());
    let mut read = Session::new(Backend::Gpu(Box::new(GpuRenderer::new(ctx))), "GPU".into());
    kept.set_read_back(false);
    for f in 0..3 {
        let r = kept.frame(&scene, &cam, &lights, &features, &opts, &|_, _| {}).unwrap();
        read.frame(&scene, &cam, &lights, &features, &opts, &|_, _| {}).unwrap();
        assert_eq!(r.gpu_traffic.map(|t| t.1), Some(0), "frame {f} read back");
        assert!(r.gpu_pass_ms.is_none());
        assert!(kept.last_frame().is_some_and(|fr| fr.on_device && fr.radiance.is_empty()));
    }
    let expected = read.last_frame().unwrap().radiance.clone();
    assert_eq!(kept.image().unwrap(), Some(expected.clone()));
    assert_eq!(read.image().unwrap(), Some(expected));
}
