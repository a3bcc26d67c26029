//! Primary rays on the default car at 1280×768 (depth-9 voxel size), every part tested by
//! every ray, one thread and all threads, reported by criterion as rays per second
//! (elements/s).
//!
//! `cargo bench --bench traverse`

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::sync::Arc;
use voxray::pipeline::{build_part, shared_resolution};
use voxray::render::{render, Features, FramePlan, RenderOptions};
use voxray::scene::{lights::Ambient, Camera, Instance, Lights, Scene, Transform};
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
    let lights = Lights { sun: None, ambient: Some(Ambient { radiance: glam::Vec3::ONE }), use_mtl_emitters: false };
    // Every part tested by every ray (no culling), as the SVO-core measurement was made;
    // `voxray bench` measures the optimized paths.
    let plan = FramePlan::new(&scene, &camera, &lights, &Features { shadows: false, ..Features::NONE }, None);

    let mut g = c.benchmark_group("car_1280x768_primary");
    g.throughput(Throughput::Elements(1280 * 768));
    g.sample_size(10);
    let all = rayon::current_num_threads();
    for threads in [1, all] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
        g.bench_function(format!("{threads}_threads"), |b| {
            b.iter(|| {
                pool.install(|| render(&scene, &camera, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}))
            })
        });
    }
    g.finish();
}

criterion_group!(benches, car_primary_rays);
criterion_main!(benches);
