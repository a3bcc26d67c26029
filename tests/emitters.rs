//! Emissive surfaces as area lights: the CPU renderer against the closed-form irradiance of a
//! square emitter, shadows from an occluder, and the emitters' own glow (and the GPU's
//! against the CPU's in `tests/gpu_emitters.rs`).

use glam::{DVec3, Vec3};
use std::sync::Arc;
use voxray::mesh::{Material, Mesh, Part, Triangle};
use voxray::render::{render, Features, Frame, FramePlan, RenderOptions};
use voxray::scene::{Camera, Instance, Lights, Scene, Transform};
use voxray::svo::{self, Svo};
use voxray::voxelize::{voxelize, Resolution, VoxelizeOptions};

/// A square of half-side `half` at height `y`, its triangles wound to face `up` or down.
fn square(name: &str, y: f32, half: f32, up: bool, material: u32) -> Part {
    let p = |x: f32, z: f32| Vec3::new(x, y, z);
    let (a, b, c, d) = (p(-half, -half), p(half, -half), p(half, half), p(-half, half));
    // a → d → c faces +y (counter-clockwise seen from above).
    let tris = if up { [[a, d, c], [a, c, b]] } else { [[a, b, c], [a, c, d]] };
    Part { name: name.into(), triangles: tris.map(|positions| Triangle { positions, uvs: None, material }).to_vec() }
}

/// Emitted radiance of the panel: not a multiple of its albedo.
const KE: Vec3 = Vec3::new(17.0, 12.0, 4.0);

fn parts(with_blocker: bool) -> Vec<Svo> {
    let materials = vec![
        Material::new("floor", Vec3::splat(0.8)),
        Material { emission: KE, ..Material::new("panel", Vec3::splat(0.78)) },
    ];
    let mut parts = vec![square("floor", 0.0, 2.0, true, 0), square("panel", 1.0, 0.25, false, 1)];
    if with_blocker {
        // A small plate halfway up, over the floor's centre: it hides part of the panel.
        parts.push(square("blocker", 0.5, 0.15, true, 0));
    }
    let mesh = Mesh { parts, materials, ..Default::default() };
    let opts = VoxelizeOptions { resolution: Resolution::VoxelSize(4.0 / 256.0), solid: false };
    mesh.parts.iter().map(|p| svo::build(&voxelize(p, &mesh.materials, &opts, &|_, _| {}).unwrap()).unwrap()).collect()
}

fn scene(parts: &[Svo]) -> Scene {
    let mut s = Scene::new(parts.iter().cloned().map(Arc::new).collect());
    for part in 0..parts.len() {
        s.add(Instance { part, parent: None, local: Transform::IDENTITY }).unwrap();
    }
    s.update().unwrap();
    s
}

fn frame(s: &Scene, cam: &Camera, lights: &Lights) -> Frame {
    let plan = FramePlan::new(s, cam, lights, &Features::default(), None);
    assert!(plan.shadows || lights.emitter_sampling() == 0, "emitters need shadow rays");
    render(s, cam, lights, &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap()
}

/// Looking along `dir` from `eye` with a narrow field, so the centre pixels see one spot.
fn camera(eye: DVec3, dir: DVec3) -> Camera {
    Camera { eye, target: eye + dir, up: DVec3::Z, vfov_deg: 2.0, width: 16, height: 16 }
}

fn panel_lights(samples: u32) -> Lights {
    Lights { sun: None, ambient: None, use_mtl_emitters: true, emitter_samples: samples, ..Lights::default() }
}

fn mean(f: &Frame) -> Vec3 {
    f.radiance.iter().copied().sum::<Vec3>() / f.radiance.len() as f32
}

/// The floor right under the panel, seen from beside the panel: its radiance is albedo/π ×
/// irradiance, and the irradiance of a uniform square on the axis has a closed form.
#[test]
fn floor_under_a_panel_matches_the_closed_form() {
    let parts = parts(false);
    let s = scene(&parts);
    // From the side of the panel down at the floor's centre: the panel is out of view.
    let eye = DVec3::new(0.6, 0.9, 0.0);
    let cam = camera(eye, (DVec3::ZERO - eye).normalize());
    let f = frame(&s, &cam, &panel_lights(256));
    assert!(f.radiance.iter().all(|c| c.is_finite()));
    assert!(f.instance.iter().all(|&i| i == 0), "the centre view should see only the floor");
    // Corner-rectangle form factor, four times (parallel square of side 0.5 at height 1).
    let corner = |a: f64, b: f64, h: f64| {
        let (x, y) = (a / h, b / h);
        let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
        (x / sx * (y / sx).atan() + y / sy * (x / sy).atan()) / (2.0 * std::f64::consts::PI)
    };
    // The floor's voxels sit half a voxel around y = 0: the height is about 1.
    let form = 4.0 * corner(0.25, 0.25, 1.0) as f32;
    let want = KE * 0.8 * form;
    let got = mean(&f);
    let err = ((got - want) / want).abs().max_element();
    eprintln!("floor under the panel: {got} against the closed form {want} ({:.2} %)", err * 100.0);
    assert!(err < 0.04, "floor radiance {got}, closed form {want}");
    // The path-traced reference samples the same emitters at every vertex; the floor sees
    // only the panel (whose underside reflects nothing back), so it converges to the same.
    let settings = voxray::gi::ReferenceSettings { spp: 256, bounces: None, seed: 3 };
    let reference = voxray::gi::path_trace(&s, &cam, &panel_lights(4), settings, &mut |_, _| {}).unwrap();
    let r = mean(&reference);
    assert!(((r - got) / got).abs().max_element() < 0.03, "reference {r} against the renderer's {got}");
    // Emitters off: the floor is black (no sun, no sky).
    let off = frame(&s, &cam, &Lights { use_mtl_emitters: false, ..panel_lights(4) });
    assert_eq!(mean(&off), Vec3::ZERO);
    // Not sampled: the panel still glows but lights nothing directly.
    assert_eq!(mean(&frame(&s, &cam, &panel_lights(0))), Vec3::ZERO);
}

/// A plate between the panel and the floor shadows the floor's centre, fully where it hides
/// the whole panel and partly (a soft edge) around it.
#[test]
fn a_plate_casts_a_soft_shadow() {
    let parts = parts(true);
    let s = scene(&parts);
    let lights = panel_lights(64);
    let under = |x: f64| {
        let eye = DVec3::new(x + 0.02, 0.3, 0.0);
        let target = DVec3::new(x, 0.0, 0.0);
        let f = frame(&s, &camera(eye, (target - eye).normalize()), &lights);
        assert!(f.instance.iter().all(|&i| i == 0));
        mean(&f).x
    };
    // The plate (half-side 0.15 at 0.5) hides every point of the panel (half-side 0.25 at 1)
    // from the floor's centre; from x = 0.2 the panel's far strip (x > 0.1) shows; from x = 0.6
    // nothing of it is hidden.
    let (umbra, penumbra, open) = (under(0.0), under(0.2), under(0.6));
    eprintln!("red radiance: under the plate {umbra}, at its edge {penumbra}, beyond {open}");
    assert!(umbra == 0.0, "umbra {umbra}");
    assert!(penumbra > 0.1 * open && penumbra < 0.9 * open, "penumbra {penumbra} against {open}");
}

/// Looking up at the panel shows its own emission, in its own colour.
#[test]
fn the_panel_glows_in_its_own_colour() {
    let parts = parts(false);
    let s = scene(&parts);
    let cam = Camera { up: DVec3::X, ..camera(DVec3::new(0.0, 0.5, 0.0), DVec3::Y) };
    let f = frame(&s, &cam, &panel_lights(4));
    assert!(f.instance.iter().all(|&i| i == 1));
    let got = mean(&f);
    assert!((got - KE).abs().max_element() < 0.1, "panel radiance {got}, Ke {KE}");
}

/// A point light over the floor: radiance albedo/π · I/h² (the inverse-square law); a spot
/// aimed at the floor gives the same inside its inner cone and nothing beyond its outer one;
/// several suns add up.
#[test]
fn point_spot_and_extra_suns_follow_their_closed_forms() {
    let parts = parts(false);
    let s = scene(&parts[..1]);
    let eye = DVec3::new(0.6, 0.9, 0.0);
    let cam = camera(eye, (DVec3::ZERO - eye).normalize());
    let intensity = Vec3::new(3.0, 2.0, 1.0);
    let dark = Lights { sun: None, ambient: None, use_mtl_emitters: false, ..Lights::default() };
    let point = voxray::scene::lights::PointLight { position: DVec3::new(0.0, 1.0, 0.0), intensity };
    let lit = Lights { points: vec![point], ..dark.clone() }.validated().unwrap();
    let got = mean(&frame(&s, &cam, &lit));
    // The floor's surface lies within a voxel (1/64) of y = 0.
    let want = intensity * 0.8 / std::f32::consts::PI;
    assert!(((got - want) / want).abs().max_element() < 0.04, "point light: {got} against {want}");
    // The reference path tracer lights its primary hits the same way (nothing else to bounce
    // off here).
    let settings = voxray::gi::ReferenceSettings { spp: 4, bounces: None, seed: 5 };
    let r = mean(&voxray::gi::path_trace(&s, &cam, &lit, settings, &mut |_, _| {}).unwrap());
    assert!((r - got).abs().max_element() < 1e-4 * got.max_element(), "reference {r} against {got}");
    let spot = |inner: f32, outer: f32, direction: Vec3| voxray::scene::lights::SpotLight {
        position: DVec3::new(0.0, 1.0, 0.0),
        direction,
        intensity,
        inner_deg: inner,
        outer_deg: outer,
    };
    let on_axis = Lights { spots: vec![spot(10.0, 20.0, -Vec3::Y)], ..dark.clone() }.validated().unwrap();
    let g = mean(&frame(&s, &cam, &on_axis));
    assert!((g - got).abs().max_element() < 1e-5 * got.max_element(), "spot on axis {g} against point {got}");
    // Aimed 45° away from the floor's centre: beyond a 20° outer cone.
    let away = Lights { spots: vec![spot(10.0, 20.0, Vec3::new(1.0, -1.0, 0.0))], ..dark.clone() }.validated().unwrap();
    assert_eq!(mean(&frame(&s, &cam, &away)), Vec3::ZERO);
    // Two extra suns straight down: twice one.
    let sun = voxray::scene::Sun { to_sun: Vec3::Y, irradiance: Vec3::ONE };
    let one = mean(&frame(&s, &cam, &Lights { suns: vec![sun], ..dark.clone() }.validated().unwrap()));
    let two = mean(&frame(&s, &cam, &Lights { suns: vec![sun, sun], ..dark.clone() }.validated().unwrap()));
    // Within the 8-bit sRGB albedo's step.
    assert!((one - Vec3::splat(0.8 / std::f32::consts::PI)).abs().max_element() < 2e-3, "{one}");
    assert!((two - 2.0 * one).abs().max_element() < 1e-5, "{two} against {one}");
    // Bad lights are refused with the field named.
    let e = Lights { spots: vec![spot(30.0, 20.0, -Vec3::Y)], ..dark.clone() }.validated().unwrap_err();
    assert!(e.to_string().contains("spots[0]"), "{e}");
    let nan = voxray::scene::lights::PointLight { position: DVec3::NAN, intensity };
    let e = Lights { points: vec![nan], ..dark }.validated().unwrap_err();
    assert!(e.to_string().contains("points[0].position"), "{e}");
}
