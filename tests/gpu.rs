//! The GPU path against the CPU, on whatever adapter wgpu finds (Mesa's software Vulkan
//! driver in CI). In CI (CI=true) a missing adapter fails these tests; elsewhere they are
//! skipped with a message.
#![cfg(feature = "gpu")]

use glam::{DQuat, DVec3, Vec3};
use std::sync::Arc;
use voxray::gpu::layout::GpuRay;
use voxray::gpu::rays::trace_rays;
use voxray::gpu::{GpuContext, GpuError, GpuRenderer};
use voxray::pipeline::build_parts;
use voxray::ray::UnitRay;
use voxray::render::{render, Features, Frame, FramePlan, HitBuffer, RenderOptions};
use voxray::scene::car::{add_car, pose, Car};
use voxray::scene::{Camera, Lights, Scene};
use voxray::stability::{check_with, merge, standard_cases, CaseReport, Ray64};
use voxray::svo::Svo;
use voxray::traverse::{trace_unit, Hit, TraceOptions};
use voxray::voxelize::Resolution;

mod common;

use common::gpu_context as context;

/// GPU t is computed in f32 from an f32 ray (the CPU uses f64): allow 10⁻⁴ relative.
const GPU_T_TOLERANCE: f64 = 1e-4;

#[test]
fn gpu_traces_the_stability_suite_like_the_cpu() {
    let Some(ctx) = context() else { return };
    eprintln!("GPU: {}", ctx.describe());
    for case in standard_cases(100_000) {
        let max_level = case.max_level.unwrap_or(u32::MAX);
        let rays: Vec<GpuRay> = case
            .rays
            .iter()
            .map(|r| GpuRay {
                origin: [r.origin.x, r.origin.y, r.origin.z, 0.0],
                dir: [r.dir.x, r.dir.y, r.dir.z, 0.0],
                t_min: r.t_min,
                t_max: r.t_max,
                max_level: max_level.min(64),
                pad: 0,
            })
            .collect();
        let gpu = trace_rays(&ctx, &case.svo, &rays).unwrap();
        let oracle_set = match case.max_level {
            Some(l) => case.set.coarsen(l),
            None => case.set.clone(),
        };
        let (mut same, mut report) = (0u64, CaseReport::default());
        for (r, g) in case.rays.iter().zip(&gpu) {
            let cpu = UnitRay::from_unit(r.origin.as_dvec3(), r.dir.as_dvec3()).and_then(|u| {
                trace_unit(&case.svo, &u, &TraceOptions { t_min: r.t_min, t_max: r.t_max, max_level }).hit
            });
            let gh = (g.hit == 1).then(|| Hit {
                t: g.t,
                level: g.level,
                coord: [g.coord[0], g.coord[1], g.coord[2]],
                attr: Default::default(),
                face_normal: glam::Vec3::ZERO,
            });
            let agree = match (&cpu, &gh) {
                (None, None) => true,
                (Some(c), Some(g)) => {
                    c.coord == g.coord && ((c.t - g.t).abs() as f64) <= GPU_T_TOLERANCE * (c.t.abs() as f64).max(1.0)
                }
                _ => false,
            };
            if agree {
                same += 1;
            } else {
                // Where they differ, the GPU's answer must itself satisfy the oracle.
                report = merge(report, check_with(&oracle_set, &Ray64::from(r), gh, g.steps, false, GPU_T_TOLERANCE));
            }
        }
        let n = case.rays.len() as u64;
        assert_eq!(report.mismatches, 0, "{}: {:?}", case.name, report.first_mismatch);
        assert!(same * 1000 >= n * 999, "{}: only {same} of {n} rays identical to the CPU", case.name);
        eprintln!("{}: {same} of {n} identical, {} differ but valid", case.name, report.rays);
    }
}

fn car_parts() -> Vec<Arc<Svo>> {
    build_parts(&voxray::model::car::mesh(), Resolution::Depth(6)).unwrap()
}

/// The cars' street seen from down the road, `width` × `height` pixels.
fn street_camera(width: u32, height: u32) -> Camera {
    Camera {
        eye: DVec3::new(0.0, 4.0, 28.0),
        target: DVec3::new(0.0, 0.5, 0.0),
        up: DVec3::Y,
        vfov_deg: 45.0,
        width,
        height,
    }
}

fn scene(cars: usize) -> (Scene, Vec<Car>) {
    let mut scene = Scene::new(car_parts());
    let mut placed = vec![add_car(&mut scene, 0, DVec3::ZERO, 0.0, false).unwrap()];
    for k in 0..cars {
        placed.push(add_car(&mut scene, 0, DVec3::new(0.0, 0.0, 8.0 + 3.0 * k as f64), 1.3 * k as f64, true).unwrap());
    }
    scene.update().unwrap();
    (scene, placed)
}

fn assert_close(cpu: &Frame, gpu: &Frame, what: &str) {
    let n = cpu.t.len();
    let same = cpu.instance.iter().zip(&gpu.instance).filter(|(a, b)| a == b).count();
    assert!(same as f64 >= 0.9999 * n as f64, "{what}: instance ids agree on {same} of {n} pixels");
    for k in 0..n {
        assert!(!gpu.t[k].is_nan() && gpu.radiance[k].is_finite(), "{what}: NaN at pixel {k}");
        if cpu.instance[k] >= 0 && cpu.instance[k] == gpu.instance[k] {
            let rel = ((cpu.t[k] - gpu.t[k]) / cpu.t[k]).abs();
            assert!(rel <= 1e-4, "{what}: pixel {k}: t {} vs {} (rel {rel:e})", cpu.t[k], gpu.t[k]);
        }
    }
    // The same searches cost the same work (sphere tests in f32 on the GPU may flip a few).
    for (what_n, c, g) in [
        ("instances traversed", cpu.instances_traced, gpu.instances_traced),
        ("spheres culled", cpu.spheres_culled, gpu.spheres_culled),
        ("pixels kept", cpu.reused, gpu.reused),
        ("moved-only rays", cpu.moved_only, gpu.moved_only),
    ] {
        let tol = 16 + c / 200;
        assert!(c.abs_diff(g) <= tol, "{what}: {what_n} CPU {c} vs GPU {g}");
    }
    let mean: f32 =
        cpu.radiance.iter().zip(&gpu.radiance).map(|(a, b)| (*a - *b).abs().max_element()).sum::<f32>() / n as f32;
    assert!(mean < 0.01, "{what}: mean radiance difference {mean}");
    // A lost shadow or light changes few pixels but changes them a lot.
    let far = cpu.radiance.iter().zip(&gpu.radiance).filter(|(a, b)| (**a - **b).abs().max_element() > 0.05).count();
    assert!(far as f64 <= 0.002 * n as f64, "{what}: {far} of {n} pixels differ by more than 0.05");
}

/// Renders a clip on both renderers and compares every frame.
fn compare_clip(cars: usize, frames: usize, orbit: f64, features: Features) {
    let Some(ctx) = context() else { return };
    // The GPU traces every primary ray from the eye; without beams on the CPU too, the two
    // searches do the same work (tests/beams.rs shows beams change no CPU hit).
    let features = Features { beams: false, ..features };
    let (mut s_cpu, cars_cpu) = scene(cars);
    let (mut s_gpu, cars_gpu) = scene(cars);
    let lights = Lights::default();
    let mut cpu_hits = HitBuffer::new();
    let mut gpu = GpuRenderer::new(ctx);
    let base = street_camera(160, 100);
    for f in 0..frames {
        let t = f as f64 / 30.0;
        for (a, b) in cars_cpu.iter().zip(&cars_gpu) {
            pose(&mut s_cpu, a, t).unwrap();
            pose(&mut s_gpu, b, t).unwrap();
        }
        s_cpu.update().unwrap();
        s_gpu.update().unwrap();
        let q = DQuat::from_rotation_y((orbit * t).to_radians());
        let cam = Camera { eye: base.target + q * (base.eye - base.target), ..base };
        let plan_cpu = FramePlan::new(&s_cpu, &cam, &lights, &features, (f > 0).then_some(&cpu_hits));
        let plan_gpu = FramePlan::new(&s_gpu, &cam, &lights, &features, (f > 0).then_some(&gpu.state));
        assert_eq!(plan_cpu, plan_gpu);
        let c = render(&s_cpu, &cam, &lights, &plan_cpu, &RenderOptions::default(), Some(&mut cpu_hits), &|_, _| {})
            .unwrap();
        let g = gpu.render(&s_gpu, &cam, &lights, &plan_gpu, &RenderOptions::default()).unwrap();
        assert_close(&c, &g, &format!("{cars} driving cars, frame {f}, plan {:?}", plan_gpu.search()));
        if plan_gpu.hit_buffer && orbit == 0.0 {
            assert!(g.reused > 0, "frame {f}: the GPU hit buffer reused nothing");
            assert!(g.moved_only > 0, "frame {f}: no GPU pixel searched the moved instances only");
        }
    }
}

#[test]
fn gpu_matches_cpu_static_camera_with_hit_buffer() {
    compare_clip(1, 4, 0.0, Features::default());
}

#[test]
fn gpu_matches_cpu_moving_camera() {
    compare_clip(1, 3, 25.0, Features::default());
}

#[test]
fn gpu_matches_cpu_without_optimizations() {
    compare_clip(1, 2, 0.0, Features::NONE.with_shadows());
}

#[test]
fn gpu_matches_cpu_with_many_cars_and_the_bvh() {
    compare_clip(5, 2, 0.0, Features::default());
}

#[test]
fn pools_split_across_two_bindings_render_the_same() {
    let Some(ctx) = context() else { return };
    let (mut scene_a, cars) = scene(1);
    let lights = Lights::default();
    let cam = Camera {
        eye: DVec3::new(5.0, 3.0, 9.0),
        target: DVec3::new(0.0, 0.5, 2.0),
        up: DVec3::Y,
        vfov_deg: 50.0,
        width: 96,
        height: 64,
    };
    for c in &cars {
        pose(&mut scene_a, c, 1.0).unwrap();
    }
    scene_a.update().unwrap();
    let plan = FramePlan::new(&scene_a, &cam, &lights, &Features::default(), None);
    let mut whole = GpuRenderer::new(ctx.clone());
    let a = whole.render(&scene_a, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    // Lower the binding limit so the attribute pool (always the larger) splits about in half.
    let attrs: usize = scene_a.parts.iter().map(|p| p.attrs.len()).sum();
    let mut split = GpuRenderer::new(ctx.clone());
    split.max_binding = (attrs as u64 * std::mem::size_of::<voxray::svo::Attr>() as u64).div_ceil(2) + 8;
    let b = split.render(&scene_a, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    assert_ne!(split.splits().1, u32::MAX, "the attribute pool should have been split");
    assert_eq!(whole.splits(), (u32::MAX, u32::MAX));
    let first_diff =
        (0..a.t.len()).find(|&k| a.instance[k] != b.instance[k] || a.t[k] != b.t[k] || a.radiance[k] != b.radiance[k]);
    assert_eq!(first_diff, None, "split pools render differently (first differing pixel)");
    // Too large even for two bindings: a clear error, not a crash.
    let mut tiny = GpuRenderer::new(ctx);
    tiny.max_binding = 64;
    let e = tiny.render(&scene_a, &cam, &lights, &plan, &RenderOptions::default()).unwrap_err();
    assert!(e.to_string().contains("pool needs"), "{e}");
}

#[test]
fn a_new_part_where_a_dropped_one_lived_is_uploaded_and_traced() {
    let Some(ctx) = context() else { return };
    let lights = Lights::default();
    let cam = street_camera(96, 60);
    let parts = car_parts();
    let (body, door) = ((*parts[0]).clone(), (*parts[5]).clone());
    drop(parts);
    let alone = |svo: Arc<Svo>| {
        let mut s = Scene::new(vec![svo]);
        s.add(voxray::scene::Instance { part: 0, parent: None, local: voxray::scene::Transform::IDENTITY }).unwrap();
        s.update().unwrap();
        s
    };
    let mut gpu = GpuRenderer::new(ctx);
    let first = Arc::new(body);
    let address = Arc::as_ptr(&first);
    {
        let s = alone(first);
        let plan = FramePlan::new(&s, &cam, &lights, &Features { beams: false, ..Features::default() }, None);
        gpu.render(&s, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    }
    // The body's scene and its only Arc are gone; a part of the same type allocated now could
    // take its address (the allocator hands back the block just freed) unless the renderer's
    // key holds it. Either way the new part must be the one traced.
    // Allocate copies of the door until one lands where the body was (held ones pin other
    // addresses); a renderer keyed by address would take that one for the body.
    let mut held = Vec::new();
    let mut second = Arc::new(door.clone());
    while Arc::as_ptr(&second) != address && held.len() < 64 {
        held.push(std::mem::replace(&mut second, Arc::new(door.clone())));
    }
    eprintln!("new part at the dropped part's address: {}", Arc::as_ptr(&second) == address);
    let s = alone(second);
    let plan = FramePlan::new(&s, &cam, &lights, &Features { beams: false, ..Features::default() }, None);
    let g = gpu.render(&s, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    let c = render(&s, &cam, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap();
    assert!(c.instance.iter().any(|&i| i >= 0), "the door should be in view");
    assert_close(&c, &g, "a new part after a dropped one");
}

/// The GPU's image-sized buffers go through the memory budget: a frame that needs more is
/// refused before any buffer is created, and the same renderer draws it under a larger one.
#[test]
fn gpu_frames_respect_the_memory_budget() {
    let Some(ctx) = context() else { return };
    let (s, _) = scene(1);
    let (lights, cam) = (Lights::default(), street_camera(256, 160));
    let plan = FramePlan::new(&s, &cam, &lights, &Features::default(), None);
    let mut gpu = GpuRenderer::new(ctx.clone());
    let e = voxray::memory::with_budget(1 << 20, || gpu.render(&s, &cam, &lights, &plan, &RenderOptions::default()))
        .unwrap_err();
    assert!(matches!(e, GpuError::Memory(_)), "{e}");
    assert!(e.to_string().contains("a 256×160 frame on the GPU needs about"), "{e}");
    let ok = voxray::memory::with_budget(64 << 20, || gpu.render(&s, &cam, &lights, &plan, &RenderOptions::default()));
    assert!(ok.is_ok_and(|f| f.instance.iter().any(|&i| i >= 0)));
}

#[test]
fn device_errors_come_back_as_library_errors() {
    if context().is_none() {
        return;
    }
    // A device of its own: the error raised outside a scope below is device-wide, and the
    // shared context's other tests must not see it.
    let ctx = GpuContext::headless().unwrap();
    // Mapped for reading and a storage buffer at once: WebGPU forbids it (validation).
    let bad = || {
        let _ = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("invalid on purpose"),
            size: 16,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
    };
    let e = ctx
        .scoped(|| {
            bad();
            Ok(())
        })
        .unwrap_err();
    assert!(matches!(e, GpuError::Validation(_)), "{e}");
    assert!(e.to_string().contains("GPU validation error"), "{e}");
    // Outside any scope wgpu's default would panic; the context keeps the error instead.
    bad();
    let e = ctx.check().unwrap_err();
    assert!(matches!(e, GpuError::Validation(_)), "{e}");
    ctx.check().unwrap(); // reported once
                          // The device still renders afterwards.
    let (scene, _) = scene(0);
    let cam = street_camera(32, 20);
    let lights = Lights::default();
    let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
    let mut gpu = GpuRenderer::new(Arc::new(ctx));
    let frame = gpu.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    assert!(frame.instance.iter().any(|&i| i >= 0));
}

#[test]
fn steady_gpu_frames_create_no_buffers() {
    if context().is_none() {
        return;
    }
    // A device of its own: the counts are per device, and other tests share the common one.
    let ctx = Arc::new(GpuContext::headless().unwrap());
    let (mut scene, cars) = scene(1);
    let lights = Lights::default();
    let cam = street_camera(64, 40);
    let mut gpu = GpuRenderer::new(ctx.clone());
    let pixels = (cam.width * cam.height) as u64;
    for f in 0..6 {
        for c in &cars {
            pose(&mut scene, c, f as f64 / 30.0).unwrap();
        }
        scene.update().unwrap();
        let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), (f > 0).then_some(&gpu.state));
        gpu.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
        let (created, read_back) = gpu.frame_traffic;
        if f == 0 {
            assert!(created > 0, "the first frame makes its buffers");
        }
        // Frame 1 may grow the moved-sphere list once (none moved in frame 0).
        if f >= 2 {
            assert_eq!(created, 0, "frame {f} created buffers");
        }
        // Still read back every frame: the hit records and the image (and the timestamps).
        let expected = pixels * (std::mem::size_of::<voxray::gpu::layout::GpuHit>() as u64 + 16);
        // Four timestamps: the trace and shade passes' starts and ends.
        let timestamps = if ctx.timestamps { 32 } else { 0 };
        assert_eq!(read_back, expected + timestamps, "frame {f}");
    }
}

/// Frames that stay on the GPU read nothing back, create no buffers once warm, and leave
/// the GPU's hit buffer exactly as frames read back every time do: after four animated
/// frames kept on the GPU, a fifth one read back equals (bit for bit, image and AOVs and
/// reuse counts) the fifth frame of a renderer that read every frame back. The radiance
/// buffer of a frame kept on the GPU holds the image the read-back frame shows.
#[test]
fn frames_kept_on_the_gpu_read_nothing_back_and_reuse_the_same_hits() {
    if context().is_none() {
        return;
    }
    let ctx = Arc::new(GpuContext::headless().unwrap());
    let (mut scene, cars) = scene(1);
    let lights = Lights::default();
    let cam = street_camera(64, 40);
    let mut every = GpuRenderer::new(ctx.clone());
    let mut kept = GpuRenderer::new(ctx.clone());
    kept.set_read_back(false);
    let mut last = (Frame::default(), Frame::default());
    for f in 0..6 {
        for c in &cars {
            pose(&mut scene, c, f as f64 / 30.0).unwrap();
        }
        scene.update().unwrap();
        if f == 5 {
            kept.set_read_back(true);
        }
        let plan_a = FramePlan::new(&scene, &cam, &lights, &Features::default(), (f > 0).then_some(&every.state));
        let plan_b = FramePlan::new(&scene, &cam, &lights, &Features::default(), (f > 0).then_some(&kept.state));
        assert_eq!(plan_a.hit_buffer, plan_b.hit_buffer, "frame {f}: the plan must not depend on read-back");
        let a = every.render(&scene, &cam, &lights, &plan_a, &RenderOptions::default()).unwrap();
        let b = kept.render(&scene, &cam, &lights, &plan_b, &RenderOptions::default()).unwrap();
        let (created, read_back) = kept.frame_traffic;
        if f < 5 {
            assert!(b.on_device && b.radiance.is_empty() && b.t.is_empty(), "frame {f}");
            assert_eq!(read_back, 0, "frame {f} read back");
            if f >= 2 {
                assert_eq!(created, 0, "frame {f} created buffers");
            }
            // What stayed on the GPU is the image the other renderer read back.
            let (_, w, h) = kept.radiance().unwrap();
            assert_eq!((w, h), (cam.width, cam.height));
            assert_eq!(kept.read_image().unwrap(), a.radiance, "frame {f}");
        }
        last = (a, b);
    }
    let (a, b) = last;
    assert!(!b.on_device && a.reused > 0, "the last frame reuses hits");
    assert_eq!((a.reused, a.moved_only), (b.reused, b.moved_only));
    assert_eq!(a.radiance, b.radiance);
    assert_eq!(a.t, b.t);
    assert_eq!(a.instance, b.instance);
    assert_eq!(a.normal, b.normal);
}

/// A crowd with more moved spheres than `MOVED_BVH_MIN`: each pixel tests only the moved
/// spheres of its tile's bin (`Reuse::tile_bins`), and what the GPU keeps and searches anew
/// equals, hit for hit, what it renders with the hit buffer off. The cars move far between
/// frames so that the spheres' new positions reach pixels their old ones did not.
#[test]
fn gpu_frames_with_binned_moved_spheres_equal_frames_rendered_afresh() {
    let Some(ctx) = context() else { return };
    let (mut scene, cars) = scene(6);
    let lights = Lights::default();
    // From above, so that cars seldom hide each other's spheres.
    let cam = Camera {
        eye: DVec3::new(0.0, 40.0, 16.0),
        target: DVec3::new(0.0, 0.0, 15.0),
        up: DVec3::NEG_Z,
        vfov_deg: 60.0,
        width: 160,
        height: 100,
    };
    let mut kept = GpuRenderer::new(ctx.clone());
    let mut fresh = GpuRenderer::new(ctx);
    let no_reuse = Features { hit_buffer: false, ..Features::default() };
    let (mut reused, mut moved_only) = (0, 0);
    for f in 0..4 {
        for c in &cars {
            pose(&mut scene, c, 0.3 * f as f64).unwrap();
        }
        scene.update().unwrap();
        let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), (f > 0).then_some(&kept.state));
        if f > 0 {
            let prepared = voxray::render::instances::prepare(&scene, cam.eye, plan.transform);
            let reuse = kept
                .state
                .reuse(&cam, &scene, &prepared, RenderOptions::default().max_level)
                .expect("the hit buffer is reused");
            assert!(reuse.tile_bins().is_some(), "frame {f}: {} moved spheres, no bins", reuse.moved_spheres.len());
        }
        let a = kept.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
        let plan_b = FramePlan::new(&scene, &cam, &lights, &no_reuse, None);
        let b = fresh.render(&scene, &cam, &lights, &plan_b, &RenderOptions::default()).unwrap();
        let first_diff = (0..a.t.len()).find(|&k| a.instance[k] != b.instance[k] || a.t[k] != b.t[k]);
        assert_eq!(first_diff, None, "frame {f}: a kept or re-searched hit differs from the fresh one");
        assert_eq!(a.radiance, b.radiance, "frame {f}");
        (reused, moved_only) = (reused + a.reused, moved_only + a.moved_only);
    }
    assert!(reused > 0 && moved_only > 0, "kept {reused}, moved-only {moved_only}: the bins went unused");
}

/// Kept hits keep their colours on the GPU too, unless their sun shadow rays meet a moved
/// sphere: frame by frame of a clip under the sun (which turns once, so that a frame keeps
/// nothing), the kept renderer's image is the one a renderer with the hit buffer off shades
/// afresh, bit for bit; colours were kept; the counts agree with the CPU's (whose test is its
/// own, in f64), read back or added up on the GPU. Two cars.
#[test]
fn gpu_kept_colours_equal_colours_shaded_afresh() {
    kept_colours_against_fresh(2);
}

/// As above with a crowd of more moved spheres than are tested one by one: the kept pixels'
/// shadow rays walk the moved spheres' BVH.
#[test]
fn gpu_kept_colours_in_a_crowd_equal_colours_shaded_afresh() {
    kept_colours_against_fresh(10);
}

fn kept_colours_against_fresh(cars: usize) {
    let Some(ctx) = context() else { return };
    // Cars driving over a ground: their shadows move over it, so kept ground pixels' shadow
    // rays meet the moved spheres.
    let mut st = voxray::scene::stage_cars(&car_parts(), cars, true, true).unwrap();
    let cam = Camera::framing(st.bounds.0.as_vec3(), st.bounds.1.as_vec3(), 160, 100);
    let mut kept = GpuRenderer::new(ctx.clone());
    let mut counted = GpuRenderer::new(ctx.clone());
    counted.set_counting(true);
    counted.set_read_back(false);
    let mut fresh = GpuRenderer::new(ctx);
    let mut cpu_hits = HitBuffer::new();
    let no_reuse = Features { hit_buffer: false, ..Features::default() };
    let features = Features { beams: false, ..Features::default() };
    let mut colours = 0;
    for f in 0..6 {
        voxray::scene::car::pose_all(&mut st.scene, &st.cars, 0.2 + 0.25 * f as f64).unwrap();
        st.scene.update().unwrap();
        let scene = &st.scene;
        let mut lights = Lights::default();
        let sun = lights.sun.as_mut().expect("the default lights have a sun");
        if f >= 3 {
            sun.to_sun = (sun.to_sun + Vec3::new(0.3, 0.0, 0.0)).normalize();
        }
        let plan = FramePlan::new(scene, &cam, &lights, &features, (f > 0).then_some(&kept.state));
        if f > 0 && cars > 8 {
            let prepared = voxray::render::instances::prepare(scene, cam.eye, plan.transform);
            let reuse = kept.state.reuse(&cam, scene, &prepared, RenderOptions::default().max_level).unwrap();
            assert!(reuse.moved_spheres.len() > 128 && reuse.moved_bvh.is_some(), "frame {f}: no BVH walk");
        }
        let a = kept.render(scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
        let on_device = counted.render(scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
        let plan_b = FramePlan::new(scene, &cam, &lights, &no_reuse, None);
        let b = fresh.render(scene, &cam, &lights, &plan_b, &RenderOptions::default()).unwrap();
        let first_diff = (0..a.t.len()).find(|&k| a.radiance[k] != b.radiance[k] || a.t[k] != b.t[k]);
        assert_eq!(first_diff, None, "frame {f}: a kept colour differs from the fresh one");
        assert_eq!((on_device.reused, on_device.shade_reused), (a.reused, a.shade_reused), "frame {f}");
        let plan_cpu = FramePlan::new(scene, &cam, &lights, &features, (f > 0).then_some(&cpu_hits));
        let c = render(scene, &cam, &lights, &plan_cpu, &RenderOptions::default(), Some(&mut cpu_hits), &|_, _| {})
            .unwrap();
        let tol = 16 + c.shade_reused / 100;
        assert!(
            c.shade_reused.abs_diff(a.shade_reused) <= tol,
            "frame {f}: colours kept CPU {} vs GPU {}",
            c.shade_reused,
            a.shade_reused
        );
        if f == 3 {
            assert_eq!(a.shade_reused, 0, "the sun turned: no colour is last frame's");
        }
        colours += a.shade_reused;
    }
    assert!(colours > 0, "no colour was kept");
}

/// The statistics the GPU adds up itself (atomics) equal the ones summed from the read-back
/// hit records, frame by frame of an animated clip with shadows; a renderer keeping its
/// frames on the GPU with counting on gets the same counters while reading back only the
/// 32-byte statistics (and the pass times).
#[test]
fn gpu_counters_equal_the_counts_of_the_read_back_records() {
    if context().is_none() {
        return;
    }
    let ctx = Arc::new(GpuContext::headless().unwrap());
    let (mut scene, cars) = scene(2);
    let lights = Lights::default();
    assert!(lights.sun.is_some());
    let cam = street_camera(64, 40);
    let mut read = GpuRenderer::new(ctx.clone());
    read.set_counting(true);
    let mut kept = GpuRenderer::new(ctx.clone());
    kept.set_read_back(false);
    kept.set_counting(true);
    let mut moved_only = 0;
    for f in 0..6 {
        for c in &cars {
            pose(&mut scene, c, f as f64 / 30.0).unwrap();
        }
        scene.update().unwrap();
        let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), (f > 0).then_some(&read.state));
        let a = read.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
        let st = read.stats.expect("counted");
        let counted = (st.reused, st.moved_only, st.instances_traced, st.spheres_culled, st.shadow_rays);
        let summed = (a.reused, a.moved_only, a.instances_traced, a.spheres_culled, a.shadow_rays);
        assert_eq!(counted.0 as u64, summed.0, "frame {f} reused");
        assert_eq!(counted.1 as u64, summed.1, "frame {f} moved-only");
        assert_eq!(counted.2 as u64, summed.2, "frame {f} octrees traversed");
        assert_eq!(counted.3 as u64, summed.3, "frame {f} spheres culled");
        assert_eq!(counted.4 as u64, summed.4, "frame {f} shadow rays");
        let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), (f > 0).then_some(&kept.state));
        let b = kept.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
        assert!(b.on_device);
        assert_eq!(
            (b.reused, b.moved_only, b.instances_traced, b.spheres_culled, b.shadow_rays),
            summed,
            "frame {f} kept on the GPU"
        );
        let timestamps = if ctx.timestamps { 32 } else { 0 };
        assert_eq!(kept.frame_traffic.1, 32 + timestamps, "frame {f}: only the statistics read back");
        moved_only += a.moved_only;
        assert!(a.shadow_rays > 0 && (f == 0 || a.reused > 0), "frame {f}: {summed:?}");
    }
    assert!(moved_only > 0, "the clip has moved-only pixels");
}

/// The emissive-panel room lit by its panel alone: the GPU samples the same points on the
/// emitters (same table, same random numbers) with the same shadow rays as the CPU, so the
/// soft-shadowed image agrees up to f32 rounding.
#[test]
fn emitters_light_the_panel_room_as_on_the_cpu() {
    let Some(ctx) = context() else { return };
    let scene = voxray::bench::gi::panel_room_scene(7).unwrap();
    let cam = voxray::model::panel_room::camera(96, 72);
    let lights = voxray::model::panel_room::lights();
    let features = Features { beams: false, ..Features::default() };
    let plan = FramePlan::new(&scene, &cam, &lights, &features, None);
    assert!(plan.shadows);
    let c = render(&scene, &cam, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap();
    let mut gpu = GpuRenderer::new(ctx);
    gpu.set_counting(true);
    let g = gpu.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    let lit = c.radiance.iter().filter(|r| r.max_element() > 0.05).count();
    assert!(lit > c.radiance.len() / 2, "the panel should light most of the room ({lit} pixels)");
    assert_close(&c, &g, "panel room");
    let rays = (c.shadow_rays as f64, g.shadow_rays as f64);
    assert!((rays.0 - rays.1).abs() <= 0.002 * rays.0 + 16.0, "shadow rays: CPU {} GPU {}", rays.0, rays.1);
}

/// Extra suns, a point and a spot on the GPU against the CPU (the panel room, its panel and
/// the added lights together).
#[test]
fn points_spots_and_extra_suns_light_the_gpu_frame_as_the_cpu() {
    let Some(ctx) = context() else { return };
    let scene = voxray::bench::gi::panel_room_scene(7).unwrap();
    let cam = voxray::model::panel_room::camera(96, 72);
    let lights = Lights {
        suns: vec![voxray::scene::Sun { to_sun: glam::Vec3::new(0.2, 1.0, 0.1), irradiance: glam::Vec3::splat(2.0) }],
        points: vec![voxray::scene::lights::PointLight {
            position: DVec3::new(0.5, 1.5, -0.2),
            intensity: glam::Vec3::new(0.5, 0.8, 1.0),
        }],
        spots: vec![voxray::scene::lights::SpotLight {
            position: DVec3::new(-0.6, 1.8, 0.5),
            direction: glam::Vec3::new(0.3, -1.0, -0.4),
            intensity: glam::Vec3::new(2.0, 0.5, 0.2),
            inner_deg: 15.0,
            outer_deg: 35.0,
        }],
        emitter_samples: 2,
        ..voxray::model::panel_room::lights()
    }
    .validated()
    .unwrap();
    let features = Features { beams: false, ..Features::default() };
    let plan = FramePlan::new(&scene, &cam, &lights, &features, None);
    let c = render(&scene, &cam, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap();
    let mut gpu = GpuRenderer::new(ctx);
    gpu.set_counting(true);
    let g = gpu.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    assert_close(&c, &g, "panel room with a sun, a point and a spot");
    let rays = (c.shadow_rays as f64, g.shadow_rays as f64);
    assert!((rays.0 - rays.1).abs() <= 0.002 * rays.0 + 16.0, "shadow rays: CPU {} GPU {}", rays.0, rays.1);
}

/// The GPU's splat frame against the CPU's: the squares are projected in f32 on the GPU (f64
/// on the CPU), so a pixel centre within rounding of a square's edge may pick the
/// neighbouring square; elsewhere the same square wins, with the same t.
fn assert_splats_close(cpu: &Frame, gpu: &Frame, what: &str) {
    let n = cpu.t.len();
    let covered = cpu.instance.iter().filter(|&&i| i >= 0).count();
    assert!(covered > n / 20, "{what}: the splats cover {covered} of {n} pixels");
    let same = cpu.instance.iter().zip(&gpu.instance).filter(|(a, b)| a == b).count();
    assert!(same as f64 >= 0.998 * n as f64, "{what}: instance ids agree on {same} of {n} pixels");
    let (mut exact, mut agree) = (0usize, 0usize);
    for k in 0..n {
        assert!(!gpu.t[k].is_nan() && gpu.radiance[k].is_finite(), "{what}: NaN at pixel {k}");
        if cpu.instance[k] >= 0 && cpu.instance[k] == gpu.instance[k] {
            agree += 1;
            exact += (((cpu.t[k] - gpu.t[k]) / cpu.t[k]).abs() <= 1e-4) as usize;
        }
    }
    assert!(exact as f64 >= 0.995 * agree as f64, "{what}: t agrees on {exact} of {agree} pixels");
    assert_eq!(gpu.reused, 0, "{what}: a splat frame keeps no hits");
    let mean: f32 =
        cpu.radiance.iter().zip(&gpu.radiance).map(|(a, b)| (*a - *b).abs().max_element()).sum::<f32>() / n as f32;
    assert!(mean < 0.01, "{what}: mean radiance difference {mean}");
}

#[test]
fn gpu_splats_match_the_cpu_splats() {
    let Some(ctx) = context() else { return };
    let (mut s_cpu, cars_cpu) = scene(3);
    let (mut s_gpu, cars_gpu) = scene(3);
    let lights = Lights::default();
    let splat = RenderOptions { renderer: voxray::render::Renderer::Splat, ..RenderOptions::default() };
    let features = Features { beams: false, ..Features::default() };
    let mut cpu_hits = HitBuffer::new();
    let mut gpu = GpuRenderer::new(ctx);
    let base = street_camera(160, 100);
    // A driving clip seen from an orbiting camera, then a close-up whose squares span many
    // pixels each, and a level-of-detail cap.
    for f in 0..4 {
        let t = f as f64 / 30.0;
        for (a, b) in cars_cpu.iter().zip(&cars_gpu) {
            pose(&mut s_cpu, a, t).unwrap();
            pose(&mut s_gpu, b, t).unwrap();
        }
        s_cpu.update().unwrap();
        s_gpu.update().unwrap();
        let q = DQuat::from_rotation_y((20.0 * t).to_radians());
        let mut cam = Camera { eye: base.target + q * (base.eye - base.target), ..base };
        let mut opts = splat;
        if f == 2 {
            cam.eye = DVec3::new(2.5, 1.5, 6.0);
        }
        if f == 3 {
            opts.max_level = 4;
        }
        let plan = FramePlan::new(&s_cpu, &cam, &lights, &features, Some(&cpu_hits));
        let c = render(&s_cpu, &cam, &lights, &plan, &opts, Some(&mut cpu_hits), &|_, _| {}).unwrap();
        let g = gpu.render(&s_gpu, &cam, &lights, &plan, &opts).unwrap();
        assert_splats_close(&c, &g, &format!("splat frame {f}"));
    }
}

/// The rasterizer's quads keep the same splat per pixel as the compute passes, bit for bit:
/// the quads cover exactly the pixel centres the compute passes' squares cover, their depths
/// order as the compute passes' keys, and the depth test keeps the earlier (lower-numbered)
/// splat at equal depth, as the compute passes' lowest number does.
#[test]
fn gpu_splat_quads_draw_what_the_compute_passes_draw() {
    let Some(ctx) = context() else { return };
    let (mut s, cars) = scene(3);
    let lights = Lights::default();
    let compute = RenderOptions { renderer: voxray::render::Renderer::Splat, ..RenderOptions::default() };
    let quads = RenderOptions { splat_draw: voxray::render::SplatDraw::Quads, ..compute };
    let features = Features { beams: false, ..Features::default() };
    let (mut by_compute, mut by_quads) = (GpuRenderer::new(ctx.clone()), GpuRenderer::new(ctx));
    let base = street_camera(160, 100);
    // A driving clip from an orbiting camera, a close-up whose squares span many pixels, a
    // level-of-detail cap, and a second image size (the quads' targets are remade).
    for f in 0..5 {
        let t = f as f64 / 30.0;
        for c in &cars {
            pose(&mut s, c, t).unwrap();
        }
        s.update().unwrap();
        let q = DQuat::from_rotation_y((20.0 * t).to_radians());
        let mut cam = Camera { eye: base.target + q * (base.eye - base.target), ..base };
        let (mut a, mut b) = (compute, quads);
        if f == 2 {
            cam.eye = DVec3::new(2.5, 1.5, 6.0);
        }
        if f == 3 {
            (a.max_level, b.max_level) = (4, 4);
        }
        if f == 4 {
            (cam.width, cam.height) = (97, 61);
        }
        let plan = FramePlan::new(&s, &cam, &lights, &features, None);
        let c = by_compute.render(&s, &cam, &lights, &plan, &a).unwrap();
        let g = by_quads.render(&s, &cam, &lights, &plan, &b).unwrap();
        let what = format!("quads, frame {f}");
        let n = c.instance.len();
        let covered = c.instance.iter().filter(|&&i| i >= 0).count();
        assert!(covered > n / 20, "{what}: the splats cover {covered} of {n} pixels");
        let differ = (0..n).filter(|&k| c.instance[k] != g.instance[k] || c.t[k].to_bits() != g.t[k].to_bits()).count();
        assert_eq!(differ, 0, "{what}: {differ} of {n} pixels keep another splat");
        assert!(c.radiance == g.radiance && c.normal == g.normal, "{what}: the shading differs");
    }
}

/// A traced frame after a splat frame traces afresh: the splatted records never stand in for
/// the rays' hits.
#[test]
fn a_traced_gpu_frame_after_splats_reuses_nothing_of_them() {
    let Some(ctx) = context() else { return };
    let (s, _) = scene(1);
    let lights = Lights::default();
    let cam = street_camera(120, 80);
    let features = Features { beams: false, ..Features::default() };
    let splat = RenderOptions { renderer: voxray::render::Renderer::Splat, ..RenderOptions::default() };
    let mut gpu = GpuRenderer::new(ctx);
    let plan = FramePlan::new(&s, &cam, &lights, &features, Some(&gpu.state));
    gpu.render(&s, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    let plan = FramePlan::new(&s, &cam, &lights, &features, Some(&gpu.state));
    gpu.render(&s, &cam, &lights, &plan, &splat).unwrap();
    let plan = FramePlan::new(&s, &cam, &lights, &features, Some(&gpu.state));
    let g = gpu.render(&s, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    assert_eq!(g.reused, 0, "the traced frame reused splatted records");
    let fresh = FramePlan::new(&s, &cam, &lights, &features, None);
    let c = render(&s, &cam, &lights, &fresh, &RenderOptions::default(), None, &|_, _| {}).unwrap();
    assert_close(&c, &g, "traced after splatted");
}

/// At a level of detail, shadow rays stop at that level on both renderers (the GPU's always
/// did; the CPU's traced them to the voxels, so about one pixel in 550 of a shadowed car at
/// level 5 came out lit on one and shadowed on the other). No pixel may differ by a lost
/// shadow.
#[test]
fn shadows_at_a_level_of_detail_match_the_cpu() {
    let Some(ctx) = context() else { return };
    let (mut scene, cars) = scene(1);
    pose(&mut scene, &cars[0], 0.4).unwrap();
    scene.update().unwrap();
    let lights = Lights::default();
    let features = Features { beams: false, hit_buffer: false, ..Features::default() };
    let mut gpu = GpuRenderer::new(ctx);
    let cam = street_camera(320, 200);
    for level in [3, 4, 5] {
        let opts = RenderOptions { max_level: level, ..RenderOptions::default() };
        let plan = FramePlan::new(&scene, &cam, &lights, &features, None);
        let c = render(&scene, &cam, &lights, &plan, &opts, None, &|_, _| {}).unwrap();
        let g = gpu.render(&scene, &cam, &lights, &plan, &opts).unwrap();
        assert_close(&c, &g, &format!("level {level}"));
        let far: Vec<usize> =
            (0..c.radiance.len()).filter(|&k| (c.radiance[k] - g.radiance[k]).abs().max_element() > 0.05).collect();
        assert!(
            far.len() <= 2,
            "level {level}: {} pixels differ by more than 0.05: {:?}",
            far.len(),
            &far[..far.len().min(8)]
        );
    }
}

/// Pixels of two GPU frames of the same crowd, one posed on the host and one on the GPU:
/// the same instance nearly everywhere, the same distance and colour where it is.
fn assert_same_crowd(host: &Frame, posed: &Frame, what: &str) {
    let n = host.t.len();
    // (The ground is the last instance.)
    let ground = host.instance.iter().copied().max().unwrap_or(0);
    let cars: Vec<usize> = (0..n).filter(|&k| (0..ground).contains(&host.instance[k])).collect();
    assert!(cars.len() > n / 40, "{what}: the cars cover {} of {n} pixels", cars.len());
    let same = host.instance.iter().zip(&posed.instance).filter(|(a, b)| a == b).count();
    assert!(same as f64 >= 0.999 * n as f64, "{what}: instance ids agree on {same} of {n} pixels");
    let same_cars = cars.iter().filter(|&&k| posed.instance[k] == host.instance[k]).count();
    assert!(
        same_cars as f64 >= 0.995 * cars.len() as f64,
        "{what}: the same car instance on {same_cars} of the {} car pixels",
        cars.len()
    );
    for k in 0..n {
        assert!(!posed.t[k].is_nan() && posed.radiance[k].is_finite(), "{what}: NaN at pixel {k}");
        if host.instance[k] >= 0 && host.instance[k] == posed.instance[k] {
            let rel = ((host.t[k] - posed.t[k]) / host.t[k]).abs();
            assert!(rel <= 1e-4, "{what}: pixel {k}: t {} vs {} (rel {rel:e})", host.t[k], posed.t[k]);
        }
    }
    let far = host.radiance.iter().zip(&posed.radiance).filter(|(a, b)| (**a - **b).abs().max_element() > 0.05).count();
    assert!(far as f64 <= 0.002 * n as f64, "{what}: {far} of {n} pixels differ by more than 0.05");
}

/// A crowd posed on the GPU (`GpuRenderer::set_crowd`) renders as the same crowd posed on
/// the host, though its scene is never posed after staging: early and late in the clip
/// (10⁶ s), with shadows, with the ground prepared on the host, at full detail and at a
/// level of detail, far from the origin.
#[test]
fn a_crowd_posed_on_the_gpu_renders_as_one_posed_on_the_host() {
    use voxray::gpu::crowd::GpuCrowd;
    use voxray::scene::car::pose_all;
    let Some(ctx) = context() else { return };
    let parts = car_parts();
    // Everything a long way from the origin, so that boxes left in world space (not
    // refitted about the eye) would miss.
    let away = DVec3::new(1000.5, 0.0, -700.25);
    let staged = || {
        let mut st = voxray::scene::stage_cars(&parts, 40, true, true).unwrap();
        for car in &mut st.cars {
            car.origin += away;
        }
        let ground = st.scene.instances().len() - 1;
        st.scene.set_local(ground, voxray::scene::Transform::from_translation(away)).unwrap();
        st.scene.update().unwrap();
        st
    };
    let mut host_st = staged();
    let still = staged();
    let lights = Lights::default();
    let features = Features { beams: false, hit_buffer: false, ..Features::default() };
    // Low over the first rows of cars, looking across the crowd.
    let cam = Camera {
        eye: away + DVec3::new(-7.0, 2.5, -5.0),
        target: away + DVec3::new(20.0, 0.0, 14.0),
        up: DVec3::Y,
        vfov_deg: 40.0,
        width: 200,
        height: 120,
    };
    let mut host = GpuRenderer::new(ctx.clone());
    let mut posed = GpuRenderer::new(ctx.clone());
    for level in [u32::MAX, 5] {
        let opts = RenderOptions { max_level: level, ..RenderOptions::default() };
        posed.set_crowd(Some(GpuCrowd::new(ctx.clone(), &still.scene, &still.cars, level).unwrap()));
        for t in [0.0, 2.5, 1e6 + 0.7] {
            pose_all(&mut host_st.scene, &host_st.cars, t).unwrap();
            host_st.scene.update().unwrap();
            let plan = FramePlan::new(&host_st.scene, &cam, &lights, &features, None);
            assert!(plan.bvh && plan.shadows, "{plan:?}");
            let h = host.render(&host_st.scene, &cam, &lights, &plan, &opts).unwrap();
            posed.set_crowd_time(t);
            let plan = FramePlan::new(&still.scene, &cam, &lights, &features, None);
            let p = posed.render(&still.scene, &cam, &lights, &plan, &opts).unwrap();
            assert_same_crowd(&h, &p, &format!("level {level}, t = {t}"));
        }
    }
}

/// What a crowd posed on the GPU cannot do is refused with a clear error, and the renderer
/// renders the scene's own transforms again once the crowd is gone.
#[test]
fn a_crowd_posed_on_the_gpu_refuses_what_it_cannot_do() {
    use voxray::gpu::crowd::GpuCrowd;
    let Some(ctx) = context() else { return };
    let parts = car_parts();
    let mut st = voxray::scene::stage_cars(&parts, 4, true, false).unwrap();
    let lights = Lights::default();
    let features = Features { beams: false, hit_buffer: false, ..Features::default() };
    let cam = Camera::framing(st.bounds.0.as_vec3(), st.bounds.1.as_vec3(), 64, 40);
    let mut gpu = GpuRenderer::new(ctx.clone());
    let plan = FramePlan::new(&st.scene, &cam, &lights, &features, None);
    let alone = gpu.render(&st.scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    gpu.set_crowd(Some(GpuCrowd::new(ctx.clone(), &st.scene, &st.cars, 6).unwrap()));
    let err = |r: Result<Frame, GpuError>| match r {
        Err(GpuError::Crowd(m)) => m,
        other => panic!("expected a crowd error, got {other:?}"),
    };
    // Another level of detail than the crowd's spheres hold.
    let m = err(gpu.render(&st.scene, &cam, &lights, &plan, &RenderOptions::default()));
    assert!(m.contains("level of detail 6"), "{m}");
    // Another scene, or this one with an instance more.
    let opts = RenderOptions { max_level: 6, ..RenderOptions::default() };
    let other = voxray::scene::stage_cars(&parts, 4, true, false).unwrap();
    assert!(err(gpu.render(&other.scene, &cam, &lights, &plan, &opts)).contains("scene changed"));
    // GI reads the host's transforms.
    gpu.set_gi(Some(voxray::gi::GiSettings::default())).unwrap();
    assert!(err(gpu.render(&st.scene, &cam, &lights, &plan, &opts)).contains("GI"));
    gpu.set_gi(None).unwrap();
    // Cars not placed as add_car places them.
    st.scene.add(voxray::scene::Instance { part: 0, parent: Some(0), local: Default::default() }).unwrap();
    let mut bad = st.cars.clone();
    bad[1].doors[0] = st.scene.instances().len() - 1;
    assert!(matches!(GpuCrowd::new(ctx.clone(), &st.scene, &bad, 6), Err(GpuError::Crowd(_))));
    bad[1].doors[0] = 10_000;
    assert!(matches!(GpuCrowd::new(ctx.clone(), &st.scene, &bad, 6), Err(GpuError::Crowd(_))));
    // Two cars that are one (their rows would race).
    let twice = [st.cars[2], st.cars[2]];
    let m = match GpuCrowd::new(ctx.clone(), &st.scene, &twice, 6) {
        Err(GpuError::Crowd(m)) => m,
        other => panic!("expected a crowd error, got {:?}", other.err()),
    };
    assert!(m.contains("another car"), "{m}");
    // Without the crowd, the scene's own transforms again.
    gpu.set_crowd(None);
    let mut st2 = voxray::scene::stage_cars(&parts, 4, true, false).unwrap();
    st2.scene.update().unwrap();
    let again = gpu.render(&st2.scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    assert_eq!(again.instance, alone.instance);
}
