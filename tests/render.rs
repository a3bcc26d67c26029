//! The CPU renderer against unoptimized references and analytic expectations, and under
//! extreme cameras.

use glam::{DVec3, Vec3};
use std::sync::Arc;
use voxray::mesh::{Material, Mesh, Part, Triangle};
use voxray::ray::UnitRay;
use voxray::render::{render, Features, Frame, FramePlan, RenderOptions};
use voxray::scene::lights::{Ambient, Sun};
use voxray::scene::{Camera, Instance, Lights, Scene, Transform};
use voxray::svo::{self, Svo};
use voxray::traverse::{trace_unit, TraceOptions};
use voxray::voxelize::{voxelize, Resolution, VoxelizeOptions};

fn quad(name: &str, y: f32, half: f32) -> Part {
    let p = |x: f32, z: f32| Vec3::new(x, y, z);
    let (a, b, c, d) = (p(-half, -half), p(half, -half), p(half, half), p(-half, half));
    Part {
        name: name.into(),
        triangles: vec![
            Triangle { positions: [a, b, c], uvs: None, material: 0 },
            Triangle { positions: [a, c, d], uvs: None, material: 0 },
        ],
    }
}

fn build(parts: Vec<Part>, voxel: f32) -> Vec<Svo> {
    let mesh = Mesh { parts, materials: vec![Material::new("grey", Vec3::splat(0.5))], ..Default::default() };
    let opts = VoxelizeOptions { resolution: Resolution::VoxelSize(voxel), solid: false };
    mesh.parts.iter().map(|p| svo::build(&voxelize(p, &mesh.materials, &opts, &|_, _| {}).unwrap()).unwrap()).collect()
}

/// The parts at the identity, one instance each.
fn scene(parts: &[Svo]) -> Scene {
    let mut s = Scene::new(parts.iter().cloned().map(Arc::new).collect());
    for part in 0..parts.len() {
        s.add(Instance { part, parent: None, local: Transform::IDENTITY }).unwrap();
    }
    s.update().unwrap();
    s
}

/// One frame with the given features and no hit buffer.
fn frame(parts: &[Svo], cam: &Camera, lights: &Lights, features: Features) -> Frame {
    let s = scene(parts);
    let plan = FramePlan::new(&s, cam, lights, &features, None);
    render(&s, cam, lights, &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap()
}

fn top_down(width: u32) -> Camera {
    Camera {
        eye: DVec3::new(0.0, 5.0, 0.0),
        target: DVec3::ZERO,
        up: DVec3::new(0.0, 0.0, -1.0),
        vfov_deg: 60.0,
        width,
        height: width,
    }
}

#[test]
fn nearest_part_matches_brute_force_over_all_parts() {
    // Overlapping parts at different heights and positions, traced from an oblique camera.
    let parts = build(vec![quad("ground", 0.0, 1.0), quad("mid", 0.4, 0.4), quad("top", 0.8, 0.2)], 1.0 / 64.0);
    let cam = Camera {
        eye: DVec3::new(1.0, 1.6, 1.3),
        target: DVec3::ZERO,
        up: DVec3::Y,
        vfov_deg: 60.0,
        width: 64,
        height: 48,
    };
    let f = frame(&parts, &cam, &Lights::default(), Features::default());
    let b = cam.basis();
    let sc = scene(&parts);
    let prepared = voxray::render::instances::prepare(&sc, cam.eye, false);
    let mut hits = 0;
    for py in 0..cam.height {
        for px in 0..cam.width {
            let dir = cam.ray_dir(&b, px, py);
            // Unoptimized: every part, full interval, keep the smallest t.
            let mut best: Option<(f32, i32)> = None;
            for (i, s) in parts.iter().enumerate() {
                let p = &prepared[i];
                let Some(u) = UnitRay::from_unit(p.to_unit.point(DVec3::ZERO), p.to_unit.vector(dir)) else { continue };
                if let Some(h) = trace_unit(s, &u, &TraceOptions::default()).hit {
                    if best.is_none_or(|(t, _)| h.t < t) {
                        best = Some((h.t, i as i32));
                    }
                }
            }
            let k = (py * cam.width + px) as usize;
            match best {
                Some((t, i)) => {
                    hits += 1;
                    assert_eq!((f.t[k], f.instance[k]), (t, i), "pixel {px},{py}");
                }
                None => assert_eq!((f.t[k], f.instance[k]), (f32::INFINITY, -1)),
            }
        }
    }
    assert!(hits > 1000, "{hits} hits");
    for i in 0..3 {
        assert!(f.instance.contains(&i), "part {i} never visible: the test would not test overlap");
    }
}

#[test]
fn shadows_fall_where_the_occluder_blocks_the_sun() {
    // Sun at 45° towards +x: the occluder (|x|,|z| ≤ 0.25 at y = 0.5) shadows x ∈ [−0.75, −0.25].
    let parts = build(vec![quad("ground", 0.0, 1.0), quad("occluder", 0.5, 0.25)], 1.0 / 128.0);
    let irr = std::f32::consts::PI * std::f32::consts::SQRT_2; // so ρ·E·cos45°/π = ρ
    let lights = Lights {
        sun: Some(Sun { to_sun: Vec3::new(1.0, 1.0, 0.0).normalize(), irradiance: Vec3::splat(irr) }),
        ambient: Some(Ambient { radiance: Vec3::splat(0.1) }),
        use_mtl_emitters: false,
        ..Lights::default()
    };
    let cam = top_down(64);
    let f = frame(&parts, &cam, &lights, Features::default());
    let at = |px: u32| f.radiance[(32 * 64 + px) as usize].x;
    // Pixel 26 sees x ≈ −0.50 (in the shadow), pixel 38 sees x ≈ +0.59 (lit).
    let albedo = voxray::svo::format::srgb8_to_linear(voxray::svo::format::linear_to_srgb8(0.5));
    assert!((at(26) - 0.1 * albedo).abs() < 1e-3, "shadowed: {}", at(26));
    assert!((at(38) - 1.1 * albedo).abs() < 1e-2, "lit: {}", at(38));
    assert!(f.shadow_rays > 0);
    // Without shadow rays the same pixel is lit.
    let f2 = frame(&parts, &cam, &lights, Features { shadows: false, ..Features::default() });
    assert!(f2.radiance[(32 * 64 + 26) as usize].x > 1.0 * albedo);
    assert_eq!(f2.shadow_rays, 0);
}

#[test]
fn extreme_cameras_give_no_nan() {
    let parts = build(vec![quad("ground", 0.0, 1.0)], 1.0 / 32.0);
    let sky = Lights::default().sky();
    let cams = [
        // So far away that the part is far below a pixel: all sky.
        Camera { eye: DVec3::new(1e15, 1e15, 0.0), ..top_down(16) },
        // A sliver of a field of view.
        Camera { vfov_deg: 1e-6, ..top_down(16) },
        // Almost a hemisphere.
        Camera { vfov_deg: 179.9, ..top_down(16) },
        // Inside the part's cube, looking along the surface.
        Camera {
            eye: DVec3::new(0.0, 0.0, 0.5),
            target: DVec3::new(0.0, 0.0, -1.0),
            up: DVec3::Y,
            vfov_deg: 90.0,
            width: 16,
            height: 16,
        },
    ];
    for c in cams {
        c.validate().unwrap();
        let f = frame(&parts, &c, &Lights::default(), Features::default());
        assert!(f.radiance.iter().all(|r| r.is_finite()), "{c:?}");
        assert!(f.t.iter().all(|t| !t.is_nan()) && f.normal.iter().all(|n| n.is_finite()), "{c:?}");
        if c.eye.x > 1e14 {
            assert!(f.instance.iter().all(|&i| i == -1) && f.radiance.iter().all(|&r| r == sky));
        }
    }
}

#[test]
fn far_from_the_origin_renders_like_at_the_origin() {
    // The same quad and camera, translated by 10⁶: camera-relative f64 keeps the image.
    let off = 1.0e6f32;
    let near = build(vec![quad("q", 0.0, 1.0)], 1.0 / 64.0);
    let mut far_part = quad("q", 0.0, 1.0);
    for t in &mut far_part.triangles {
        for p in &mut t.positions {
            p.x += off;
        }
    }
    let far = build(vec![far_part], 1.0 / 64.0);
    let cam = Camera {
        eye: DVec3::new(0.7, 3.0, 1.9),
        target: DVec3::ZERO,
        up: DVec3::Y,
        vfov_deg: 50.0,
        width: 48,
        height: 48,
    };
    let cam_far = Camera { eye: cam.eye + DVec3::X * off as f64, target: DVec3::X * off as f64, ..cam };
    let a = frame(&near, &cam, &Lights::default(), Features::default());
    let b = frame(&far, &cam_far, &Lights::default(), Features::default());
    let same = a.instance.iter().zip(&b.instance).filter(|(x, y)| x == y).count();
    // f32 bounds at 10⁶ move the voxel grid by up to 1/16 unit; allow edge pixels to differ.
    assert!(same as f64 >= 0.97 * a.instance.len() as f64, "{same} of {} pixels agree", a.instance.len());
}

/// A tetrahedron of 10⁻⁸, 1, 10¹⁹ and 10³⁸ units, each framed by the default camera, gives
/// the same picture: the framing and the voxels' normals do not depend on the model's scale
/// (in object units² the normals' weights underflowed at 10⁻⁸ and overflowed at 10³⁸, and
/// the framing gave up below a micrometre and above 10³⁸/√3).
#[test]
fn tiny_and_huge_models_render_like_unit_ones() {
    let image = |s: f32| {
        let v = [Vec3::ZERO, Vec3::X * s, Vec3::Y * s, Vec3::Z * s];
        let tri = |a: usize, b: usize, c: usize| Triangle { positions: [v[a], v[b], v[c]], uvs: None, material: 0 };
        let part = Part { name: "t".into(), triangles: vec![tri(0, 1, 2), tri(0, 1, 3), tri(0, 2, 3), tri(1, 2, 3)] };
        let mats = [Material::new("grey", Vec3::splat(0.5))];
        let opts = VoxelizeOptions { resolution: Resolution::Depth(6), solid: false };
        let svo = svo::build(&voxelize(&part, &mats, &opts, &|_, _| {}).unwrap()).unwrap();
        let s = scene(&[svo]);
        let (lo, hi) = s.bounds();
        let cam = Camera::framing(lo.as_vec3(), hi.as_vec3(), 64, 48);
        let plan = FramePlan::new(&s, &cam, &Lights::default(), &Features::default(), None);
        render(&s, &cam, &Lights::default(), &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap()
    };
    let unit = image(1.0);
    let covered = unit.instance.iter().filter(|&&i| i >= 0).count();
    assert!(covered > 64 * 48 / 10, "the model covers {covered} pixels");
    for s in [1e-8, 1e19, 1e38] {
        let f = image(s);
        let same =
            unit.radiance.iter().zip(&f.radiance).filter(|(a, b)| (**a - **b).abs().max_element() < 1e-3).count();
        assert!(
            same as f64 >= 0.9 * unit.radiance.len() as f64,
            "scale {s}: {same} of {} pixels agree",
            f.radiance.len()
        );
    }
}

#[test]
fn absurd_resolutions_are_refused_before_allocating() {
    let mesh =
        Mesh { parts: vec![quad("q", 0.0, 1.0)], materials: vec![Material::new("m", Vec3::ONE)], ..Default::default() };
    let e = voxelize(
        &mesh.parts[0],
        &mesh.materials,
        &VoxelizeOptions { resolution: Resolution::Depth(20), solid: false },
        &|_, _| {},
    );
    let msg = e.unwrap_err().to_string();
    // The library says what to change in its own terms; the CLI adds its flags.
    assert!(msg.contains("million voxels") && msg.contains("smaller depth") && !msg.contains("--"), "{msg}");
}

/// The library's render refuses a camera that cannot make an image (zero or absurd sizes,
/// NaN, a zero field of view) with the camera's typed error, before allocating anything:
/// a width of 0 used to panic in the pixel loop.
#[test]
fn render_refuses_bad_cameras() {
    let parts = build(vec![quad("q", 0.0, 1.0)], 1.0 / 16.0);
    let s = scene(&parts);
    let good = top_down(16);
    let lights = Lights::default();
    let plan = FramePlan::new(&s, &good, &lights, &Features::default(), None);
    assert!(render(&s, &good, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}).is_ok());
    let bad = [
        Camera { width: 0, ..good },
        Camera { height: 0, ..good },
        Camera { width: 1 << 20, height: 1 << 20, ..good },
        Camera { eye: DVec3::NAN, ..good },
        Camera { vfov_deg: 0.0, ..good },
        Camera { target: good.eye, ..good },
    ];
    for cam in bad {
        match render(&s, &cam, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}) {
            Err(e) => assert_eq!(Some(e), cam.validate().err()),
            Ok(_) => panic!("rendered with {cam:?}"),
        }
    }
}

/// An eye inside a voxel gives a flat image (every ray hits at t = 0); the frame says so, so
/// the CLI and the demo can warn. Outside, no pixel hits at t = 0.
#[test]
fn an_eye_inside_a_voxel_is_reported() {
    let parts = build(vec![quad("floor", 0.0, 2.0)], 0.25);
    let lights = Lights::default();
    let outside = frame(&parts, &top_down(16), &lights, Features::default());
    assert_eq!(outside.eye_inside_fraction(), 0.0);
    let mut cam = top_down(16);
    cam.eye = DVec3::new(0.3, 0.01, 0.2); // inside the floor's voxel layer
    cam.target = DVec3::new(1.0, 0.01, 0.2);
    cam.up = DVec3::Y;
    let inside = frame(&parts, &cam, &lights, Features::default());
    assert!(inside.eye_inside_fraction() > 0.9, "{}", inside.eye_inside_fraction());
}

#[test]
fn a_recycled_frame_renders_like_a_fresh_one() {
    // The first frame sees the quad from above (hits nearly everywhere); its buffers are then
    // reused for a view that mostly misses: every pixel must be overwritten, misses included.
    let parts = build(vec![quad("a", 0.0, 1.0)], 0.05);
    let s = scene(&parts);
    let lights = Lights::default();
    let near = Camera { eye: DVec3::new(0.0, 1.2, 0.0), ..top_down(48) };
    let far = Camera { eye: DVec3::new(0.0, 30.0, 0.0), ..top_down(48) };
    // With the hit buffer on, the records are kept for reuse; with it off, only their memory
    // is kept for the next frame to overwrite.
    for features in [Features::default(), Features { hit_buffer: false, ..Features::default() }] {
        let mut hits = voxray::render::HitBuffer::new();
        let render_with = |cam: &Camera, hits: &mut voxray::render::HitBuffer| {
            let plan = FramePlan::new(&s, cam, &lights, &features, Some(&*hits));
            render(&s, cam, &lights, &plan, &RenderOptions::default(), Some(hits), &|_, _| {}).unwrap()
        };
        let first = render_with(&near, &mut hits);
        assert!(first.instance.iter().filter(|&&i| i >= 0).count() > first.instance.len() / 2);
        hits.recycle(first);
        let reused = render_with(&far, &mut hits);
        let fresh = frame(&parts, &far, &lights, features);
        assert!(fresh.instance.iter().filter(|&&i| i < 0).count() > fresh.instance.len() / 2);
        assert_eq!(reused, fresh);
    }
}

/// `Svo::contains` and `instances::eye_inside` against the voxel set they were built from:
/// the centre of every cell of a random depth-4 grid, carried into the world by a rotated,
/// anisotropically scaled instance (the forward map, while `eye_inside` inverts it), is
/// inside exactly when its cell is set.
#[test]
fn eye_inside_matches_the_voxel_set() {
    use std::collections::HashSet;
    use voxray::render::instances::{eye_inside, eye_inside_listed, prepare};
    use voxray::svo::Cube;
    use voxray::voxelize::VoxelGrid;
    let mut rng = voxray::rng::Rng::new(11);
    let cells = 16u32;
    let set: HashSet<[u32; 3]> =
        (0..900).map(|_| [0, 1, 2].map(|_| ((rng.f32() * cells as f32) as u32).min(cells - 1))).collect();
    let cube = Cube { min: Vec3::new(-1.0, -0.5, -2.0), size: 2.0 };
    let grid = VoxelGrid::from_coords(4, cube, set.iter().copied(), Vec3::splat(0.5));
    let svo = svo::build(&grid).unwrap();
    let mut scene = Scene::new(vec![Arc::new(svo.clone())]);
    let t = Transform {
        translation: DVec3::new(3.0, -2.0, 7.5),
        rotation: glam::DQuat::from_euler(glam::EulerRot::YXZ, 0.7, -0.4, 1.1),
        scale: DVec3::new(1.5, 0.6, -2.0),
    };
    scene.add(Instance { part: 0, parent: None, local: t }).unwrap();
    scene.update().unwrap();
    let w = scene.world(0);
    let size = cube.size as f64 / cells as f64;
    let mut inside = 0;
    for x in 0..cells {
        for y in 0..cells {
            for z in 0..cells {
                let c = [x, y, z];
                let unit = (DVec3::new(x as f64, y as f64, z as f64) + 0.5) / cells as f64;
                assert_eq!(svo.contains(unit), set.contains(&c), "{c:?}");
                let obj = cube.min.as_dvec3() + DVec3::new(x as f64, y as f64, z as f64) * size + size * 0.5;
                let world = w.transform_point3(obj);
                let prepared = prepare(&scene, world, true);
                let found = eye_inside(&scene.parts, &prepared);
                assert_eq!(found, set.contains(&c), "{c:?} at {world}");
                let spheres: Vec<_> = prepared.iter().map(|p| (p.centre, p.radius)).collect();
                assert_eq!(eye_inside_listed(&scene.parts, &prepared, &spheres), found, "{c:?}, listed");
                inside += set.contains(&c) as u32;
            }
        }
    }
    assert!(inside > 100 && inside < cells * cells * cells - 100, "{inside} cells set");
    // Outside the cube: nothing.
    assert!(!svo.contains(DVec3::new(1.0, 0.5, 0.5)) && !svo.contains(DVec3::splat(-1e-9)));
    assert!(!eye_inside(&scene.parts, &prepare(&scene, w.transform_point3(DVec3::new(50.0, 0.0, 0.0)), true)));
}
