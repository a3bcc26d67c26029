//! GPU GI against the CPU reference passes, on whatever adapter wgpu finds (Mesa's software
//! Vulkan driver in CI; a missing adapter fails in CI and skips elsewhere): the transformed
//! volume within the fixed-point tolerance, the injected level chain, and the cone-traced image.
#![cfg(feature = "gpu")]

use glam::{DVec3, Vec3};
use std::sync::Arc;
use voxray::bench::gi::room_scene;
use voxray::gi::shade::VolumeChoice;
use voxray::gi::{inject, levels, plan_volume, Filter, GiCaches, GiReuse, GiSettings, Volume};
use voxray::gpu::gi::GiCapture;
use voxray::gpu::{GpuContext, GpuRenderer};
use voxray::pipeline::build_parts;
use voxray::render::{render, Features, Frame, FramePlan, RenderOptions};
use voxray::scene::car::{add_car, pose};
use voxray::scene::{Camera, Lights, Scene};
use voxray::voxelize::Resolution;

fn context() -> Option<Arc<GpuContext>> {
    match GpuContext::headless() {
        Ok(c) => Some(Arc::new(c)),
        Err(e) if std::env::var("CI").is_ok_and(|v| v == "true") => panic!("CI needs a GPU adapter: {e}"),
        Err(e) => {
            eprintln!("skipping GPU test: {e}");
            None
        }
    }
}

/// Three cars, two of them driving (wheels turned, doors swung), posed mid-clip.
fn cars() -> Scene {
    let parts = build_parts(&voxray::model::car::mesh(), Resolution::Depth(6)).unwrap();
    let mut scene = Scene::new(parts);
    let mut placed = vec![add_car(&mut scene, 0, DVec3::ZERO, 0.0, false).unwrap()];
    for k in 0..2 {
        placed.push(add_car(&mut scene, 0, DVec3::new(1.0, 0.0, 7.0 + 3.5 * k as f64), 0.9 + k as f64, true).unwrap());
    }
    for car in &placed {
        pose(&mut scene, car, 0.37).unwrap();
    }
    scene.update().unwrap();
    scene
}

fn car_camera() -> Camera {
    Camera {
        eye: DVec3::new(9.0, 5.0, 20.0),
        target: DVec3::new(0.0, 0.5, 5.0),
        up: DVec3::Y,
        vfov_deg: 45.0,
        width: 96,
        height: 64,
    }
}

/// Renders one GPU frame with GI and the volume read back.
fn gpu_frame(ctx: Arc<GpuContext>, scene: &Scene, cam: &Camera, lights: &Lights, s: GiSettings) -> (Frame, GiCapture) {
    let mut gpu = GpuRenderer::new(ctx);
    gpu.set_gi(Some(s)).unwrap();
    gpu.gi_capture = true;
    let plan = FramePlan::new(scene, cam, lights, &Features::default(), None);
    let frame = gpu.render(scene, cam, lights, &plan, &RenderOptions::default()).unwrap();
    let stats = gpu.gi_stats.expect("GI ran");
    assert!(stats.voxels > 0 && stats.jobs as usize <= scene.instances().len());
    (frame, gpu.gi_captured.take().expect("captured"))
}

/// The CPU volume of the same frame (same placement, caches and matrices) and its outside weight.
fn cpu_volume(scene: &Scene, cam: &Camera, s: &GiSettings) -> (Volume, f64) {
    let mut caches = GiCaches::new();
    let (spec, levels_of) = plan_volume(scene, cam, s, &mut caches).unwrap();
    let mut vol = Volume::new(spec);
    let mut outside = 0.0;
    for (i, inst) in scene.instances().iter().enumerate() {
        let cache = caches.get(&scene.parts[inst.part], levels_of[inst.part]).unwrap();
        outside += vol.splat(cache, &scene.world(i), s.filter).unwrap().outside;
    }
    (vol, outside)
}

#[test]
fn gpu_volume_equals_cpu_volume_within_fixed_point() {
    let Some(ctx) = context() else { return };
    let scene = cars();
    let cam = car_camera();
    // A volume smaller than the scene, so weight also falls outside.
    let s = GiSettings { res: 48, filter: Filter::Split, extent: Some(14.0), ..Default::default() };
    let (_, cap) = gpu_frame(ctx, &scene, &cam, &Lights::default(), s);
    let (cpu, cpu_out) = cpu_volume(&scene, &cam, &s);
    assert_eq!(cap.volume.spec, cpu.spec);
    assert!(cpu_out > 10.0, "the test volume leaves some voxels out ({cpu_out})");
    assert!((cap.outside - cpu_out).abs() <= 1e-3 * cpu_out + 1.0, "outside: GPU {} vs CPU {cpu_out}", cap.outside);
    // Each add rounds to 1/65536 and the f32 grid coordinates move split weights by ~1e-6:
    // a cell gathering up to a few hundred adds stays within 2e-3 of the CPU's f32 sums.
    let tol = |cpu: f32| 2e-3 + 1e-4 * cpu.abs();
    let mut occupied = 0;
    for i in 0..cpu.occupancy.len() {
        let (o, g) = (cpu.occupancy[i], cap.volume.occupancy[i]);
        occupied += (o > 0.0) as usize;
        assert!((o - g).abs() <= tol(o), "cell {i}: occupancy CPU {o} vs GPU {g}");
        for (what, c, gv, scale) in [
            ("albedo", cpu.albedo[i], cap.volume.albedo[i], 1.0),
            ("normal", cpu.normal[i], cap.volume.normal[i], 1.0),
            ("emission", cpu.emission[i], cap.volume.emission[i], 16.0),
        ] {
            let d = (c - gv).abs().max_element();
            assert!(d <= scale * tol(c.abs().max_element()), "cell {i}: {what} CPU {c} vs GPU {gv}");
        }
    }
    assert!(occupied > 500, "the cars fill {occupied} cells");
    let (tc, tg) = (cpu.total_occupancy(), cap.volume.total_occupancy());
    assert!((tc - tg).abs() <= 1e-4 * tc, "total occupancy CPU {tc} vs GPU {tg}");
}

#[test]
fn gpu_nearest_filtering_moves_every_voxel_to_one_cell() {
    let Some(ctx) = context() else { return };
    let scene = cars();
    let cam = car_camera();
    let s = GiSettings { res: 64, filter: Filter::Nearest, ..Default::default() };
    let (_, cap) = gpu_frame(ctx, &scene, &cam, &Lights::default(), s);
    let (cpu, _) = cpu_volume(&scene, &cam, &s);
    // Whole voxels only: every cell holds an integer count.
    for (&o, &g) in cpu.occupancy.iter().zip(&cap.volume.occupancy) {
        assert_eq!(g, g.round(), "GPU nearest occupancy {g} is not a whole count");
        assert!(o == o.round());
    }
    // A moved centre within f32 rounding of a cell face may land on the other side: allow a
    // handful of the cells to differ, never the total.
    let differ = cpu.occupancy.iter().zip(&cap.volume.occupancy).filter(|(a, b)| a != b).count();
    let occupied = cpu.occupancy.iter().filter(|&&o| o > 0.0).count();
    assert!(differ <= 2 + occupied / 500, "{differ} of {occupied} cells differ");
    assert_eq!(cpu.total_occupancy(), cap.volume.total_occupancy());
}

#[test]
fn gpu_injection_and_levels_match_cpu() {
    let Some(ctx) = context() else { return };
    let scene = cars();
    let cam = car_camera();
    let lights = Lights::default();
    let s = GiSettings { res: 32, ..Default::default() };
    let (_, cap) = gpu_frame(ctx, &scene, &cam, &lights, s);
    let (cpu, _) = cpu_volume(&scene, &cam, &s);
    let chain = levels::build(&inject(&cpu, &scene, &lights, s.cell_light_samples));
    assert_eq!(chain.levels.len(), cap.levels.levels.len());
    for (l, (c, g)) in chain.levels.iter().zip(&cap.levels.levels).enumerate() {
        assert_eq!((c.res, c.rgba.len()), (g.res, g.rgba.len()), "level {l}");
        assert!((c.cell - g.cell).abs() <= 1e-12 * c.cell);
        let peak = c.rgba.iter().map(|v| v.truncate().max_element()).fold(0.0f32, f32::max);
        assert!(peak > 0.0, "level {l} is lit");
        // Opacity depends on occupancy alone; radiance also on shadow rays traced in f32 from
        // camera-relative points, which may flip for cells right at a shadow's edge.
        let mut flipped = 0;
        for (a, b) in c.rgba.iter().zip(&g.rgba) {
            assert!((a.w - b.w).abs() <= 2e-3, "level {l}: alpha CPU {} vs GPU {}", a.w, b.w);
            assert!(b.is_finite());
            if (a.truncate() - b.truncate()).abs().max_element() > 1e-3 * peak.max(1.0) {
                flipped += 1;
            }
        }
        let lit = c.rgba.iter().filter(|v| v.w > 0.0).count();
        assert!(flipped <= 1 + lit / 50, "level {l}: {flipped} of {lit} cells differ in radiance");
    }
}

/// The plain box and the box with glossy white surfaces (the specular cone and the sun's
/// Phong highlight on the GPU against the CPU).
#[test]
fn gpu_gi_image_matches_cpu_gi_on_the_box() {
    let Some(ctx) = context() else { return };
    let s = GiSettings { res: 32, ..Default::default() };
    box_images_agree(ctx.clone(), &room_scene(6).unwrap(), s);
    let glossy = voxray::bench::gi::glossy_room_scene(6).unwrap();
    box_images_agree(ctx.clone(), &glossy, s);
    // The sparse volume on both backends (its GPU buffers a fraction of a dense 256³ one's).
    let sparse = GiSettings { res: 256, volume: voxray::gi::shade::VolumeChoice::Sparse, ..s };
    let (_, _, stats) = box_images_agree_with_stats(ctx, &room_scene(6).unwrap(), sparse);
    // The box's six walls touch 15 % of the bricks; a dense volume holds 40 bytes of sums per
    // cell and 16 of levels per cell at level 0 (8/7 of that over the chain).
    let dense = 256u64.pow(3) * (40 + 16 * 8 / 7);
    assert!(stats.bytes < dense / 4, "{} bytes against {dense} dense", stats.bytes);
}

/// Anisotropic levels on the GPU (`levels_aniso_main`, `gi_sample_level`'s faces): the
/// thick-walled box's image equals the CPU's (at 64³: at 32³ its walls are under two cells
/// thick and even the isotropic images differ by 2 %), with one bounce and with two (the chain rebuilt
/// after the bounce), and differs from the GPU's isotropic image, so the faces were read.
#[test]
fn gpu_anisotropic_levels_match_the_cpu() {
    let Some(ctx) = context() else { return };
    let scene = voxray::bench::gi::thick_room_scene(6).unwrap();
    // Per-pixel cones: their wide cones read the coarse levels' faces (the default caches'
    // narrow cones read mostly the finest level, which has none).
    let gather = voxray::render::Gather::Pixels;
    let s = GiSettings { res: 64, anisotropic: true, gather, ..Default::default() };
    let (_, aniso) = box_images_agree(ctx.clone(), &scene, s);
    box_images_agree(ctx.clone(), &scene, GiSettings { bounces: 2, ..s });
    let (_, iso) = box_images_agree(ctx, &scene, GiSettings { anisotropic: false, ..s });
    let n = aniso.radiance.len() as f32;
    let change = aniso.radiance.iter().zip(&iso.radiance).map(|(a, b)| (*a - *b).abs().element_sum()).sum::<f32>() / n;
    let mean = iso.radiance.iter().map(|c| c.element_sum()).sum::<f32>() / n;
    assert!(change > 0.02 * mean, "anisotropic levels changed the GPU image by only {change} (mean {mean})");
}

/// The half-resolution gather on the GPU: the image equals the CPU's half-resolution image,
/// and differs from the GPU's own per-pixel one (so the samples were really used).
#[test]
fn gpu_half_resolution_gather_matches_the_cpu() {
    let Some(ctx) = context() else { return };
    let scene = room_scene(6).unwrap();
    let half = GiSettings { res: 32, gather: voxray::render::Gather::Half, ..Default::default() };
    let (cpu, gpu) = box_images_agree(ctx.clone(), &scene, half);
    assert!(cpu.gathers > 0 && cpu.gathers < cpu.radiance.len() as u64 / 2);
    let pixels = GiSettings { gather: voxray::render::Gather::Pixels, ..half };
    let (_, per_pixel) = box_images_agree(ctx, &scene, pixels);
    let w = 64;
    let differ = (0..gpu.radiance.len())
        .filter(|&k| (k % w) % 2 == 1 && gpu.radiance[k] != per_pixel.radiance[k] && gpu.instance[k] >= 0)
        .count();
    assert!(differ > 100, "only {differ} odd-column pixels changed with the half gather");
    for k in (0..gpu.radiance.len()).filter(|k| (k % w) % 2 == 0 && (k / w) % 2 == 0) {
        assert_eq!(gpu.radiance[k], per_pixel.radiance[k], "sample pixel {k}");
    }
}

/// More bounces on the GPU: the two- and three-bounce images equal the CPU's, and each bounce
/// brightens the closed box; so do the images with the bounces' tail (dense and sparse
/// volumes: the bounce pass's workgroup sums, the factor pass, the tail's commit), which are
/// brighter than the same bounces without it.
#[test]
fn gpu_gi_bounces_match_the_cpu() {
    let Some(ctx) = context() else { return };
    let scene = room_scene(6).unwrap();
    let sum = |f: &Frame| f.radiance.iter().map(|c| c.element_sum()).sum::<f32>();
    let mut last = 0.0;
    for bounces in 1..=3 {
        let s = GiSettings { res: 32, bounces, bounce_tail: false, ..Default::default() };
        let (_, gpu) = box_images_agree(ctx.clone(), &scene, s);
        assert!(sum(&gpu) > last * 1.02, "{bounces} bounces: {} against {last}", sum(&gpu));
        last = sum(&gpu);
    }
    for (volume, bounces) in [(VolumeChoice::Dense, 2), (VolumeChoice::Sparse, 2), (VolumeChoice::Dense, 3)] {
        let s = GiSettings { res: 32, bounces, volume, ..Default::default() };
        assert!(s.bounce_tail, "the tail is on by default");
        let (_, with) = box_images_agree(ctx.clone(), &scene, s);
        let (_, without) = box_images_agree(ctx.clone(), &scene, GiSettings { bounce_tail: false, ..s });
        let (a, b) = (sum(&with), sum(&without));
        assert!(a > 1.05 * b, "{volume:?}, {bounces} bounces: {a} with the tail against {b} without");
        // The factor itself, read back, against the CPU's (sums of every cell: a workgroup
        // left out of the GPU's sum moves it).
        let (cam, lights) = (voxray::model::room::camera(64, 48), voxray::model::room::lights());
        let (_, capture) = gpu_frame(ctx.clone(), &scene, &cam, &lights, s);
        let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
        let mut caches = GiCaches::new();
        let opts = RenderOptions::default();
        let (_, stats) =
            voxray::gi::render_with_gi(&scene, &cam, &lights, &plan, &opts, None, &s, &mut caches, &|_, _| {}).unwrap();
        let (cpu, gpu) = (stats.tail.expect("the CPU added the tail"), capture.tail.expect("the GPU added the tail"));
        assert!(cpu.min_element() > 0.1, "{cpu}");
        let off = (cpu - gpu).abs().max_element();
        assert!(off <= 5e-3 * cpu.max_element(), "{volume:?}, {bounces} bounces: tail factor CPU {cpu} GPU {gpu}");
    }
    // A chain gathered with one bounce is not reused for two.
    let (cam, lights) = (voxray::model::room::camera(16, 12), voxray::model::room::lights());
    let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
    let mut gpu = GpuRenderer::new(ctx);
    for (bounces, want) in [(1, GiReuse::Nothing), (1, GiReuse::Levels), (2, GiReuse::Volume), (2, GiReuse::Levels)] {
        gpu.set_gi(Some(GiSettings { res: 16, bounces, ..Default::default() })).unwrap();
        gpu.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
        assert_eq!(gpu.gi_stats.expect("GI ran").reuse, want, "{bounces} bounces");
    }
}

/// Renders the box on both backends with `s` and checks the images agree; returns them.
fn box_images_agree(ctx: Arc<GpuContext>, scene: &Scene, s: GiSettings) -> (Frame, Frame) {
    let (cpu, gpu, _) = box_images_agree_with_stats(ctx, scene, s);
    (cpu, gpu)
}

/// [`box_images_agree`], with what the GPU's GI did.
fn box_images_agree_with_stats(
    ctx: Arc<GpuContext>,
    scene: &Scene,
    s: GiSettings,
) -> (Frame, Frame, voxray::gpu::gi::GpuGiStats) {
    let cam = voxray::model::room::camera(64, 48);
    images_agree(ctx, scene, &cam, &voxray::model::room::lights(), s)
}

/// Renders `scene` with GI on both backends and checks the images agree.
fn images_agree(
    ctx: Arc<GpuContext>,
    scene: &Scene,
    cam: &Camera,
    lights: &Lights,
    s: GiSettings,
) -> (Frame, Frame, voxray::gpu::gi::GpuGiStats) {
    let (cam, lights) = (*cam, lights.clone());
    let plan = FramePlan::new(scene, &cam, &lights, &Features::default(), None);
    let flat = render(scene, &cam, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap().radiance;
    let opts = RenderOptions::default();
    let mut caches = GiCaches::new();
    let (cpu, _) =
        voxray::gi::render_with_gi(scene, &cam, &lights, &plan, &opts, None, &s, &mut caches, &|_, _| {}).unwrap();
    let mut renderer = GpuRenderer::new(ctx);
    renderer.set_gi(Some(s)).unwrap();
    let gpu = renderer.render(scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    let stats = renderer.gi_stats.expect("GI ran");
    assert_eq!(stats.layout, s.layout());
    let n = cpu.radiance.len();
    let mean = |v: &[Vec3]| v.iter().map(|c| c.element_sum()).sum::<f32>() / n as f32;
    // GI changes the closed box a lot (bounced sun instead of a flat sky everywhere): the
    // comparison only means something if it does.
    let change = cpu.radiance.iter().zip(&flat).map(|(a, b)| (*a - *b).abs().element_sum()).sum::<f32>() / n as f32;
    assert!(change > 0.2 * mean(&cpu.radiance), "GI changed the box by only {change}");
    assert!(gpu.radiance.iter().all(|c| c.is_finite() && c.min_element() >= 0.0));
    let diff =
        cpu.radiance.iter().zip(&gpu.radiance).map(|(a, b)| (*a - *b).abs().element_sum()).sum::<f32>() / n as f32;
    let rel = diff / mean(&cpu.radiance);
    assert!(rel < 0.02, "mean GPU−CPU difference is {:.2} % of the mean radiance", 100.0 * rel);
    let off = cpu
        .radiance
        .iter()
        .zip(&gpu.radiance)
        .filter(|(a, b)| (**a - **b).abs().max_element() > 0.1 * a.max_element().max(0.05))
        .count();
    assert!(off as f64 <= 0.01 * n as f64, "{off} of {n} pixels differ by more than 10 %");
    // The cones' ambient occlusion AOV, read back from the radiance's fourth channel.
    assert_eq!((cpu.ao.len(), gpu.ao.len()), (n, n));
    let ao_diff = cpu.ao.iter().zip(&gpu.ao).map(|(a, b)| (a - b).abs()).sum::<f32>() / n as f32;
    assert!(ao_diff < 0.01, "mean GPU−CPU AO difference {ao_diff}");
    (cpu, gpu, stats)
}

#[test]
fn gpu_gi_stays_finite_for_extreme_knobs_and_skips_without_lights() {
    let Some(ctx) = context() else { return };
    let scene = cars();
    let mut cam = car_camera();
    cam.width = 32;
    cam.height = 24;
    let mut gpu = GpuRenderer::new(ctx.clone());
    // Bad knobs are refused before any frame.
    for bad in [
        GiSettings { res: 0, ..Default::default() },
        GiSettings { res: 4096, ..Default::default() },
        GiSettings { cones: voxray::gi::ConeSettings { diffuse_cones: 0, ..Default::default() }, ..Default::default() },
        GiSettings {
            cones: voxray::gi::ConeSettings { aperture_deg: 180.0, ..Default::default() },
            ..Default::default()
        },
    ] {
        let e = gpu.set_gi(Some(bad)).unwrap_err().to_string();
        assert!(e.contains("GI") || e.contains("cone"), "unclear error: {e}");
    }
    let lights = Lights::default();
    let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
    for s in [
        GiSettings { res: 1, ..Default::default() },
        GiSettings { res: 2, filter: Filter::Nearest, ..Default::default() },
        GiSettings {
            res: 16,
            cones: voxray::gi::ConeSettings {
                diffuse_cones: 64,
                aperture_deg: 179.0,
                max_distance: 1e-3,
                specular_cone: true,
            },
            ..Default::default()
        },
        GiSettings { res: 16, extent: Some(1e-3), ..Default::default() },
        GiSettings { res: 16, extent: Some(1e7), ..Default::default() },
        GiSettings { res: 16, bounces: voxray::gi::shade::MAX_BOUNCES, ..Default::default() },
    ] {
        gpu.set_gi(Some(s)).unwrap();
        let f = gpu.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
        assert!(f.radiance.iter().all(|c| c.is_finite() && c.min_element() >= 0.0), "{s:?}");
    }
    // A non-finite extent or too many bounces are errors, not a NaN image.
    assert!(gpu.set_gi(Some(GiSettings { res: 16, extent: Some(f64::NAN), ..Default::default() })).is_err());
    let e = gpu.set_gi(Some(GiSettings { bounces: 9, ..Default::default() })).unwrap_err().to_string();
    assert!(e.contains("bounces"), "{e}");
    // Anisotropic levels live in the level buffer only: a clear refusal with the texture store.
    let aniso_texture =
        GiSettings { anisotropic: true, levels: voxray::gi::shade::LevelStore::Texture, ..Default::default() };
    let e = gpu.set_gi(Some(aniso_texture)).unwrap_err().to_string();
    assert!(e.contains("level buffer only"), "{e}");
    // `auto` on the GPU is the CPU's choice (dense up to 128³, sparse above) where this device
    // can bind a dense volume's cells, sparse where it cannot; anisotropic levels keep it dense
    // wherever it fits. A sparse volume needs a multiple of 8 cells per side.
    let limit = ctx.limits.max_storage_buffer_binding_size.min(ctx.limits.max_buffer_size);
    let fits = |res: u32| (res as u64).pow(3) * 40 + 4 <= limit;
    for res in [64, 256] {
        gpu.set_gi(Some(GiSettings { res, ..Default::default() })).unwrap();
        let want = if fits(res) && res <= 128 { voxray::gi::Layout::Dense } else { voxray::gi::Layout::Sparse };
        assert_eq!(gpu.gi_settings().map(|s| s.layout()), Some(want), "{res}³, binding limit {limit}");
    }
    let aniso = gpu.set_gi(Some(GiSettings { res: 256, anisotropic: true, ..Default::default() }));
    match fits(256) {
        true => assert_eq!(gpu.gi_settings().map(|s| s.layout()), Some(voxray::gi::Layout::Dense)),
        false => assert!(aniso.is_err_and(|e| e.to_string().contains("anisotropic")), "binding limit {limit}"),
    }
    gpu.set_gi(Some(GiSettings { res: 1024, ..Default::default() })).unwrap();
    assert_eq!(gpu.gi_settings().map(|s| s.layout()), Some(voxray::gi::Layout::Sparse));
    let sparse = GiSettings { res: 60, volume: voxray::gi::shade::VolumeChoice::Sparse, ..Default::default() };
    let e = gpu.set_gi(Some(sparse)).unwrap_err().to_string();
    assert!(e.contains("multiple of 8"), "{e}");
    // No lights at all: GI would add nothing, so it is skipped.
    let dark = Lights { sun: None, ambient: None, use_mtl_emitters: false, ..Lights::default() };
    assert_eq!(dark.sky(), Vec3::ZERO);
    gpu.set_gi(Some(GiSettings { res: 16, ..Default::default() })).unwrap();
    gpu.render(&scene, &cam, &dark, &plan, &RenderOptions::default()).unwrap();
    assert!(gpu.gi_stats.is_none(), "GI ran without lights");
}

/// The sparse volume on the GPU holds exactly what the dense one holds: the same fixed-point
/// sums (integer atomics add the same values in any order), the same injected light and levels
/// (the same children averaged in the same order), hence the same image, with one bounce and
/// with two (with the bounces' tail, to rounding); and a brick pool that grows for a fuller scene renders what a fresh one renders.
#[test]
fn gpu_sparse_volume_equals_the_dense_one() {
    use voxray::gi::shade::VolumeChoice;
    use voxray::gi::Layout;
    let Some(ctx) = context() else { return };
    let scene = cars();
    let cam = car_camera();
    let lights = Lights::default();
    // The bounces' tail sums floats over the cells in the layout's order, so with it the two
    // agree to rounding instead of bit for bit.
    for (bounces, bounce_tail) in [(1, false), (2, false), (2, true)] {
        // Smaller than the scene, so weight also falls outside.
        let s = GiSettings { res: 48, extent: Some(14.0), bounces, bounce_tail, ..Default::default() };
        let dense = GiSettings { volume: VolumeChoice::Dense, ..s };
        let sparse = GiSettings { volume: VolumeChoice::Sparse, ..s };
        let (fd, cd) = gpu_frame(ctx.clone(), &scene, &cam, &lights, dense);
        let (fs, cs) = gpu_frame(ctx.clone(), &scene, &cam, &lights, sparse);
        assert!(cd.outside > 10.0, "the test volume leaves some voxels out ({})", cd.outside);
        assert_eq!(cs.outside, cd.outside);
        assert_eq!(cs.volume, cd.volume, "{bounces} bounces: volume");
        assert_eq!(cs.levels.levels.len(), cd.levels.levels.len());
        assert!(cd.levels.levels[0].rgba.iter().any(|v| v.truncate().max_element() > 0.0), "lit");
        if bounce_tail {
            let (a, b) = (cs.tail.expect("sparse tail"), cd.tail.expect("dense tail"));
            assert!((a - b).abs().max_element() <= 1e-5 * b.max_element(), "tail factor sparse {a} dense {b}");
            for (k, (a, b)) in fs.radiance.iter().zip(&fd.radiance).enumerate() {
                assert!((*a - *b).abs().max_element() <= 1e-4 * b.max_element().max(1.0), "pixel {k}: {a} vs {b}");
            }
            continue;
        }
        for (l, (a, b)) in cs.levels.levels.iter().zip(&cd.levels.levels).enumerate() {
            assert_eq!(a, b, "{bounces} bounces: level {l}");
        }
        assert_eq!(fs.radiance, fd.radiance, "{bounces} bounces: image");
    }
    // Stats, reuse, and a pool grown from the box's bricks to the cars' ones.
    let s = GiSettings { res: 48, extent: Some(14.0), volume: VolumeChoice::Sparse, ..Default::default() };
    let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
    let mut gpu = GpuRenderer::new(ctx.clone());
    gpu.set_gi(Some(GiSettings { res: 16, ..s })).unwrap();
    let room = room_scene(4).unwrap();
    let room_plan = FramePlan::new(&room, &cam, &lights, &Features::default(), None);
    gpu.render(&room, &voxray::model::room::camera(16, 12), &lights, &room_plan, &RenderOptions::default()).unwrap();
    let small = gpu.gi_bricks().unwrap().expect("a sparse volume");
    gpu.set_gi(Some(s)).unwrap();
    let a = gpu.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    let stats = gpu.gi_stats.expect("GI ran");
    assert_eq!((stats.layout, stats.reuse), (Layout::Sparse, GiReuse::Nothing));
    let bricks = gpu.gi_bricks().unwrap().expect("a sparse volume");
    assert!(bricks > small && bricks < 6 * 6 * 6, "{bricks} bricks of 216");
    assert!(stats.brick_capacity >= bricks, "a pool of {} for {bricks} bricks", stats.brick_capacity);
    let b = gpu.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    assert_eq!(gpu.gi_stats.expect("GI ran").reuse, GiReuse::Levels);
    assert_eq!(a.radiance, b.radiance);
    let (fresh, _) = gpu_frame(ctx.clone(), &scene, &cam, &lights, s);
    assert_eq!(a.radiance, fresh.radiance);
    // A pool whose bound may not be allocated is sized by the count read back: same image.
    let mut counting = GpuRenderer::new(ctx);
    counting.set_gi(Some(s)).unwrap();
    counting.set_gi_brick_bound_limit(0);
    let c = counting.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
    let st = counting.gi_stats.expect("GI ran");
    assert_eq!(st.bricks_counted, Some(bricks), "the count was read back");
    assert_eq!(st.brick_capacity, (bricks + bricks / 4).max(8), "a quarter's slack over the count");
    eprintln!(
        "{bricks} bricks: a pool of {} from the bound, {} from the count",
        stats.brick_capacity, st.brick_capacity
    );
    assert_eq!(c.radiance, a.radiance);
}

/// The level chain read from a 3D texture (rgba16float, hardware quadrilinear filtering)
/// gives the image the f32 buffer chain gives, within the texture's precision, on one bounce
/// and two (the bounce cones read it too); a reused frame equals the first; a sparse volume
/// refuses it.
#[test]
fn gpu_texture_levels_match_the_buffer_levels() {
    use voxray::gi::shade::{LevelStore, VolumeChoice};
    let Some(ctx) = context() else { return };
    let scene = room_scene(6).unwrap();
    let cam = voxray::model::room::camera(64, 48);
    let lights = voxray::model::room::lights();
    let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
    for (res, bounces) in [(32, 1), (48, 2)] {
        let s = GiSettings { res, bounces, volume: VolumeChoice::Dense, ..Default::default() };
        let frame = |levels| {
            let mut gpu = GpuRenderer::new(ctx.clone());
            gpu.set_gi(Some(GiSettings { levels, ..s })).unwrap();
            let f = gpu.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
            let again = gpu.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
            assert_eq!(gpu.gi_stats.expect("GI ran").reuse, GiReuse::Levels);
            assert_eq!(f.radiance, again.radiance);
            f
        };
        let (buf, tex) = (frame(LevelStore::Buffer), frame(LevelStore::Texture));
        let flat = render(&scene, &cam, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap();
        let n = buf.radiance.len() as f32;
        let mean = buf.radiance.iter().map(|c| c.element_sum()).sum::<f32>() / n;
        let diff = |a: &Frame, b: &Frame| {
            a.radiance.iter().zip(&b.radiance).map(|(x, y)| (*x - *y).abs().element_sum()).sum::<f32>() / n
        };
        // GI changes the box by tens of percent; the texture's half floats and the sampler's
        // weights move it by 0.005 % on llvmpipe. The bound leaves room for hardware samplers'
        // 8-bit sub-texel weights; a chain 3 % too dark moves it by 0.5 %.
        assert!(diff(&buf, &flat) > 0.2 * mean);
        let rel = diff(&buf, &tex) / mean;
        assert!(rel < 0.001, "{res}³, {bounces} bounces: texture against buffer {:.3} %", 100.0 * rel);
        assert!(tex.radiance.iter().all(|c| c.is_finite() && c.min_element() >= 0.0));
    }
    let mut gpu = GpuRenderer::new(ctx);
    let sparse =
        GiSettings { res: 64, volume: VolumeChoice::Sparse, levels: LevelStore::Texture, ..Default::default() };
    let e = gpu.set_gi(Some(sparse)).unwrap_err().to_string();
    assert!(e.contains("dense volume"), "{e}");
}

#[test]
fn gpu_static_frames_reuse_the_volume_and_render_what_a_fresh_frame_renders() {
    let Some(ctx) = context() else { return };
    let mut scene = room_scene(5).unwrap();
    let cam = voxray::model::room::camera(32, 24);
    let lights = voxray::model::room::lights();
    let s = GiSettings { res: 32, ..Default::default() };
    let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
    let mut gpu = GpuRenderer::new(ctx.clone());
    gpu.set_gi(Some(s)).unwrap();
    let frame = |gpu: &mut GpuRenderer, scene: &Scene, lights: &Lights| {
        let f = gpu.render(scene, &cam, lights, &plan, &RenderOptions::default()).unwrap();
        (f.radiance, gpu.gi_stats.unwrap().reuse)
    };
    let fresh = |scene: &Scene, lights: &Lights| {
        let mut g = GpuRenderer::new(ctx.clone());
        g.set_gi(Some(s)).unwrap();
        g.render(scene, &cam, lights, &plan, &RenderOptions::default()).unwrap().radiance
    };
    let (a, ra) = frame(&mut gpu, &scene, &lights);
    assert_eq!(ra, GiReuse::Nothing);
    let (b, rb) = frame(&mut gpu, &scene, &lights);
    assert_eq!(rb, GiReuse::Levels);
    assert_eq!(a, b);
    let mut dim = lights;
    if let Some(sun) = dim.sun.as_mut() {
        sun.irradiance *= 0.5;
    }
    let (c, rc) = frame(&mut gpu, &scene, &dim);
    assert_eq!(rc, GiReuse::Volume);
    assert_ne!(c, a);
    assert_eq!(c, fresh(&scene, &dim));
    let t = voxray::scene::Transform { translation: DVec3::new(0.05, 0.0, 0.0), ..voxray::scene::Transform::IDENTITY };
    scene.set_local(scene.instances().len() - 1, t).unwrap();
    scene.update().unwrap();
    let (d, rd) = frame(&mut gpu, &scene, &dim);
    assert_eq!(rd, GiReuse::Nothing);
    assert_eq!(d, fresh(&scene, &dim));
}

#[test]
fn gpu_revoxelization_marks_the_cells_the_cpu_voxelizer_marks() {
    use voxray::gpu::baseline::GpuVolumePasses;
    use voxray::mesh::Part;
    use voxray::svo::Cube;
    let Some(ctx) = context() else { return };
    let scene = cars();
    let mesh = voxray::model::car::mesh();
    let instances: Vec<(usize, glam::DAffine3)> =
        scene.instances().iter().enumerate().map(|(i, inst)| (inst.part, scene.world(i))).collect();
    let (lo, hi) = scene.bounds();
    let spec = voxray::gi::VolumeSpec::following((lo + hi) * 0.5, (hi - lo).max_element() * 1.05, 64).unwrap();
    let passes = GpuVolumePasses::new(ctx);
    let gpu = passes.revoxelize(&mesh, &instances, &spec, 1).unwrap();
    assert_eq!(gpu.work as usize, instances.iter().map(|(p, _)| mesh.parts[*p].triangles.len()).sum::<usize>());
    // The CPU baseline: each moved part voxelized into the same cells.
    let cube = Cube { min: spec.min.as_vec3(), size: (spec.cell * 64.0) as f32 };
    let mut cpu = Volume::new(spec);
    for (part, world) in &instances {
        let mut moved = Part { name: String::new(), triangles: mesh.parts[*part].triangles.clone() };
        for t in &mut moved.triangles {
            for p in &mut t.positions {
                *p = world.transform_point3(p.as_dvec3()).as_vec3();
            }
        }
        let grid = voxray::voxelize::voxelize_in(&moved, &mesh.materials, cube, 6, false, &|_, _| {}).unwrap();
        cpu.write_grid(&grid).unwrap();
    }
    // The GPU voxelizes all instances together (one unit per touched cell); the CPU adds one
    // per part voxel. Compare which cells are occupied and their mean albedo; f32 on the GPU
    // may flip cells a triangle only touches.
    let (mut both, mut only) = (0usize, 0usize);
    let (mut albedo_off, mut single) = (0usize, 0usize);
    for i in 0..cpu.occupancy.len() {
        let (c, g) = (cpu.occupancy[i], gpu.volume.occupancy[i]);
        assert!(g == 0.0 || (g - 1.0).abs() < 1e-4, "GPU occupancy {g} is not one unit");
        match (c > 0.0, g > 0.0) {
            (true, true) => {
                both += 1;
                // Cells of one part only: where parts share a cell the CPU averages per part.
                if c == 1.0 {
                    single += 1;
                    let d = (cpu.albedo[i] - gpu.volume.albedo[i] / g).abs().max_element();
                    albedo_off += (d > 0.02) as usize;
                }
            }
            (false, false) => {}
            _ => only += 1,
        }
    }
    assert!(both > 1000, "{both} cells occupied");
    assert!(only <= both / 100, "{only} cells occupied on one side only, {both} on both");
    assert!(albedo_off <= single / 100 && single > both / 2, "{albedo_off} of {single} cells differ in albedo");
    // The transformation through the same passes equals the CPU splat.
    let mut caches = Vec::new();
    for p in &scene.parts {
        caches.push(voxray::gi::VoxelCache::from_svo(p, 4).unwrap());
    }
    let moved = passes.transform(&caches, &instances, &spec, Filter::Split, 2).unwrap();
    assert_eq!(moved.ms.len(), 2);
    let mut cpu = Volume::new(spec);
    for (part, world) in &instances {
        cpu.splat(&caches[*part], world, Filter::Split).unwrap();
    }
    let (tc, tg) = (cpu.total_occupancy(), moved.volume.total_occupancy());
    assert!((tc - tg).abs() <= 1e-4 * tc && tc > 1000.0, "total occupancy CPU {tc} vs GPU {tg}");
}

/// GI frames of an animated clip create no buffers once warm and, kept on the GPU, read
/// nothing back (dense and sparse volumes: the sparse pool is sized from a bound and its brick
/// count stays on the GPU): the jobs and uniforms are kept and rewritten, and bind groups
/// reused while the buffers they name stay. Each frame equals a fresh renderer's frame of the
/// same pose, so nothing stale is bound.
#[test]
fn gpu_gi_frames_of_an_animated_clip_create_no_buffers_and_match_fresh_frames() {
    let Some(ctx) = context() else { return };
    let parts = build_parts(&voxray::model::car::mesh(), Resolution::Depth(6)).unwrap();
    let mut scene = Scene::new(parts);
    let car = add_car(&mut scene, 0, DVec3::ZERO, 0.0, true).unwrap();
    let cam = car_camera();
    let lights = Lights::default();
    for volume in [voxray::gi::shade::VolumeChoice::Dense, voxray::gi::shade::VolumeChoice::Sparse] {
        let s = GiSettings { res: 32, volume, ..Default::default() };
        let own = Arc::new(GpuContext::headless().unwrap());
        let mut gpu = GpuRenderer::new(own.clone());
        gpu.set_gi(Some(s)).unwrap();
        gpu.set_read_back(false);
        for f in 0..6 {
            pose(&mut scene, &car, 0.2 + f as f64 / 30.0).unwrap();
            scene.update().unwrap();
            let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), (f > 0).then_some(&gpu.state));
            gpu.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
            let stats = gpu.gi_stats.expect("GI ran");
            assert_eq!(stats.reuse, GiReuse::Nothing, "{volume:?} frame {f}: the car moved");
            assert_eq!(stats.bricks_counted, None, "{volume:?} frame {f}: the brick count was read back");
            let (created, read) = gpu.frame_traffic;
            eprintln!(
                "{volume:?} frame {f}: created {created} buffers, read {read} B, a pool of {} bricks",
                stats.brick_capacity
            );
            assert_eq!(read, 0, "{volume:?} frame {f} read back");
            if f >= 2 {
                assert_eq!(created, 0, "{volume:?} frame {f} created buffers");
            }
            let image = gpu.read_image().unwrap();
            let mut fresh = GpuRenderer::new(ctx.clone());
            fresh.set_gi(Some(s)).unwrap();
            let plan0 = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
            let expected = fresh.render(&scene, &cam, &lights, &plan0, &RenderOptions::default()).unwrap();
            assert_eq!(image, expected.radiance, "{volume:?} frame {f}");
        }
    }
}

/// The emissive-panel room with GI: both backends sample the panel from every shaded pixel and
/// every lit GI cell with the same points, so the walls' bounced light agrees as well.
#[test]
fn gpu_gi_with_emitters_matches_the_cpu() {
    let Some(ctx) = context() else { return };
    let scene = voxray::bench::gi::panel_room_scene(6).unwrap();
    let cam = voxray::model::panel_room::camera(64, 48);
    let lights = voxray::model::panel_room::lights();
    images_agree(ctx.clone(), &scene, &cam, &lights, GiSettings { res: 32, ..Default::default() });
    // A point and a spot besides the panel: injected into the cells the same way.
    let more = Lights {
        points: vec![voxray::scene::lights::PointLight {
            position: glam::DVec3::new(0.5, 1.5, -0.2),
            intensity: Vec3::new(0.5, 0.8, 1.0),
        }],
        spots: vec![voxray::scene::lights::SpotLight {
            position: glam::DVec3::new(-0.6, 1.8, 0.5),
            direction: Vec3::new(0.3, -1.0, -0.4),
            intensity: Vec3::new(2.0, 0.5, 0.2),
            inner_deg: 15.0,
            outer_deg: 35.0,
        }],
        ..lights
    }
    .validated()
    .unwrap();
    images_agree(ctx, &scene, &cam, &more, GiSettings { res: 32, ..Default::default() });
}

/// Light injection with emitters on the GPU draws `cell_light_samples` points per cell, as the
/// CPU does: the panel room's injected level equals the CPU's at one and at three samples,
/// which differ from each other.
#[test]
fn gpu_cells_draw_as_many_emitter_samples_as_the_cpu() {
    let Some(ctx) = context() else { return };
    let scene = voxray::bench::gi::panel_room_scene(6).unwrap();
    let cam = voxray::model::panel_room::camera(64, 48);
    let lights = voxray::model::panel_room::lights();
    let mut cpu_levels = Vec::new();
    for samples in [1, 3] {
        let s = GiSettings { res: 32, cell_light_samples: samples, ..Default::default() };
        let (_, cap) = gpu_frame(ctx.clone(), &scene, &cam, &lights, s);
        let (cpu, _) = cpu_volume(&scene, &cam, &s);
        let inj = inject(&cpu, &scene, &lights, samples);
        let g = &cap.levels.levels[0];
        assert_eq!(inj.rgba.len(), g.rgba.len());
        let peak = inj.rgba.iter().map(|v| v.truncate().max_element()).fold(0.0f32, f32::max);
        assert!(peak > 0.0);
        let off = inj
            .rgba
            .iter()
            .zip(&g.rgba)
            .filter(|(a, b)| (a.truncate() - b.truncate()).abs().max_element() > 1e-3 * peak)
            .count();
        let lit = inj.rgba.iter().filter(|v| v.w > 0.0).count();
        assert!(off <= 1 + lit / 50, "{samples} samples: {off} of {lit} cells differ in radiance");
        cpu_levels.push(inj.rgba);
    }
    let changed = cpu_levels[0].iter().zip(&cpu_levels[1]).filter(|(a, b)| a != b).count();
    let lit = cpu_levels[0].iter().filter(|v| v.w > 0.0).count();
    assert!(changed > lit / 2, "one and three samples changed only {changed} of {lit} cells");
}

/// Cone-traced emitter shadows on the GPU: the panel room's image equals the CPU's with them,
/// and differs from the GPU's image with shadow rays (so the cones replaced the rays).
#[test]
fn gpu_cone_shadows_match_the_cpu() {
    let Some(ctx) = context() else { return };
    let scene = voxray::bench::gi::panel_room_scene(6).unwrap();
    let cam = voxray::model::panel_room::camera(64, 48);
    let lights = voxray::model::panel_room::lights();
    let s = GiSettings { res: 32, cone_shadows: true, ..Default::default() };
    let (_, cones, _) = images_agree(ctx.clone(), &scene, &cam, &lights, s);
    let (_, rays, _) = images_agree(ctx, &scene, &cam, &lights, GiSettings { cone_shadows: false, ..s });
    let n = cones.radiance.len() as f32;
    let change = cones.radiance.iter().zip(&rays.radiance).map(|(a, b)| (*a - *b).abs().element_sum()).sum::<f32>() / n;
    let mean = rays.radiance.iter().map(|c| c.element_sum()).sum::<f32>() / n;
    assert!(change > 0.01 * mean, "cone shadows changed the GPU image by only {change} (mean {mean})");
}

/// The GPU counts its GI gathers as the CPU does: every shaded hit with the per-pixel gather;
/// the samples and the pixels no sample serves with the half-resolution one.
#[test]
fn gpu_counts_its_gathers_like_the_cpu() {
    let Some(ctx) = context() else { return };
    let scene = room_scene(6).unwrap();
    let (cam, lights) = (voxray::model::room::camera(64, 48), voxray::model::room::lights());
    let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
    let opts = RenderOptions::default();
    for gather in [voxray::render::Gather::Pixels, voxray::render::Gather::Half] {
        let s = GiSettings { res: 32, gather, ..Default::default() };
        let (cpu, _) =
            voxray::gi::render_with_gi(&scene, &cam, &lights, &plan, &opts, None, &s, &mut GiCaches::new(), &|_, _| {})
                .unwrap();
        let mut gpu = GpuRenderer::new(ctx.clone());
        gpu.set_gi(Some(s)).unwrap();
        gpu.set_counting(true);
        let g = gpu.render(&scene, &cam, &lights, &plan, &opts).unwrap();
        let tol = 8 + cpu.gathers / 50;
        assert!(g.gathers > 0, "{gather:?}: the GPU counted no gathers");
        assert!(cpu.gathers.abs_diff(g.gathers) <= tol, "{gather:?}: CPU {} GPU {} gathers", cpu.gathers, g.gathers);
    }
}

/// Radiance caches on the GPU: the box lit through them as on the CPU, clustered and even,
/// with their fallback gathers counted alike; and different from the GPU's per-pixel gather
/// (so the caches were really used).
#[test]
fn gpu_radiance_caches_match_the_cpu() {
    use voxray::render::radiance_cache::{CacheSettings, Placement};
    let Some(ctx) = context() else { return };
    let scene = room_scene(6).unwrap();
    let pixels = GiSettings { res: 32, gather: voxray::render::Gather::Pixels, ..Default::default() };
    let (_, per_pixel) = box_images_agree(ctx.clone(), &scene, pixels);
    for placement in [Placement::Clustered, Placement::Even] {
        let c = CacheSettings { placement, tile: 8, ..Default::default() };
        let s = GiSettings { res: 32, gather: voxray::render::Gather::Caches(c), ..Default::default() };
        let (cpu, gpu) = box_images_agree(ctx.clone(), &scene, s);
        let differ = gpu.radiance.iter().zip(&per_pixel.radiance).filter(|(a, b)| a != b).count();
        assert!(
            differ > gpu.radiance.len() / 4,
            "{placement:?}: only {differ} pixels differ from the per-pixel gather"
        );
        let mut renderer = GpuRenderer::new(ctx.clone());
        renderer.set_gi(Some(s)).unwrap();
        renderer.set_counting(true);
        let (cam, lights) = (voxray::model::room::camera(64, 48), voxray::model::room::lights());
        let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
        let g = renderer.render(&scene, &cam, &lights, &plan, &RenderOptions::default()).unwrap();
        assert!(
            cpu.gathers.abs_diff(g.gathers) <= 8 + cpu.gathers / 10,
            "{placement:?}: CPU {} GPU {} fallback gathers",
            cpu.gathers,
            g.gathers
        );
    }
    // Glossy walls: the caches' lobe-sized mip level along the mirror direction.
    let glossy = voxray::bench::gi::glossy_room_scene(6).unwrap();
    let c = CacheSettings { tile: 8, ..Default::default() };
    box_images_agree(
        ctx,
        &glossy,
        GiSettings { res: 32, gather: voxray::render::Gather::Caches(c), ..Default::default() },
    );
}
