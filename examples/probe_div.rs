// Throwaway probe (not kept).
use voxray::gi::{render_with_gi, GiCaches, GiSettings, PathTracer, ReferenceSettings};
use voxray::render::{Features, FramePlan, RenderOptions};
fn main() {
    let (w, h) = (160, 120);
    let scene = voxray::bench::gi::panel_room_scene(8).unwrap();
    let camera = voxray::model::panel_room::camera(w, h);
    let lights = voxray::model::panel_room::lights();
    let mut pt =
        PathTracer::new(&scene, &camera, &lights, ReferenceSettings { spp: 256, bounces: Some(1), seed: 1 }).unwrap();
    pt.run(&mut |_, _| {});
    let reference = pt.frame();
    let plan = FramePlan::new(&scene, &camera, &lights, &Features::default(), None);
    let s = GiSettings::default();
    let mut c = GiCaches::new();
    let mut times = vec![];
    let mut last = None;
    for _ in 0..4 {
        c.forget_last_frame();
        let t0 = std::time::Instant::now();
        let (f, st) =
            render_with_gi(&scene, &camera, &lights, &plan, &RenderOptions::default(), None, &s, &mut c, &|_, _| {})
                .unwrap();
        times.push((t0.elapsed().as_secs_f64() * 1e3, st.inject_ms));
        last = Some(f);
    }
    let e = voxray::bench::metrics::compare(&last.unwrap(), &reference).unwrap();
    println!("FLIP {:.4} frames/inject ms {:?}", e.flip.unwrap(), times);
}
