//! Primary rays on the default car at 1280×768 (depth-9 voxel size), one thread and all
//! threads, reported by criterion as rays per second (elements/s):
//!
//! - `car_1280x768_primary`: whole frames with every part tested by every ray (no culling,
//!   no beams), as the SVO-core measurement was made; `voxray bench` measures the optimized
//!   paths;
//! - `car_1280x768_trace_only`: the car merged into one SVO, nearest hits only through
//!   `render::primary` (8×8 tiles), with beams (each tile then goes through the octree as one
//!   packet, `traverse::packet`) and without (one ray at a time, from the eye).
//! - `car_single_rays`: the same camera's rays through the merged car one at a time on one
//!   thread, every fourth pixel per axis: `traverse::trace_unit` (Revelles' loop) against
//!   `traverse::packet::trace_single` (the packet-of-one walk that shadow rays and the per-ray
//!   search take; the same answers).
//! - `car_scene_caster`: a library caller's rays through `cast::SceneCaster` (the car's 8
//!   parts as instances, one ray at a time): the camera's rays at every second pixel per axis,
//!   and one ambient-occlusion ray from each of their hits (short, incoherent rays).
//!
//! `cargo bench --bench traverse`

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::sync::Arc;
use voxray::cast::{CastRay, SceneCaster};
use voxray::pipeline::{build_part, shared_resolution};
use voxray::ray::{Ray, UnitRay};
use voxray::render::instances::prepare;
use voxray::render::primary::{trace_tiles, Primary, Todo};
use voxray::render::visibility::{FrameInstances, Search};
use voxray::render::{render, Features, FramePlan, RenderOptions};
use voxray::scene::{lights::Ambient, Camera, Instance, Lights, Scene, Transform};
use voxray::traverse::packet::trace_single;
use voxray::traverse::{trace_unit, TraceOptions};
use voxray::voxelize::{Resolution, VoxelizeOptions};

fn car_primary_rays(c: &mut Criterion) {
    let mesh = voxray::model::embedded::load_default_car().expect("embedded car");
    let resolution = shared_resolution(&mesh, Resolution::Depth(9)).expect("resolution");
    let opts = VoxelizeOptions { resolution, solid: false };
    let parts: Vec<_> = (0..mesh.parts.len())
        .map(|i| Arc::new(build_part(&mesh, i, &opts, None, &|_, _| {}).expect("build").svo))
        .collect();
    let mut scene = Scene::new(parts);
    for part in 0..scene.parts.len() {
        scene.add(Instance { part, parent: None, local: Transform::IDENTITY }).expect("instance");
    }
    scene.update().expect("update");
    let (mut lo, mut hi) = (glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY);
    for t in mesh.parts.iter().flat_map(|p| &p.triangles) {
        for v in t.positions {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    let camera = Camera::framing(lo, hi, 1280, 768);
    // Primary rays only: no sun (so no shadow rays), ambient shading.
    let lights = Lights {
        sun: None,
        ambient: Some(Ambient { radiance: glam::Vec3::ONE }),
        use_mtl_emitters: false,
        ..Lights::default()
    };
    let plan = FramePlan::new(&scene, &camera, &lights, &Features { shadows: false, ..Features::NONE }, None);

    // The car merged into one part, as the peers scenario traces it.
    let mut merged_mesh = mesh.clone();
    let all: Vec<_> = mesh.parts.iter().flat_map(|p| p.triangles.iter().copied()).collect();
    merged_mesh.parts.truncate(1);
    merged_mesh.parts[0].triangles = all;
    let merged_opts = VoxelizeOptions {
        resolution: shared_resolution(&merged_mesh, Resolution::Depth(9)).expect("res"),
        solid: false,
    };
    let merged = Arc::new(build_part(&merged_mesh, 0, &merged_opts, None, &|_, _| {}).expect("build").svo);
    let mut single = Scene::new(vec![merged]);
    single.add(Instance { part: 0, parent: None, local: Transform::IDENTITY }).expect("instance");
    single.update().expect("update");
    let prepared = prepare(&single, camera.eye, false);

    let all_threads = rayon::current_num_threads();
    let mut g = c.benchmark_group("car_1280x768_primary");
    g.throughput(Throughput::Elements(1280 * 768));
    g.sample_size(10);
    for threads in [1, all_threads] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
        g.bench_function(format!("{threads}_threads"), |b| {
            b.iter(|| {
                pool.install(|| {
                    render(&scene, &camera, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap()
                })
            })
        });
    }
    g.finish();

    let mut g = c.benchmark_group("car_1280x768_trace_only");
    g.throughput(Throughput::Elements(1280 * 768));
    g.sample_size(10);
    let mut t_hit = vec![f32::INFINITY; 1280 * 768];
    for beams in [true, false] {
        for threads in [1, all_threads] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
            let fi = FrameInstances { parts: &single.parts, prepared: &prepared, bvh: None, starts: None };
            let primary = Primary {
                instances: fi,
                camera: &camera,
                search: Search::Plain,
                opts: Default::default(),
                beams,
                bvh_beams: false,
                lists: None,
                moved: &[],
                moved_flags: &[],
                missed_before: &[],
            };
            let name = format!("{}_{threads}_threads", if beams { "beams_packets" } else { "no_beams_one_by_one" });
            g.bench_function(name, |b| {
                b.iter(|| {
                    pool.install(|| {
                        trace_tiles(
                            &primary,
                            &mut t_hit,
                            |_| Some(()),
                            |_, _, _, _| Todo::All,
                            |t, h| *t = h.map_or(f32::INFINITY, |h| h.0.hit.t),
                            |_| {},
                        )
                    })
                })
            });
        }
    }
    g.finish();

    // One ray at a time: every fourth pixel per axis, in object space (the car's own frame).
    let svo = &single.parts[0];
    let basis = camera.basis();
    let rays: Vec<UnitRay> = (0..768 / 4)
        .flat_map(|y| (0..1280 / 4).map(move |x| (4 * x, 4 * y)))
        .filter_map(|(x, y)| {
            let ray = Ray::new(camera.eye.as_vec3(), camera.ray_dir(&basis, x, y).as_vec3());
            UnitRay::from_object(&svo.bounds, &ray)
        })
        .collect();
    let opts = TraceOptions::default();
    let mut g = c.benchmark_group("car_single_rays");
    g.throughput(Throughput::Elements(rays.len() as u64));
    g.sample_size(10);
    g.bench_function("trace_unit", |b| {
        b.iter(|| rays.iter().filter(|r| trace_unit(svo, r, &opts).hit.is_some()).count())
    });
    g.bench_function("trace_single", |b| {
        b.iter(|| rays.iter().filter(|r| trace_single(svo, r, &opts).is_some()).count())
    });
    g.finish();

    // A library caller's own rays through `cast::SceneCaster` (the car's 8 parts as
    // instances): the camera's rays at every second pixel per axis, then from each of their
    // hits one ray into the hemisphere around its normal (ambient-occlusion rays: short,
    // incoherent, starting on the surface).
    let caster = SceneCaster::new(&scene).expect("caster");
    let camera_rays: Vec<CastRay> = (0..768 / 2)
        .flat_map(|y| (0..1280 / 2).map(move |x| (2 * x, 2 * y)))
        .map(|(x, y)| CastRay::new(camera.eye, camera.ray_dir(&basis, x, y)))
        .collect();
    let ao_rays = voxray::bench::matrix::ambient_occlusion_rays(&caster, &camera_rays);
    let mut g = c.benchmark_group("car_scene_caster");
    g.sample_size(10);
    for (name, rays) in [("camera", &camera_rays), ("ambient_occlusion", &ao_rays)] {
        g.throughput(Throughput::Elements(rays.len() as u64));
        for threads in [1, all_threads] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
            g.bench_function(format!("{name}_{threads}_threads"), |b| {
                b.iter(|| pool.install(|| caster.nearest_all(rays).iter().filter(|h| h.is_some()).count()))
            });
            // Into one buffer kept between the calls, as a caller casting batch after batch.
            let mut hits = Vec::new();
            g.bench_function(format!("{name}_into_{threads}_threads"), |b| {
                b.iter(|| {
                    pool.install(|| caster.nearest_into(rays, &mut hits));
                    hits.iter().filter(|h| h.is_some()).count()
                })
            });
        }
    }
    g.finish();
}

criterion_group!(benches, car_primary_rays);
criterion_main!(benches);
