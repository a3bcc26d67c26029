//! The sparse world volume against the dense one, its oracle: the same moved voxels give the
//! same cells, the same level chain and the same GI image, bit for bit; 1024³ coverage fits
//! in a small fraction of the dense volume's memory; bad resolutions give clear errors.

use glam::{DAffine3, DQuat, DVec3, Vec3};
use voxray::bench::gi::{gi_frame, room_scene};
use voxray::gi::shade::VolumeChoice;
use voxray::gi::{
    inject, levels, Chain, Filter, GiError, GiSettings, Layout, SparseLevels, SparseVolume, Volume, VolumeSpec,
    VoxelCache,
};
use voxray::mesh::{Material, Part, Triangle};
use voxray::render::{render, Features, FramePlan, RenderOptions};
use voxray::rng::Rng;
use voxray::scene::Scene;
use voxray::svo::Cube;
use voxray::voxelize::voxelize_in;

/// A tilted plate and a box corner: surfaces crossing brick boundaries at odd angles.
fn cache() -> VoxelCache {
    let v = Vec3::new;
    let quad = |a: Vec3, b: Vec3, c: Vec3, d: Vec3| [[a, b, c], [a, c, d]];
    let mut triangles = Vec::new();
    for q in [
        quad(v(1.0, 1.0, 1.0), v(14.0, 2.0, 1.5), v(14.5, 3.0, 13.0), v(1.5, 2.0, 12.0)),
        quad(v(2.0, 1.0, 2.0), v(2.0, 12.0, 2.0), v(2.0, 12.0, 9.0), v(2.0, 1.0, 9.0)),
        quad(v(2.0, 1.0, 2.0), v(11.0, 1.0, 2.0), v(11.0, 9.0, 2.0), v(2.0, 9.0, 2.0)),
    ] {
        for positions in q {
            triangles.push(Triangle { positions, uvs: None, material: 0 });
        }
    }
    let part = Part { name: "plate".into(), triangles };
    let mats = vec![Material::new("grey", Vec3::new(0.6, 0.5, 0.4))];
    let grid = voxelize_in(&part, &mats, Cube { min: Vec3::ZERO, size: 16.0 }, 5, false, &|_, _| {}).unwrap();
    VoxelCache::from_grid(&grid).unwrap()
}

fn poses(n: usize) -> Vec<DAffine3> {
    let mut rng = Rng::new(11);
    (0..n)
        .map(|_| {
            let axis = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5).normalize();
            let scale = DVec3::new(0.6 + rng.f64(), 0.6 + rng.f64(), 0.6 + rng.f64());
            // Some poses reach past the volume, so outside weight is compared too.
            let t = DVec3::new(rng.f64() * 30.0 - 15.0, rng.f64() * 30.0 - 15.0, rng.f64() * 30.0 - 15.0);
            DAffine3::from_scale_rotation_translation(scale, DQuat::from_axis_angle(axis, rng.f64() * 6.3), t)
        })
        .collect()
}

#[test]
fn sparse_cells_and_chain_equal_the_dense_ones() {
    let cache = cache();
    let worlds = poses(6);
    for filter in [Filter::Split, Filter::Nearest] {
        let spec = VolumeSpec::new(48, DVec3::splat(-20.0), 0.9).unwrap();
        let mut dense = Volume::new(spec);
        let mut outside = 0.0;
        for w in &worlds {
            outside += dense.splat(&cache, w, filter).unwrap().outside;
        }
        let moves: Vec<(&VoxelCache, DAffine3)> = worlds.iter().map(|w| (&cache, *w)).collect();
        let (sparse, stats) = SparseVolume::build(spec, &moves, filter).unwrap();
        assert!(outside > 0.0, "some weight falls outside, so that is compared too");
        // Summed per pose on one side and across poses on the other: equal up to rounding.
        assert!(
            (stats.outside - outside).abs() <= 1e-9 * outside,
            "{filter:?}: outside {} vs {outside}",
            stats.outside
        );
        assert_eq!(stats.voxels, (cache.voxels.len() * worlds.len()) as u64);
        // Every cell: the same sums, bit for bit; no brick where the dense cell is empty.
        let mut stored = 0;
        for z in 0..48 {
            for y in 0..48 {
                for x in 0..48 {
                    let d = dense.index([x, y, z]);
                    match sparse.index([x, y, z]) {
                        Some(i) => {
                            stored += 1;
                            assert_eq!(sparse.occupancy[i], dense.occupancy[d]);
                            assert_eq!(sparse.albedo[i], dense.albedo[d]);
                            assert_eq!(sparse.normal[i], dense.normal[d]);
                            assert_eq!(sparse.emission[i], dense.emission[d]);
                        }
                        None => assert_eq!(dense.occupancy[d], 0.0, "{filter:?}: cell {x},{y},{z} has no brick"),
                    }
                }
            }
        }
        assert_eq!(stored, sparse.occupancy.len(), "every stored cell was visited once");
        assert!(sparse.bricks() < (48usize / 8).pow(3), "the volume is sparse: {} bricks", sparse.bricks());
        // The chains: lit by an emitter-free sun through an empty scene, then averaged.
        let lights = voxray::scene::Lights {
            sun: Some(voxray::scene::Sun {
                to_sun: Vec3::new(0.3, 0.9, 0.2).normalize(),
                irradiance: Vec3::splat(3.0),
            }),
            ambient: None,
            use_mtl_emitters: false,
            ..voxray::scene::Lights::default()
        };
        let empty = Scene::new(vec![]);
        let dense_chain = levels::build(&inject(&dense, &empty, &lights, 4));
        let (rgba, _) = voxray::gi::inject::inject_cells(&sparse, &empty, &lights, 4);
        let sparse_chain = SparseLevels::build(&sparse, rgba);
        assert_eq!(sparse_chain.count(), dense_chain.count());
        for l in 0..dense_chain.count() {
            assert_eq!(sparse_chain.res(l), dense_chain.res(l));
            assert_eq!(sparse_chain.cell(l), dense_chain.cell(l));
            let r = dense_chain.res(l);
            for z in 0..r {
                for y in 0..r {
                    for x in 0..r {
                        assert_eq!(sparse_chain.value(l, [x, y, z]), dense_chain.value(l, [x, y, z]), "level {l}");
                    }
                }
            }
        }
        assert!(dense_chain.levels[0].rgba.iter().any(|v| v.x > 0.0), "the sun lit something");
    }
}

/// The whole GI pass on the box: the sparse volume's image is the dense volume's, with one
/// bounce and with three, while it stores a fraction of the cells.
#[test]
fn sparse_gi_renders_the_dense_image() {
    let scene = room_scene(6).unwrap();
    let camera = voxray::model::room::camera(48, 36);
    let lights = voxray::model::room::lights();
    let plan = FramePlan::new(&scene, &camera, &lights, &Features::default(), None);
    let base = render(&scene, &camera, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap();
    for bounces in [1, 3] {
        let s = |volume| GiSettings { res: 64, bounces, volume, ..GiSettings::default() };
        let (_, dense) = gi_frame(&scene, &camera, &lights, &plan, &s(VolumeChoice::Dense), 1).unwrap();
        let (_, sparse) = gi_frame(&scene, &camera, &lights, &plan, &s(VolumeChoice::Sparse), 1).unwrap();
        assert!(dense.radiance != base.radiance, "GI changed the image");
        assert_eq!(dense.radiance, sparse.radiance, "{bounces} bounces");
    }
    let mut caches = voxray::gi::GiCaches::new();
    let (_, stats) = voxray::gi::render_with_gi(
        &scene,
        &camera,
        &lights,
        &plan,
        &RenderOptions::default(),
        None,
        &GiSettings { res: 64, volume: VolumeChoice::Sparse, ..GiSettings::default() },
        &mut caches,
        &|_, _| {},
    )
    .unwrap();
    assert_eq!(stats.layout, Some(Layout::Sparse));
    // A closed room touches most bricks along its walls; still fewer cells than dense.
    assert!(stats.volume_bytes < stats.dense_bytes, "{} of {} bytes", stats.volume_bytes, stats.dense_bytes);
}

#[test]
fn a_1024_volume_fits_sparse_and_bad_resolutions_are_refused() {
    let cache = cache();
    let spec = VolumeSpec::with_layout(1024, DVec3::splat(-20.0), 40.0 / 1024.0, Layout::Sparse).unwrap();
    let worlds = poses(3);
    let moves: Vec<(&VoxelCache, DAffine3)> = worlds.iter().map(|w| (&cache, *w)).collect();
    let (sparse, _) = SparseVolume::build(spec, &moves, Filter::Split).unwrap();
    let total: f64 = sparse.occupancy.iter().map(|&o| o as f64).sum();
    assert!(total > 0.0 && total.is_finite());
    assert!(sparse.bytes() * 50 < SparseVolume::dense_bytes(1024), "{} bytes", sparse.bytes());
    // Dense stops at 512³ and points at the sparse volume; sparse needs multiples of 8.
    let e = VolumeSpec::with_layout(1024, DVec3::ZERO, 1.0, Layout::Dense).unwrap_err();
    assert!(matches!(e, GiError::Resolution(1024)) && e.to_string().contains("sparse"), "{e}");
    for bad in [0, 100, 2048] {
        let e = VolumeSpec::with_layout(bad, DVec3::ZERO, 1.0, Layout::Sparse).unwrap_err().to_string();
        assert!(e.contains("multiple of 8"), "{bad}: {e}");
        let s = GiSettings { res: bad, volume: VolumeChoice::Sparse, ..GiSettings::default() };
        assert!(s.validated().is_err());
    }
    assert!("tree".parse::<VolumeChoice>().unwrap_err().contains("dense, sparse or auto"));
    // Auto: dense up to 128³, sparse above where the bricks divide the volume.
    assert_eq!(VolumeChoice::Auto.pick(128), Layout::Dense);
    assert_eq!(VolumeChoice::Auto.pick(256), Layout::Sparse);
    assert_eq!(VolumeChoice::Auto.pick(300), Layout::Dense);
    // On the GPU the same, but a dense volume must fit one binding, and anisotropic levels
    // keep it dense wherever it does.
    let (big, small) = (4u64 << 30, 32u64 << 20);
    assert_eq!(VolumeChoice::Auto.pick_on_gpu(128, big, false), Layout::Dense);
    assert_eq!(VolumeChoice::Auto.pick_on_gpu(256, big, false), Layout::Sparse);
    assert_eq!(VolumeChoice::Auto.pick_on_gpu(300, big, false), Layout::Dense);
    assert_eq!(VolumeChoice::Auto.pick_on_gpu(128, small, false), Layout::Sparse);
    assert_eq!(VolumeChoice::Auto.pick_on_gpu(256, big, true), Layout::Dense);
    assert_eq!(VolumeChoice::Auto.pick_on_gpu(256, small, true), Layout::Sparse);
    assert_eq!(VolumeChoice::Dense.pick_on_gpu(256, small, false), Layout::Dense);
    assert!(GiSettings { res: 1024, ..GiSettings::default() }.validated().is_ok());
    assert!(GiSettings { res: 1000, ..GiSettings::default() }.validated().is_ok());
    let e = GiSettings { res: 1001, ..GiSettings::default() }.validated().unwrap_err().to_string();
    assert!(e.contains("sparse"), "{e}");
}
