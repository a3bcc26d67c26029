//! Nearest hits of the primary rays of the default car, merged into one SVO, on the peers'
//! default view and close-up, through `render::primary` (8×8 tiles), with and without beams.
//! Prints the best of a few frames. A quick probe for traversal work; `voxray bench
//! --scenarios peers` is the full comparison.
//!
//! `cargo run --release --example primary_rays [-- DEPTH [WIDTH HEIGHT]]` (default 9, 1280×768);
//! `RAYON_NUM_THREADS=1` for one thread, `REPS=n` frames per measurement, `BEAMS=on` or `off`
//! for one of the two, `VIEW=default` or `close-up` for one view, `WHOLE=on` to also time whole
//! frames (traced and shaded), `TURN=on` to turn the car a little (its instance then maps rays
//! and normals with a full matrix, as an animated scene's do), `SHADOWS=on` for whole frames
//! with the sun's shadow rays (as `voxray render` draws them; off, as the peers' row).

use std::sync::Arc;
use std::time::Instant;
use voxray::backend::Backend;
use voxray::pipeline::{build_part, shared_resolution};
use voxray::render::instances::prepare;
use voxray::render::primary::{trace_tiles, Primary, Todo};
use voxray::render::visibility::{FrameInstances, Search};
use voxray::render::{Features, RenderOptions};
use voxray::scene::{Camera, Instance, Scene, Transform};
use voxray::session::Session;
use voxray::voxelize::{Resolution, VoxelizeOptions};

fn main() -> Result<(), voxray::Error> {
    let arg = |k: usize, default: u32| std::env::args().nth(k).and_then(|s| s.parse().ok()).unwrap_or(default);
    let (depth, width, height) = (arg(1, 9), arg(2, 1280).clamp(8, 8192), arg(3, 768).clamp(8, 8192));
    let reps: usize = std::env::var("REPS").ok().and_then(|s| s.parse().ok()).unwrap_or(7).max(1);
    let mut mesh = voxray::model::embedded::load_default_car()?;
    let all: Vec<_> = mesh.parts.iter().flat_map(|p| p.triangles.iter().copied()).collect();
    mesh.parts.truncate(1);
    mesh.parts[0].triangles = all;
    let opts = VoxelizeOptions { resolution: shared_resolution(&mesh, Resolution::Depth(depth))?, solid: false };
    let svo = Arc::new(build_part(&mesh, 0, &opts, None, &|_, _| {})?.svo);
    let st = svo.stats();
    println!(
        "{} voxels at depth {depth}: geometry {:.3} B/voxel, attributes {:.2} B/voxel",
        st.voxels,
        st.geometry_bytes_per_voxel(),
        st.attribute_bytes_per_voxel()
    );
    let mut scene = Scene::new(vec![svo]);
    // `TURN=on`: the car turned a little about the vertical, so that its instance maps rays
    // with a full matrix (as an animated scene's instances do).
    let local = match std::env::var("TURN").is_ok_and(|t| t == "on") {
        true => Transform { rotation: glam::DQuat::from_rotation_y(0.2), ..Transform::IDENTITY },
        false => Transform::IDENTITY,
    };
    scene.add(Instance { part: 0, parent: None, local })?;
    scene.update()?;
    let (lo, hi) = scene.bounds();
    let default = Camera::framing(lo.as_vec3(), hi.as_vec3(), width, height);
    let close = Camera { eye: default.target + (default.eye - default.target) * 0.4, ..default };
    for (name, camera) in [("default", default), ("close-up", close)] {
        if std::env::var("VIEW").is_ok_and(|v| v != name) {
            continue;
        }
        if std::env::var("WHOLE").is_ok_and(|w| w == "on") {
            // The same rays traced and shaded into a frame (sky and sun, no hit buffer; no
            // shadows unless asked), as the peers' whole-frame row renders them.
            let lights = voxray::scene::Lights::default();
            let shadows = std::env::var("SHADOWS").is_ok_and(|s| s == "on");
            let features = Features { hit_buffer: false, shadows, ..Features::default() };
            // Through a session, as the harness renders it: each frame refills the last one.
            let mut session = Session::new(Backend::Cpu(Box::default()), "CPU".into());
            let mut best = f64::INFINITY;
            for _ in 0..reps {
                let start = Instant::now();
                session.frame(&scene, &camera, &lights, &features, &RenderOptions::default(), &|_, _| {})?;
                best = best.min(start.elapsed().as_secs_f64());
                std::hint::black_box(session.last_frame());
            }
            let n = (camera.width * camera.height) as f64;
            println!("{name:9} whole frame: {:7.1} ms, {:6.2} Mrays/s", best * 1e3, n / best / 1e6);
        }
        let prepared = prepare(&scene, camera.eye, false);
        let instances = FrameInstances { parts: &scene.parts, prepared: &prepared, bvh: None, starts: None };
        for beams in [true, false] {
            if std::env::var("BEAMS").is_ok_and(|b| (b == "on") != beams) {
                continue;
            }
            let primary = Primary {
                instances,
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
            let mut t_hit = vec![f32::INFINITY; (camera.width * camera.height) as usize];
            let mut best = f64::INFINITY;
            for _ in 0..reps {
                let start = Instant::now();
                let store = |t: &mut f32, h: Option<(&voxray::render::visibility::InstanceHit, glam::DVec3)>| {
                    *t = h.map_or(f32::INFINITY, |h| h.0.hit.t)
                };
                trace_tiles(&primary, &mut t_hit, |_| Some(()), |_, _, _, _| Todo::All, store, |_| {});
                best = best.min(start.elapsed().as_secs_f64());
            }
            let n = (camera.width * camera.height) as f64;
            let hits = t_hit.iter().filter(|t| t.is_finite()).count() as f64;
            println!(
                "{name:9} beams {:3}: {:7.1} ms, {:6.2} Mrays/s on {} threads, hits {:.1}%",
                if beams { "on" } else { "off" },
                best * 1e3,
                n / best / 1e6,
                rayon::current_num_threads(),
                100.0 * hits / n
            );
        }
    }
    Ok(())
}
