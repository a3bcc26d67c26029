//! `voxray render`: stills, clips and the path-traced reference, with their image and AOV
//! output.

use super::*;

/// `car.png` → `car_0007.png` for frame 7 of a sequence.
pub(crate) fn numbered(path: &Path, frame: u32) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = path.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or_default();
    path.with_file_name(format!("{stem}_{frame:04}{ext}"))
}

pub(crate) fn orbit(camera: &Camera, degrees: f64) -> Camera {
    let q = glam::DQuat::from_axis_angle(camera.up.normalize(), degrees.to_radians());
    Camera { eye: camera.target + q * (camera.eye - camera.target), ..*camera }
}

/// The frames this run renders: `--frame-range A..B` (default the whole clip), then the
/// contiguous block `--shard I/N` of it.
pub(crate) fn frames_to_render(a: &RenderArgs) -> Result<std::ops::Range<u32>, Error> {
    let mut range = 0..a.frames;
    if let Some(r) = &a.frame_range {
        let parsed =
            r.split_once("..").and_then(|(x, y)| Some((x.trim().parse::<u32>().ok()?, y.trim().parse::<u32>().ok()?)));
        match parsed {
            Some((x, y)) if x < y && y <= a.frames => range = x..y,
            _ => {
                return Err(usage(&format!(
                    "--frame-range {r}: expected A..B with A < B ≤ --frames ({}), frames numbered from 0",
                    a.frames
                )))
            }
        }
    }
    if let Some(sh) = &a.shard {
        let parsed =
            sh.split_once('/').and_then(|(i, n)| Some((i.trim().parse::<u32>().ok()?, n.trim().parse::<u32>().ok()?)));
        match parsed {
            Some((i, n)) if n >= 1 && i < n => {
                let len = (range.end - range.start) as u64;
                let at = |k: u32| range.start + (len * k as u64 / n as u64) as u32;
                range = at(i)..at(i + 1);
            }
            _ => return Err(usage(&format!("--shard {sh}: expected I/N with 0 ≤ I < N (e.g. 0/4 … 3/4)"))),
        }
    }
    Ok(range)
}

/// Whether frame `f`'s outputs are on disk and whole (resume): the image decodes at the
/// camera's size, and with --aov-dir its AOVs are there.
fn frame_done(a: &RenderArgs, f: u32, width: u32, height: u32) -> bool {
    let path = numbered(&a.out, f);
    let image_ok = image::ImageReader::open(&path)
        .ok()
        .and_then(|r| r.with_guessed_format().ok())
        .and_then(|r| r.decode().ok())
        .is_some_and(|img| img.width() == width && img.height() == height);
    let aovs_ok = a.aov_dir.as_ref().is_none_or(|dir| {
        let d = dir.join(format!("frame_{f:04}"));
        ["t.npy", "instance.npy", "normal.npy"].iter().all(|n| d.join(n).is_file())
    });
    image_ok && aovs_ok
}

pub(crate) fn render_cmd(a: RenderArgs) -> Result<(), Error> {
    let t0 = Instant::now();
    let is_gif = a.out.extension().is_some_and(|e| e.eq_ignore_ascii_case("gif"));
    if is_gif && a.frames < 2 {
        return Err(usage("a .gif output needs --frames 2 or more"));
    }
    let range = frames_to_render(&a)?;
    if is_gif && (range != (0..a.frames) || a.resume) {
        return Err(usage(
            "a .gif is one file of the whole clip: --frame-range, --shard and --resume write PNG or EXR frames",
        ));
    }
    if a.frames == 1 && a.resume {
        return Err(usage("--resume skips the finished frames of a clip (--frames 2 or more)"));
    }
    // A clip's frames go into a folder of their own, often one a batch job names: make it.
    if a.frames > 1 && !is_gif {
        if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|source| Error::Io { path: dir.display().to_string(), source })?;
        }
    }
    if !(a.fps.is_finite() && a.fps > 0.0) {
        return Err(usage(&format!("--fps {}: frames per second must be a positive number", a.fps)));
    }
    if !a.time.is_finite() {
        return Err(usage(&format!("--time {}: the clip time must be a finite number of seconds", a.time)));
    }
    if !a.orbit.is_finite() {
        return Err(usage(&format!(
            "--orbit {}: the camera's turn must be a finite number of degrees per second",
            a.orbit
        )));
    }
    let features = a.switches.features();
    if !(a.splat_factor.is_finite() && (0.1..=8.0).contains(&a.splat_factor)) {
        return Err(usage(&format!("--splat-factor {}: must be 0.1…8", a.splat_factor)));
    }
    let renderer =
        if a.renderer == "splat" { voxray::render::Renderer::Splat } else { voxray::render::Renderer::Trace };
    use voxray::render::SplatDraw;
    let splat_draw = if a.splat_draw == "quads" { SplatDraw::Quads } else { SplatDraw::Compute };
    let opts =
        RenderOptions { max_level: a.lod.unwrap_or(u32::MAX), renderer, splat_factor: a.splat_factor, splat_draw };
    let gi = a.gi.then(|| voxray::gi::GiSettings {
        res: a.gi_res,
        filter: a.gi_filter,
        cones: voxray::gi::ConeSettings { diffuse_cones: a.gi_cones, ..Default::default() },
        extent: a.gi_extent,
        bounces: a.gi_bounces,
        bounce_tail: a.gi_bounce_tail == "on",
        volume: a.gi_volume,
        levels: a.gi_levels,
        anisotropic: a.gi_anisotropic,
        cone_shadows: a.gi_shadows == "cones",
        cell_light_samples: a.gi_cell_samples,
        gather: match a.gi_gather {
            voxray::render::Gather::Caches(_) => {
                voxray::render::Gather::Caches(voxray::render::radiance_cache::CacheSettings {
                    tile: a.gi_cache_tile,
                    per_tile: a.gi_cache_count,
                    res: a.gi_cache_res,
                    radius: a.gi_cache_radius,
                    placement: a.gi_cache_placement,
                    cone_percent: a.gi_cache_cone,
                })
            }
            g => g,
        },
    });
    if let Some(g) = &gi {
        // Check the knobs before the scene is loaded and voxelized (minutes at depth 11), not
        // after.
        g.validated().map_err(|e| usage(&e.to_string()))?;
    }
    let lights = match &a.lights_json {
        Some(p) => Lights::from_json(&read_text(p)?).map_err(|e| with_path(p, e))?,
        None => Lights::default(),
    };
    let camera_json = a
        .camera_json
        .as_ref()
        .map(|p| read_text(p).and_then(|t| Camera::from_json(&t).map_err(|e| with_path(p, e))))
        .transpose()?;
    let mut st = stage(&a.source, a.cars, a.in_place, a.static_car, !a.no_ground)?;
    let mut camera = camera_json.unwrap_or_else(|| {
        if a.frames == 1 {
            // One frame: frame the car(s) as posed, seen from the front left of the first car.
            let _ = st.pose(a.time);
            let _ = st.scene.update();
            let heading = st
                .cars
                .first()
                .map_or(glam::DQuat::IDENTITY, |c| st.scene.world(c.body).to_scale_rotation_translation().1);
            let (lo, hi) = st.cars_bounds();
            Camera::framing_from(lo.as_vec3(), hi.as_vec3(), 1280, 768, heading * glam::DVec3::new(0.95, 0.36, -0.9))
        } else {
            Camera::framing(st.bounds.0.as_vec3(), st.bounds.1.as_vec3(), 1280, 768)
        }
    });
    camera.width = a.width.unwrap_or(camera.width);
    camera.height = a.height.unwrap_or(camera.height);
    camera.validate()?;
    let t_setup = t0.elapsed();
    let emitters: usize = st.scene.parts.iter().map(|p| p.emitters.len()).sum();
    if emitters > 0 && !a.source.scene.is_empty() && !lights.use_mtl_emitters {
        eprintln!(
            "note: the model has {emitters} emissive triangles (MTL Ke); they light nothing unless the lights JSON sets \"use_mtl_emitters\": true"
        );
    }

    let deepest = st.scene.parts.iter().map(|p| p.depth).max().unwrap_or(0);
    if let Some(lod) = a.lod.filter(|&l| l >= deepest) {
        eprintln!(
            "note: --lod {lod} is at or below the deepest part's depth ({deepest}): every part renders at full detail"
        );
    }
    let size = (st.bounds.1 - st.bounds.0).max_element();
    if let Some(extent) = a.gi_extent.filter(|&e| a.gi && e < size * 1e-3) {
        eprintln!(
            "note: --gi-extent {extent:e} is under a thousandth of the scene's size ({size:.3}): the GI volume holds almost none of it, so GI adds next to nothing"
        );
    }
    let sampled = lights.emitter_sampling() > 0 && emitters > 0;
    let glowing = lights.use_mtl_emitters && st.scene.parts.iter().any(|p| p.attrs.iter().any(|a| a.is_emissive()));
    if !lights.has_direct() && lights.sky() == glam::Vec3::ZERO && !sampled {
        eprintln!(
            "note: the lights give no light (no sun, no sky, no sampled emitter): the image is black{}",
            if glowing { " except where emitters glow" } else { "" }
        );
    }
    // The frames, their AOVs, the reference's sums and every GIF frame, before any is made.
    let pixels = camera.width as u64 * camera.height as u64;
    let mut need = pixels * voxray::memory::FRAME_BYTES_PER_PIXEL;
    if a.reference {
        need += pixels * voxray::memory::REFERENCE_BYTES_PER_PIXEL;
    }
    if is_gif {
        need += pixels * 4 * a.frames as u64;
    }
    let what = format!(
        "rendering {}×{}{}{}",
        camera.width,
        camera.height,
        if a.reference { " with the path-traced reference" } else { "" },
        if is_gif { format!(" into a GIF of {} frames", a.frames) } else { String::new() }
    );
    voxray::memory::check(&what, need, "lower --width/--height (or --frames of a GIF), or raise --memory-budget")?;
    // Where the AOVs go is checked before rendering, not after (and not made for a render the
    // budget refuses).
    if let Some(dir) = &a.aov_dir {
        std::fs::create_dir_all(dir).map_err(|source| Error::Io { path: dir.display().to_string(), source })?;
    }
    if a.reference {
        return reference_cmd(&a, &st, &camera, &lights, t_setup);
    }
    let mut session = voxray::session::Session::open(a.backend)?;
    eprintln!("backend: {}", session.description());
    session.set_gi(gi)?;
    let mut gpu_times = Vec::new();
    let mut cache_times: Vec<[f64; 3]> = Vec::new();
    let mut last_plan: Option<FramePlan> = None;
    let mut gif_frames = Vec::new();
    let (mut times, mut traced, mut reused) = (Vec::new(), 0u64, 0u64);
    let todo: Vec<u32> = range.filter(|&f| !(a.resume && frame_done(&a, f, camera.width, camera.height))).collect();
    if a.frames > 1 && (a.resume || a.shard.is_some() || a.frame_range.is_some()) {
        eprintln!(
            "frames {}: {} to render{}",
            if todo.is_empty() { "none".to_string() } else { format!("{}..{}", todo[0], todo[todo.len() - 1] + 1) },
            todo.len(),
            if a.resume {
                format!(" ({} of this range already written)", frames_to_render(&a)?.len() - todo.len())
            } else {
                String::new()
            }
        );
    }
    let pb = if a.frames > 1 { bar(todo.len() as u64, "frames") } else { bar(2 * camera.height as u64, "rendering") };
    // GI's passes before the pixels can take minutes on a large volume: show which is running.
    let stage_bar = pb.clone();
    session.on_gi_stage(move |what| stage_bar.set_message(what.to_string()));
    // Only the cars some ray of a frame can reach are posed (the picture is the same): the
    // box of visible surfaces, once (the cars' reach over the clip holds wherever they go).
    let surfaces = match features.pose_seen && st.animated.is_none() && !st.cars.is_empty() {
        true => Some(st.surfaces(opts.max_level)?),
        false => None,
    };
    for &f in &todo {
        let first = Some(&f) == todo.first();
        let start = Instant::now();
        let t = a.time + f as f64 / a.fps;
        let cam = orbit(&camera, a.orbit * (t - a.time));
        let sight = surfaces.and_then(|box_| {
            let rays = voxray::scene::FrameRays::of(&st.scene, &features, session.gi().is_some(), &opts);
            voxray::scene::Sight::new(&cam, &lights, rays, box_).ok()
        });
        let stages = || -> Result<_, voxray::Error> {
            st.pose_seen(t, sight.as_ref(), opts.max_level)?;
            st.scene.update()?;
            session.frame(&st.scene, &cam, &lights, &features, &opts, &|d, _| {
                if a.frames == 1 {
                    pb.set_position(d as u64)
                }
            })
        };
        let report = voxray::pool::run_awake(stages)?;
        let plan = report.plan;
        if a.explain && last_plan.as_ref().is_none_or(|p| p.reasons != plan.reasons) {
            pb.suspend(|| eprintln!("frame {f}: {}", plan.explain()));
        }
        // The brick count is read back only for the GPU GI message, on the first frame.
        let counted = match (&report.gi, first) {
            (None, true) => session.gi_bricks()?,
            _ => None,
        };
        let frame = session.last_frame().ok_or_else(|| usage("the renderer kept no frame"))?;
        if first && frame.eye_inside_fraction() > 0.5 {
            pb.suspend(|| {
                eprintln!(
                    "warning: the eye is inside a voxel ({:.0} % of the rays hit at t = 0), so the image is one flat \
                     colour: move the camera (--camera-json) out of the geometry",
                    100.0 * frame.eye_inside_fraction()
                )
            });
        }
        let backend = session.backend();
        match (session.gi(), &report.gi, first) {
            (Some(g), Some(s), true) => pb.suspend(|| {
                eprintln!(
                    "GI: {} voxels into {} of {}³ cells; caches {:.0} ms, transform {:.0} ms, inject {:.0} ms, levels {:.0} ms, cones {:.0} ms ({} gathers for {} hits)",
                    s.voxels, s.occupied, g.res, s.caches_ms, s.transform_ms, s.inject_ms, s.levels_ms, s.cones_ms,
                    frame.gathers, frame.instance.iter().filter(|&&i| i >= 0).count()
                );
                if let Some(c) = frame.cache_stages {
                    eprintln!(
                        "GI radiance caches: {} placed; placement {:.1} ms, cache tracing {:.1} ms, convolution {:.1} ms, gathering {:.1} ms",
                        c.caches, c.placement_ms, c.tracing_ms, c.convolution_ms, c.gathering_ms
                    );
                }
                if let Some(f) = s.tail {
                    eprintln!(
                        "GI: the bounces after the {} traced, estimated as the last bounce's light × ({:.3}, {:.3}, {:.3}) (--gi-bounce-tail off: none)",
                        g.bounces, f.x, f.y, f.z
                    );
                }
                let mb = |b: u64| b as f64 / (1u64 << 20) as f64;
                eprintln!(
                    "GI volume: {:?}, {:.1} MiB of cells (dense {}³: {:.1} MiB)",
                    s.layout.unwrap_or(voxray::gi::Layout::Dense),
                    mb(s.volume_bytes),
                    g.res,
                    mb(s.dense_bytes),
                )
            }),
            (Some(g), None, true) => {
                let ms = backend.gi_pass_ms().map_or("not timed".to_string(), |ms| format!("{ms:.2} ms"));
                let volume = match backend.gi_volume() {
                    Some((voxray::gi::Layout::Sparse, pool, bytes)) => {
                        format!(
                            "sparse {}³ volume ({} bricks in a pool of {pool}, {:.1} MiB of GI buffers)",
                            g.res,
                            counted.map_or("?".to_string(), |n| n.to_string()),
                            bytes as f64 / 1048576.0
                        )
                    }
                    Some((_, _, bytes)) => {
                        format!("dense {}³ volume ({:.1} MiB of GI buffers)", g.res, bytes as f64 / 1048576.0)
                    }
                    None => format!("{}³ volume", g.res),
                };
                pb.suspend(|| {
                    eprintln!(
                        "GI on the GPU: {volume}; transform + inject + levels{} {ms} (cones are in the shade pass)",
                        if g.bounces > 1 { format!(" + {} more bounces", g.bounces - 1) } else { String::new() }
                    )
                });
            }
            _ => {}
        }
        times.push(start.elapsed().as_secs_f64());
        if let Some(t) = backend.pass_times() {
            gpu_times.push(t);
        }
        if let Some(t) = backend.cache_pass_times() {
            cache_times.push(t);
        }
        traced += frame.primary_rays - frame.reused + frame.shadow_rays;
        reused += frame.reused;
        last_plan = Some(plan);
        write_frame(&a, frame, f, is_gif, &mut gif_frames)?;
        if a.frames > 1 {
            pb.inc(1);
        }
    }
    pb.finish_and_clear();
    if is_gif {
        output::write_gif(&a.out, camera.width, camera.height, a.fps, gif_frames)?;
    } else if let (true, Some(first), Some(last)) = (a.frames > 1, todo.first(), todo.last()) {
        println!("wrote {} … {}", numbered(&a.out, *first).display(), numbered(&a.out, *last).display());
        if let Some(dir) = &a.aov_dir {
            println!(
                "wrote AOVs (t, instance, normal .npy) under {}/frame_{first:04} … frame_{last:04}",
                dir.display()
            );
        }
    }
    let total: f64 = times.iter().sum();
    let (median, p95, _) = voxray::bench::summarize(&times);
    if todo.is_empty() {
        return Ok(());
    }
    let pixels = camera.width as u64 * camera.height as u64 * todo.len() as u64;
    eprintln!(
        "timings: setup (load, voxelize, build) {:.2}s | {} frame(s) {:.3}s, median {:.1} ms, p95 {:.1} ms",
        t_setup.as_secs_f64(),
        todo.len(),
        total,
        median * 1e3,
        p95 * 1e3
    );
    if !gpu_times.is_empty() {
        let (tr, _, _) = voxray::bench::summarize(&gpu_times.iter().map(|t| t.0).collect::<Vec<_>>());
        let (sh, _, _) = voxray::bench::summarize(&gpu_times.iter().map(|t| t.1).collect::<Vec<_>>());
        eprintln!("GPU passes (timestamp queries, median): trace {tr:.2} ms, shade {sh:.2} ms");
    }
    if !cache_times.is_empty() {
        let m = |k: usize| voxray::bench::summarize(&cache_times.iter().map(|t| t[k]).collect::<Vec<_>>()).0;
        eprintln!(
            "GPU radiance-cache passes (median): placement {:.2} ms, cache tracing {:.2} ms, convolution {:.2} ms (gathering is in the shade pass)",
            m(0),
            m(1),
            m(2)
        );
    }
    eprintln!(
        "rays: {traced} traced ({:.1}% of pixels reused from the hit buffer) = {:.2} Mrays/s on {} ({}x{}, {} instances)",
        100.0 * reused as f64 / pixels as f64,
        traced as f64 / total / 1e6,
        if matches!(session.backend(), Backend::Cpu(_)) {
            format!("{} threads", rayon::current_num_threads())
        } else {
            "the GPU".into()
        },
        camera.width,
        camera.height,
        st.scene.instances().len()
    );
    Ok(())
}

/// `voxray render --reference`: path-traces the first frame, writing the estimate so far each
/// time another tenth of the samples is done (stop it early and the image is still there).
pub(crate) fn reference_cmd(
    a: &RenderArgs,
    st: &Staged,
    camera: &Camera,
    lights: &Lights,
    t_setup: std::time::Duration,
) -> Result<(), Error> {
    if a.frames > 1 {
        return Err(usage("--reference renders one frame; drop --frames"));
    }
    let settings = voxray::gi::ReferenceSettings { spp: a.spp, bounces: a.bounces, seed: 1 };
    let start = Instant::now();
    let mut pt = if a.reference_geometry == "triangles" {
        let mut mesh = load_mesh(&a.source)?;
        if a.static_car {
            let merged: Vec<_> = mesh.parts.iter().flat_map(|p| p.triangles.iter().copied()).collect();
            mesh.parts = vec![Part { name: "car (static)".into(), triangles: merged }];
        }
        voxray::gi::PathTracer::on_triangles(&st.scene, &mesh, camera, lights, settings)
    } else {
        voxray::gi::PathTracer::new(&st.scene, camera, lights, settings)
    }
    .map_err(|e| match e {
        voxray::gi::ReferenceError::Triangles(t) => usage(&format!("{t}: with the default car, add --no-ground")),
        e => usage(&e.to_string()),
    })?;
    let pb = bar(a.spp as u64, "samples per pixel");
    let checkpoint = a.spp.div_ceil(10);
    while pt.samples() < a.spp {
        pt.pass();
        pb.set_position(pt.samples() as u64);
        if pt.samples() % checkpoint == 0 || pt.samples() == a.spp {
            output::write_image(&pt.frame(), &a.out)?;
        }
    }
    pb.finish_and_clear();
    let secs = start.elapsed().as_secs_f64();
    eprintln!("wrote {} ({} samples per pixel)", a.out.display(), pt.samples());
    eprintln!(
        "timings: setup (load, voxelize, build) {:.2}s | path tracing {:.2}s, {} rays = {:.2} Mrays/s",
        t_setup.as_secs_f64(),
        secs,
        pt.rays(),
        pt.rays() as f64 / secs / 1e6
    );
    Ok(())
}

pub(crate) fn write_frame(
    a: &RenderArgs,
    frame: &Frame,
    f: u32,
    is_gif: bool,
    gif: &mut Vec<Vec<u8>>,
) -> Result<(), Error> {
    if is_gif {
        gif.push(output::srgb8(frame));
    } else {
        let path = if a.frames > 1 { numbered(&a.out, f) } else { a.out.clone() };
        output::write_image(frame, &path)?;
        if a.frames == 1 {
            println!("wrote {}", path.display());
        }
    }
    if let Some(dir) = &a.aov_dir {
        let d = if a.frames > 1 { dir.join(format!("frame_{f:04}")) } else { dir.clone() };
        output::write_aovs(frame, &d)?;
        if a.frames == 1 {
            println!(
                "wrote AOVs (t, instance, normal{} .npy) under {}",
                if frame.ao.is_empty() { "" } else { ", ao" },
                dir.display()
            );
        }
    }
    Ok(())
}
