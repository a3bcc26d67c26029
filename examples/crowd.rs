//! Where a crowd's frame goes: N driving cars (8 instances each) at 320×192, primary rays
//! only, as the harness's instance sweep renders them, with the frame split into posing, the
//! transform update and the render (which prepares the instances, lists or refits their
//! bounds, traces and shades; through a CPU session, as the harness renders, so each frame
//! refills the last one's memory). Prints the median of each over the timed frames. `voxray bench --scenarios
//! instances` is the full comparison.
//!
//! The frame's stages run inside [`voxray::pool::run_awake`], as the harness runs them (a GPU
//! frame lets the pool's threads rest once it is submitted).
//!
//! Only the cars some pixel ray can reach are posed ([`voxray::scene::car::SeenCars::pose`]), as the
//! harness does, and also printed are the cars tested against the frame's rays (a car found
//! clear of them is let go untested while its motion cannot bring it near one); a further
//! argument `all` poses every car, and `gpu` renders on the GPU backend (read back only its
//! statistics, as the harness does; its pass times are printed too, and the render's host
//! time up to its submit, `GpuRenderer::submit_host_ms`); `posed` with `gpu` poses the cars
//! and refits their tree on the GPU ([`voxray::gpu::crowd`], as the harness's instance sweep
//! does on the GPU): the host then only sets each frame's time.
//!
//! `cargo run --release --example crowd [-- CARS [FRAMES [all] [gpu [posed]]]]` (default
//! 10 000 cars, 20 frames).

use std::sync::Arc;
use std::time::Instant;
use voxray::pipeline::{build_part, shared_resolution};
use voxray::render::{Features, RenderOptions};
use voxray::scene::{Camera, Lights};
use voxray::session::Session;
use voxray::voxelize::{Resolution, VoxelizeOptions};

fn main() -> Result<(), voxray::Error> {
    let arg = |k: usize, default: usize| std::env::args().nth(k).and_then(|s| s.parse().ok()).unwrap_or(default);
    let (cars, frames) = (arg(1, 10_000).clamp(1, 100_000), arg(2, 20).clamp(1, 1000));
    let mesh = voxray::model::embedded::load_default_car()?;
    let opts = VoxelizeOptions { resolution: shared_resolution(&mesh, Resolution::Depth(9))?, solid: false };
    let parts = (0..mesh.parts.len())
        .map(|i| build_part(&mesh, i, &opts, None, &|_, _| {}).map(|b| Arc::new(b.svo)))
        .collect::<Result<Vec<_>, _>>()?;
    let mut st = voxray::scene::stage_cars(&parts, cars, true, false)?;
    let camera = Camera::framing(st.bounds.0.as_vec3(), st.bounds.1.as_vec3(), 320, 192);
    let lights = Lights::default();
    let features = Features { hit_buffer: false, shadows: false, ..Features::default() };
    // Frames go through a CPU session, as the harness renders them: each frame's memory is
    // the last one's, refilled.
    let flag = |name: &str| std::env::args().skip(3).any(|a| a == name);
    let (all, gpu) = (flag("all"), flag("gpu"));
    let on_gpu = gpu && flag("posed");
    let (backend, name) = voxray::backend::Backend::open(if gpu {
        voxray::backend::BackendKind::Gpu
    } else {
        voxray::backend::BackendKind::Cpu
    })?;
    let mut session = Session::new(backend, name.clone());
    #[cfg(feature = "gpu")]
    if let (true, Some(g)) = (on_gpu, session.backend_mut().gpu_mut()) {
        let crowd = voxray::gpu::crowd::GpuCrowd::new(g.ctx.clone(), &st.scene, &st.cars, u32::MAX)?;
        g.set_crowd(Some(crowd));
    }
    // The harness's GPU frames stay on the GPU: only the statistics come back.
    session.set_counting(gpu);
    session.set_read_back(!gpu);
    let rays = voxray::scene::FrameRays::of(&st.scene, &features, false, &RenderOptions::default());
    let sight = voxray::scene::Sight::new(&camera, &lights, rays, st.surfaces(u32::MAX)?).ok().filter(|_| !all);
    let (mut posed, mut tested, mut passes, mut host) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut crowd_passes = Vec::new();
    let mut per_ray = Vec::new();
    let mut times: [Vec<f64>; 4] = Default::default();
    for f in 0..frames + 2 {
        let t = f as f64 / 30.0;
        let t0 = Instant::now();
        // The frame's stages run as the harness runs them (voxray::pool::run_awake).
        let frame = || -> Result<_, voxray::Error> {
            let n = if on_gpu {
                #[cfg(feature = "gpu")]
                if let Some(g) = session.backend_mut().gpu_mut() {
                    g.set_crowd_time(t);
                }
                cars
            } else {
                st.pose_seen(t, sight.as_ref(), u32::MAX)?
            };
            let t1 = Instant::now();
            if !on_gpu {
                st.scene.update()?;
            }
            let t2 = Instant::now();
            session.frame(&st.scene, &camera, &lights, &features, &RenderOptions::default(), &|_, _| {})?;
            Ok((n, t1, t2))
        };
        let (n, t1, t2) = voxray::pool::run_awake(frame)?;
        let t3 = Instant::now();
        std::hint::black_box(session.last_frame());
        if f >= 2 {
            posed.push(n as f64);
            tested.push(if on_gpu { 0.0 } else { st.cars_tested() as f64 });
            if let Some(fr) = session.last_frame() {
                per_ray.push(fr.instances_traced as f64 / fr.primary_rays.max(1) as f64);
            }
            if let Some((trace, shade)) = session.backend().pass_times() {
                passes.push(trace + shade);
            }
            if let Some(ms) = session.backend().crowd_pass_ms() {
                crowd_passes.push(ms);
            }
            if let Some(g) = session.backend().gpu() {
                host.push(g.submit_host_ms);
            }
            for (v, d) in times.iter_mut().zip([t1 - t0, t2 - t1, t3 - t2, t3 - t0]) {
                v.push(d.as_secs_f64() * 1e3);
            }
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let [pose, update, draw, total] = &mut times;
    println!(
        "{cars} cars ({} instances), 320×192, median of {frames} frames: pose {:.2} ms, update {:.2} ms, \
         render {:.2} ms, frame {:.2} ms; cars posed {}, tested {}; octrees entered per ray {:.2}",
        st.scene.instances().len(),
        median(pose),
        median(update),
        median(draw),
        median(total),
        median(&mut posed),
        median(&mut tested),
        median(&mut per_ray)
    );
    if !passes.is_empty() {
        println!("{name}: GPU passes {:.2} ms (trace and shade, timestamps)", median(&mut passes));
    }
    if !crowd_passes.is_empty() {
        println!("the crowd's passes (posing the cars, refitting their tree) {:.2} ms", median(&mut crowd_passes));
    }
    if !host.is_empty() {
        println!("render's host time up to the submit {:.2} ms", median(&mut host));
    }
    Ok(())
}
