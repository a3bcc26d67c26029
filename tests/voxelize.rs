//! The voxelizer against independent oracles: SAT overlap against polygon clipping, the
//! hierarchical descent against a dense brute-force test, area conservation, solid fill.

use glam::{DVec3, Vec3};
use voxray::mesh::{Material, Part, Triangle};
use voxray::rng::Rng;
use voxray::svo::format::morton_decode;
use voxray::voxelize::{
    bounding_cube, clip_area, tri_box_overlap, voxelize, Resolution, VoxelizeError, VoxelizeOptions,
};

fn rand_tri(rng: &mut Rng, lo: f32, hi: f32) -> [Vec3; 3] {
    [0; 3].map(|_: i32| Vec3::new(rng.range(lo, hi), rng.range(lo, hi), rng.range(lo, hi)))
}

#[test]
fn sat_agrees_with_clipping_on_random_triangles() {
    let mut rng = Rng::new(11);
    let (mut overlaps, mut n) = (0, 0);
    for _ in 0..200_000 {
        let t = rand_tri(&mut rng, -1.5, 1.5).map(|p| p.as_dvec3());
        let (area, _) = clip_area(&t, DVec3::ZERO, DVec3::ONE);
        let sat = tri_box_overlap(DVec3::splat(0.5), DVec3::splat(0.5), &t);
        // Generic positions: overlap means a clipped polygon of positive area.
        assert_eq!(sat, area > 0.0, "triangle {t:?}: SAT {sat}, clipped area {area}");
        overlaps += sat as u32;
        n += 1;
    }
    assert!(overlaps > n / 10 && overlaps < n * 9 / 10, "{overlaps} of {n}: not a discriminating test");
}

fn part(tris: Vec<[Vec3; 3]>) -> Part {
    Part {
        name: "p".into(),
        triangles: tris.into_iter().map(|positions| Triangle { positions, uvs: None, material: 0 }).collect(),
    }
}

#[test]
fn sparse_descent_finds_exactly_the_dense_overlap_set() {
    let mut rng = Rng::new(12);
    let mats = [Material::new("m", Vec3::splat(0.5))];
    for _ in 0..20 {
        let tris: Vec<[Vec3; 3]> = (0..3).map(|_| rand_tri(&mut rng, -1.0, 1.0)).collect();
        let p = part(tris.clone());
        let opts = VoxelizeOptions { resolution: Resolution::Depth(5), solid: false };
        let g = voxelize(&p, &mats, &opts, &|_, _| {}).unwrap();
        let (cube, depth) = bounding_cube(&p, opts.resolution).unwrap();
        let n = 1u32 << depth;
        let vs = cube.size as f64 / n as f64;
        let mut dense = Vec::new();
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    let c = cube.min.as_dvec3() + (DVec3::new(x as f64, y as f64, z as f64) + 0.5) * vs;
                    // In voxel units, as the voxelizer tests them.
                    let hit = tris.iter().any(|t| {
                        let tv = t.map(|q| (q.as_dvec3() - cube.min.as_dvec3()) / vs);
                        tri_box_overlap((c - cube.min.as_dvec3()) / vs, DVec3::splat(0.5), &tv)
                    });
                    if hit {
                        dense.push([x, y, z]);
                    }
                }
            }
        }
        let mut got: Vec<[u32; 3]> = g.voxels.iter().map(|v| morton_decode(v.code)).collect();
        got.sort();
        dense.sort();
        assert_eq!(got, dense);
    }
}

#[test]
fn voxel_weights_add_up_to_the_triangle_area() {
    let mut rng = Rng::new(13);
    let mats = [Material::new("m", Vec3::splat(0.5))];
    for _ in 0..20 {
        let t = rand_tri(&mut rng, -1.0, 1.0);
        let area = ((t[1] - t[0]).cross(t[2] - t[0]).length() * 0.5) as f64;
        let g = voxelize(
            &part(vec![t]),
            &mats,
            &VoxelizeOptions { resolution: Resolution::Depth(6), solid: false },
            &|_, _| {},
        )
        .unwrap();
        // Weights are in voxel faces.
        let face = (g.bounds.size as f64 / 64.0).powi(2);
        let sum: f64 = g.voxels.iter().map(|v| v.weight as f64 * face).sum();
        assert!((sum - area).abs() <= 1e-4 * area, "sum {sum} area {area}");
    }
}

fn cube_mesh() -> Part {
    let v = |x: f32, y: f32, z: f32| Vec3::new(x, y, z) - 0.5;
    let c = [
        v(0., 0., 0.),
        v(1., 0., 0.),
        v(1., 1., 0.),
        v(0., 1., 0.),
        v(0., 0., 1.),
        v(1., 0., 1.),
        v(1., 1., 1.),
        v(0., 1., 1.),
    ];
    let faces = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [2, 3, 7, 6], [1, 2, 6, 5], [0, 4, 7, 3]];
    let mut tris = Vec::new();
    for f in faces {
        tris.push([c[f[0]], c[f[1]], c[f[2]]]);
        tris.push([c[f[0]], c[f[2]], c[f[3]]]);
    }
    part(tris)
}

#[test]
fn solid_fill_fills_a_closed_cube() {
    let mats = [Material::new("m", Vec3::new(0.2, 0.4, 0.6))];
    let p = cube_mesh();
    // Voxel size 1/8: the cube spans 8 voxels plus the touching boundary layers.
    let surface =
        voxelize(&p, &mats, &VoxelizeOptions { resolution: Resolution::VoxelSize(0.125), solid: false }, &|_, _| {})
            .unwrap();
    let solid =
        voxelize(&p, &mats, &VoxelizeOptions { resolution: Resolution::VoxelSize(0.125), solid: true }, &|_, _| {})
            .unwrap();
    let (lo, hi) = surface.coords().fold(([u32::MAX; 3], [0; 3]), |(lo, hi), c| {
        ([lo[0].min(c[0]), lo[1].min(c[1]), lo[2].min(c[2])], [hi[0].max(c[0]), hi[1].max(c[1]), hi[2].max(c[2])])
    });
    let box_count: usize = (0..3).map(|i| (hi[i] - lo[i] + 1) as usize).product();
    assert_eq!(solid.voxels.len(), box_count, "solid fill should fill the whole box");
    assert!(surface.voxels.len() < box_count);
    assert!(solid.voxels.iter().all(|v| (v.albedo - Vec3::new(0.2, 0.4, 0.6)).length() < 1e-5));
    // Too deep for the dense flood fill: a clear error.
    let e = voxelize(&p, &mats, &VoxelizeOptions { resolution: Resolution::Depth(10), solid: true }, &|_, _| {});
    assert_eq!(e.unwrap_err(), VoxelizeError::SolidTooDeep(10));
}

#[test]
fn bad_resolutions_and_geometry_are_refused() {
    let mats = [Material::new("m", Vec3::ONE)];
    let p = cube_mesh();
    for r in [
        Resolution::Depth(0),
        Resolution::Depth(21),
        Resolution::VoxelSize(0.0),
        Resolution::VoxelSize(f32::NAN),
        Resolution::VoxelSize(1e-9),
    ] {
        let e = voxelize(&p, &mats, &VoxelizeOptions { resolution: r, solid: false }, &|_, _| {});
        assert!(matches!(e, Err(VoxelizeError::Resolution(_))), "{r:?}");
    }
    let mut nan = cube_mesh();
    nan.triangles[3].positions[1].y = f32::NAN;
    assert!(matches!(bounding_cube(&nan, Resolution::Depth(4)), Err(VoxelizeError::NonFinite(_))));
    assert!(matches!(bounding_cube(&part(vec![]), Resolution::Depth(4)), Err(VoxelizeError::EmptyPart(_))));
}
