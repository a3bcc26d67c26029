//! `voxray demo`: the interactive window.

use super::*;
use voxray::render::SplatDraw;

pub(crate) fn demo_cmd(a: DemoArgs) -> Result<(), Error> {
    use voxray::viewer::{check_display, run, CarParts, DemoOptions};
    let lights = match &a.lights_json {
        Some(p) => Lights::from_json(&read_text(p)?).map_err(|e| with_path(p, e))?,
        None => Lights::default(),
    };
    check_display()?;
    let st = stage(&a.source, a.cars, a.in_place, false, !a.no_ground)?;
    // A scene file's clip is framed over its whole loop (st.bounds), the parked cars as posed.
    let (lo, hi) =
        if st.animated.is_none() && (st.cars.is_empty() || a.in_place) { st.cars_bounds() } else { st.bounds };
    let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), a.width, a.height);
    // The default car can be re-staged with another car count from the panel.
    let car_parts =
        (!st.cars.is_empty()).then(|| CarParts { parts: st.scene.parts[..8].to_vec(), ground: !a.no_ground });
    let opts = DemoOptions {
        width: a.width,
        height: a.height,
        frames: a.frames,
        exit: a.exit,
        screenshot: a.screenshot.clone(),
        backend: a.backend,
        features: a.switches.features(),
        car_parts,
        gi: a.gi,
        gi_gather: a.gi_gather,
        gpu_read_back: a.gpu_read_back,
        gpu_stats: a.gpu_stats,
        animated: st.animated.clone(),
        splat: a.renderer == "splat",
        splat_draw: if a.splat_draw == "quads" { SplatDraw::Quads } else { SplatDraw::Compute },
    };
    let report = run(opts, st.scene, st.cars, lights, camera)?;
    eprintln!("demo: {} frames on {}, median {:.1} ms/frame", report.frames, report.backend, report.median_ms);
    if let Some(line) = report.gpu_steady_state() {
        println!("{line}");
    }
    Ok(())
}
