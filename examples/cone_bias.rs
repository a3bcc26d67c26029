//! Where the box's GI error comes from: the indirect light that the default gather (six 60°
//! cones) adds, against the one-bounce path-traced reference's, and against many narrow cones
//! traced through the same level chain (cosine-distributed directions, one aperture at a
//! time). Narrow cones read the finest level, so they measure the voxel volume itself
//! (voxelization, transformation, injection); wider ones read coarser levels.
//!
//! `cargo run --release --example cone_bias [SPP] [anisotropic]` (default 256 samples per
//! pixel, isotropic levels; about ten seconds on two cores) prints the sums over every fourth
//! pixel in each direction; the sky is off so that only the sun's bounced light is compared.
//! Figures in docs/accuracy.md ("Why the box errs").

use glam::Vec3;
use voxray::gi::{prepare_light, render_with_gi, GiCaches, GiSettings, PathTracer, ReferenceSettings};
use voxray::render::{brdf, Features, FramePlan, RenderOptions};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let spp = std::env::args().nth(1).map(|s| s.parse()).transpose()?.unwrap_or(256);
    let scene = voxray::bench::gi::room_scene(8)?;
    let (w, h) = (160u32, 120u32);
    let camera = voxray::model::room::camera(w, h);
    let lights = voxray::scene::Lights { ambient: None, ..voxray::model::room::lights() };
    let plan = FramePlan::new(&scene, &camera, &lights, &Features::default(), None);
    let opts = RenderOptions::default();
    let mut pt = PathTracer::new(&scene, &camera, &lights, ReferenceSettings { spp, bounces: Some(1), seed: 1 })?;
    pt.run(&mut |_, _| {});
    let reference = pt.frame();
    // Without GI and without a sky the frame is the direct light alone.
    let direct = voxray::render::render(&scene, &camera, &lights, &plan, &opts, None, &|_, _| {})?;
    let anisotropic = std::env::args().nth(2).is_some_and(|a| a == "anisotropic");
    let s = GiSettings { anisotropic, ..GiSettings::default() };
    let mut caches = GiCaches::new();
    let (gi, _) = render_with_gi(&scene, &camera, &lights, &plan, &opts, None, &s, &mut caches, &|_, _| {})?;
    prepare_light(&scene, &camera, &lights, &s, &mut caches)?;
    let (_, _, cone, _) = caches.ambient(&lights).ok_or("no GI light")?;
    let basis = camera.basis();
    let pixels: Vec<usize> = (0..h)
        .step_by(4)
        .flat_map(|y| (0..w).step_by(4).map(move |x| (y * w + x) as usize))
        .filter(|&k| gi.instance[k] >= 0)
        .collect();
    let indirect = |f: &voxray::render::Frame| -> f32 {
        pixels.iter().map(|&k| (f.radiance[k] - direct.radiance[k]).element_sum()).sum()
    };
    let want = indirect(&reference);
    let levels = if anisotropic { "anisotropic" } else { "isotropic" };
    println!("indirect light summed over {} pixels (RGB summed), sky off, {levels} levels:", pixels.len());
    println!("  path-traced reference ({spp} spp, one bounce): {want:.1}");
    let got = indirect(&gi);
    println!("  default gather (6 cones of 60°): {got:.1} ({:.2}× the reference)", got / want);
    const DIRECTIONS: usize = 128;
    for aperture_deg in [1.0f64, 5.0, 10.0, 20.0, 60.0] {
        let mut rng = voxray::rng::Rng::new(5);
        let mut sum = 0.0;
        for &k in &pixels {
            let (x, y) = ((k as u32) % w, (k as u32) / w);
            let p = camera.eye + camera.ray_dir(&basis, x, y) * gi.t[k] as f64;
            let n = gi.normal[k].as_dvec3();
            let mut light = Vec3::ZERO;
            for _ in 0..DIRECTIONS {
                let d = brdf::cosine_sample(n, &mut rng);
                light += cone(p, n, d, aperture_deg.to_radians()).truncate();
            }
            sum += (gi.albedo[k] * light / DIRECTIONS as f32).element_sum();
        }
        println!("  {DIRECTIONS} cosine-distributed cones of {aperture_deg}°: {sum:.1} ({:.2}×)", sum / want);
    }
    Ok(())
}
