//! The instance BVH's per-frame work at crowd scale, reported by criterion as spheres per
//! second (elements/s):
//!
//! - `build`: a tree over 158 000 spheres, the size of the moved-sphere tree the hit buffer
//!   builds every frame when 10 000 cars drive (old and new place of 79 000 instances);
//! - `build_sorted`: the same by Morton order ([`Bvh::build_sorted`], the moved-sphere tree's
//!   build since step 76);
//! - `refit_whole`: every box of an 80 000-instance tree recomputed;
//! - `refit_changed`: only the boxes above an eighth of its instances (what a crowd whose
//!   seen cars are posed changes a frame), as the GPU renderer refits its tree.
//!
//! `cargo bench --bench bvh`

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use glam::DVec3;
use voxray::render::bvh::Bvh;
use voxray::rng::Rng;

/// `n` spheres scattered like a crowd's parts: clusters of eight along a wide plane.
fn crowd(n: usize, rng: &mut Rng) -> Vec<(DVec3, f64)> {
    (0..n)
        .map(|i| {
            let car = (i / 8) as f64;
            let at = DVec3::new((car * 7.3) % 900.0, 0.0, (car * 3.1).floor() % 900.0);
            (at + DVec3::new(rng.f64() * 4.0, rng.f64(), rng.f64() * 2.0), 0.3 + rng.f64() * 2.0)
        })
        .collect()
}

fn instance_bvh(c: &mut Criterion) {
    let mut rng = Rng::new(3);
    let moved = crowd(158_000, &mut rng);
    let spheres = crowd(80_000, &mut rng);
    let mut g = c.benchmark_group("instance_bvh");
    g.sample_size(20);
    g.throughput(Throughput::Elements(moved.len() as u64));
    g.bench_function("build", |b| b.iter(|| Bvh::build_with(&moved, false).nodes.len()));
    g.bench_function("build_sorted", |b| b.iter(|| Bvh::build_sorted(&moved, false).nodes.len()));
    g.throughput(Throughput::Elements(spheres.len() as u64));
    let mut tree = Bvh::build_with(&spheres, false);
    g.bench_function("refit_whole", |b| b.iter(|| tree.refit(&spheres)));
    let changed: Vec<u32> = (0..spheres.len() as u32).step_by(8).collect();
    let mut dirty = Vec::new();
    g.bench_function("refit_changed", |b| b.iter(|| tree.refit_changed(&spheres, &changed, &mut dirty)));
    g.finish();
}

criterion_group!(benches, instance_bvh);
criterion_main!(benches);
