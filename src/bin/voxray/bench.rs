//! `voxray bench`: the frame-time harness's scenarios, records, tables and charts.

use super::*;

/// The GPU for a GI scenario's GPU rows: on `--backends gpu`, and on `auto` where the adapter
/// is hardware (as `Backend::open` decides); None (saying why where it failed) otherwise.
#[cfg(feature = "gpu")]
pub(crate) fn bench_gpu(
    backends: &[voxray::backend::BackendKind],
    pb: &ProgressBar,
    scenario: &str,
) -> Option<std::sync::Arc<voxray::gpu::GpuContext>> {
    use voxray::backend::BackendKind;
    match voxray::gpu::GpuContext::headless() {
        Ok(ctx) if backends.contains(&BackendKind::Gpu) || ctx.info.device_type != wgpu::DeviceType::Cpu => {
            Some(std::sync::Arc::new(ctx))
        }
        Ok(_) => None,
        Err(e) => {
            pb.suspend(|| eprintln!("skipping GPU {scenario}: {e}"));
            None
        }
    }
}

pub(crate) fn bench_cmd(a: BenchArgs) -> Result<(), Error> {
    use voxray::bench::matrix::{self, CarModel, MatrixConfig, Scenario};
    use voxray::bench::{machine, Record};
    if a.report_only {
        return write_records(&a, Vec::new());
    }
    let command = std::env::args()
        .enumerate()
        .map(|(i, s)| if i == 0 { "voxray".to_string() } else { s })
        .collect::<Vec<_>>()
        .join(" ");
    let mut scenarios = Vec::new();
    let (mut peers, mut gi_scaling, mut gi_accuracy, mut gi_volume) = (false, false, false, false);
    for s in &a.scenarios {
        if s.eq_ignore_ascii_case("peers") {
            peers = true;
        } else if s.eq_ignore_ascii_case("gi-scaling") {
            gi_scaling = true;
        } else if s.eq_ignore_ascii_case("gi-accuracy") {
            gi_accuracy = true;
        } else if s.eq_ignore_ascii_case("gi-volume") {
            gi_volume = true;
        } else {
            scenarios.push(s.parse::<Scenario>().map_err(|e| usage(&e))?);
        }
    }
    let on_file = !a.source.scene.is_empty();
    // A scene file with triangles (OBJ, glTF) gets the paper comparison and the peers against
    // its triangles merged at time 0; a .vox or .svo file has none to merge.
    let file_triangles = on_file
        && a.source.scene.iter().all(|p| SceneKind::of(p).is_ok_and(|k| matches!(k, SceneKind::Obj | SceneKind::Gltf)));
    if on_file {
        let mut skipped: Vec<String> = Vec::new();
        let mut skip = |what: &str, on: &mut bool| {
            if *on {
                skipped.push(what.to_string());
                *on = false;
            }
        };
        // Built around the default car: its figure-eights and the GI test scenes.
        let mut instances = scenarios.contains(&Scenario::Instances);
        skip("instances", &mut instances);
        let mut splat = scenarios.contains(&Scenario::Splat);
        skip("splat", &mut splat);
        let mut cast = scenarios.contains(&Scenario::Cast);
        skip("cast", &mut cast);
        let mut paper = scenarios.contains(&Scenario::Paper);
        if !file_triangles {
            skip("paper", &mut paper);
            skip("peers", &mut peers);
        }
        skip("gi-scaling", &mut gi_scaling);
        skip("gi-accuracy", &mut gi_accuracy);
        skip("gi-volume", &mut gi_volume);
        scenarios.retain(|s| matches!(s, Scenario::Resolution | Scenario::Depth) || (*s == Scenario::Paper && paper));
        if !skipped.is_empty() {
            eprintln!(
                "note: skipping {} on a scene file (the instance and splat sweeps, the caster's rays and the GI scenarios are built around the default car; the paper comparison and the peers need triangles)",
                skipped.join(", ")
            );
        }
        if scenarios.is_empty() && !peers {
            return Err(usage("--scene: choose --scenarios among paper, resolution, depth, peers"));
        }
    }
    if peers && !cfg!(feature = "peers") {
        return Err(usage(
            "the peers scenario needs a build with `--features peers` (and Debian's libembree-dev for Embree)",
        ));
    }
    let resolutions = a
        .resolutions
        .iter()
        .map(|r| {
            let (w, h) = r.split_once(['x', '×']).ok_or_else(|| usage(&format!("resolution '{r}' is not WxH")))?;
            let p = |v: &str| v.trim().parse::<u32>().ok().filter(|&v| (1..=16384).contains(&v));
            match (p(w), p(h)) {
                (Some(w), Some(h)) => Ok((w, h)),
                _ => Err(usage(&format!("resolution '{r}': width and height must be 1…16384"))),
            }
        })
        .collect::<Result<Vec<_>, Error>>()?;
    for (w, h) in [(a.width, a.height), (a.sweep_width, a.sweep_height)] {
        if !(1..=16384).contains(&w) || !(1..=16384).contains(&h) {
            return Err(usage("image sizes must be 1…16384"));
        }
    }
    // The largest frame any scenario renders, before anything is built.
    let sizes = resolutions.iter().copied().chain([(a.width, a.height), (a.sweep_width, a.sweep_height)]);
    if let Some((w, h)) = sizes.max_by_key(|&(w, h)| w as u64 * h as u64) {
        voxray::memory::check(
            &format!("benchmark frames of {w}×{h}"),
            w as u64 * h as u64 * voxray::memory::FRAME_BYTES_PER_PIXEL,
            "lower --width/--height or --resolutions, or raise --memory-budget",
        )?;
    }
    if let Some(&n) = a.sweep_cars.iter().find(|&&n| n == 0 || n > 100_000) {
        return Err(usage(&format!("--sweep-cars {n}: car counts must be 1…100000")));
    }
    if let Some(&n) = a.gi_cars.iter().find(|&&n| n == 0 || n > 100_000) {
        return Err(usage(&format!("--gi-cars {n}: car counts must be 1…100000")));
    }
    if !(a.gi_res.is_power_of_two() && (1..=voxray::gi::volume::MAX_DENSE_RES).contains(&a.gi_res)) {
        return Err(usage(&format!(
            "--gi-res {}: the GI scenarios' volume needs a power of two from 1 to {} cells per side",
            a.gi_res,
            voxray::gi::volume::MAX_DENSE_RES
        )));
    }
    if let Some(&l) = a.lod_levels.iter().find(|&&l| l == 0 || l > voxray::svo::MAX_DEPTH) {
        return Err(usage(&format!(
            "--lod-levels {l}: levels must be 1…{} (and below the parts' depth)",
            voxray::svo::MAX_DEPTH
        )));
    }
    let cfg = MatrixConfig {
        scenarios,
        warmup: a.warmup,
        frames: a.frames as usize,
        size: (a.width, a.height),
        cars: a.sweep_cars.clone(),
        sweep_frames: a.sweep_frames as usize,
        sweep_size: (a.sweep_width, a.sweep_height),
        crowd_on_gpu: a.crowd_posing == super::args::CrowdPosing::Gpu,
        resolutions,
        lod_levels: a.lod_levels.clone(),
        command: command.clone(),
        machine: machine(),
    };
    // The car: its parts, and all of it merged into one SVO for the static baseline; or the
    // scene file, staged with its animation.
    let mut staged = if on_file { Some(stage(&a.source, 1, false, false, false)?) } else { None };
    let mesh = if on_file { Mesh::default() } else { load_mesh(&a.source)? };
    // The file's triangles where its instances stand at time 0, as one part.
    let file_mesh = match (&staged, file_triangles) {
        (Some(st), true) => {
            let parts = load_mesh(&a.source)?;
            let mut merged: Vec<voxray::mesh::Triangle> = Vec::new();
            for (i, inst) in st.scene.instances().iter().enumerate() {
                let w = st.scene.world(i);
                for t in parts.parts.get(inst.part).map_or(&[][..], |p| &p.triangles[..]) {
                    let positions = t.positions.map(|p| w.transform_point3(p.as_dvec3()).as_vec3());
                    merged.push(voxray::mesh::Triangle { positions, ..*t });
                }
            }
            let mut m = parts.clone();
            m.parts = vec![Part { name: "scene (static)".into(), triangles: merged }];
            Some(m)
        }
        _ => None,
    };
    let file_merged = match (&file_mesh, cfg.scenarios.contains(&Scenario::Paper) || peers) {
        (Some(m), true) => Some(build_parts(m, &a.source)?.remove(0)),
        _ => None,
    };
    let car = if on_file {
        None
    } else {
        let parts = build_parts(&mesh, &a.source)?;
        let mut merged_mesh = mesh.clone();
        let all: Vec<_> = mesh.parts.iter().flat_map(|p| p.triangles.iter().copied()).collect();
        merged_mesh.parts = vec![Part { name: "car (static)".into(), triangles: all }];
        let merged = build_parts(&merged_mesh, &a.source)?.remove(0);
        Some(CarModel { parts, merged })
    };
    let the_car = || car.as_ref().ok_or_else(|| usage("this scenario needs the default car"));
    let depth = match &staged {
        Some(st) => st.scene.parts.iter().map(|p| p.depth).max().unwrap_or(0),
        None => the_car()?.parts.iter().map(|p| p.depth).max().unwrap_or(0),
    };
    if let Some(&l) = a.lod_levels.iter().find(|&&l| l >= depth && cfg.scenarios.contains(&Scenario::Depth)) {
        return Err(usage(&format!(
            "--lod-levels {l}: the parts are {depth} levels deep, so a level of detail must be 1…{}",
            depth.saturating_sub(1)
        )));
    }

    let mut records: Vec<Record> = Vec::new();
    let mut kinds = a.backends.clone();
    kinds.dedup();
    let pb = bar(
        (cfg.steps() * kinds.len()) as u64
            + if peers { 4 } else { 0 }
            + gi_scaling as u64
            + gi_accuracy as u64
            + gi_volume as u64,
        "measurements",
    );
    for kind in kinds {
        let mut session = match voxray::session::Session::open(kind) {
            Ok(s) => s,
            Err(e) => {
                pb.suspend(|| eprintln!("skipping backend {kind:?}: {e}"));
                pb.inc(cfg.steps() as u64);
                continue;
            }
        };
        let name = session.description().to_string();
        pb.suspend(|| eprintln!("backend: {name}"));
        let mut progress = |what: &str| {
            pb.set_message(what.to_string());
            pb.inc(1);
        };
        let mut subject = match staged.as_mut() {
            Some(st) => {
                let file = a.source.scene[0].file_name().map_or_else(String::new, |f| f.to_string_lossy().into_owned());
                matrix::Subject::File { staged: st, name: file, merged: file_merged.clone() }
            }
            None => matrix::Subject::Car(the_car()?),
        };
        records.extend(matrix::run(&cfg, &mut subject, &mut session, &name, &mut progress)?);
    }
    #[cfg(feature = "peers")]
    if peers {
        pb.set_message("peers: building the views");
        // The car (or the scene file's triangles, merged where they stand at time 0).
        let source_mesh = file_mesh.as_ref().unwrap_or(&mesh);
        let car_triangles: Vec<[glam::Vec3; 3]> =
            source_mesh.parts.iter().flat_map(|p| p.triangles.iter().map(|t| t.positions)).collect();
        let merged_svo = match &file_merged {
            Some(m) => m.clone(),
            None => the_car()?.merged.clone(),
        };
        let scene = matrix::static_scene(merged_svo.clone())?;
        let (lo, hi) = scene.bounds();
        let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), a.width, a.height);
        // Close up: the same direction, near enough that the model covers most pixels.
        let close = Camera { eye: camera.target + (camera.eye - camera.target) * 0.4, ..camera };
        let mut views = vec![
            voxray::bench::peers::PeerView {
                name: "default".into(),
                triangles: &car_triangles,
                svo: merged_svo.clone(),
                camera,
                whole_frame: true,
            },
            voxray::bench::peers::PeerView {
                name: "close-up".into(),
                triangles: &car_triangles,
                svo: merged_svo.clone(),
                camera: close,
                whole_frame: false,
            },
        ];
        // The car's body alone, voxelized 2^11 along its longest side.
        let body_triangles: Vec<[glam::Vec3; 3]>;
        if !on_file {
            let body_index = mesh.parts.iter().position(|p| p.name == "body").unwrap_or(0);
            let mut body_mesh = mesh.clone();
            body_mesh.parts = vec![mesh.parts[body_index].clone()];
            let body_source = SourceArgs { depth: 11, voxel_size: None, ..a.source.clone() };
            let body = build_parts(&body_mesh, &body_source)?.remove(0);
            body_triangles = body_mesh.parts[0].triangles.iter().map(|t| t.positions).collect();
            let (blo, bhi) = matrix::static_scene(body.clone())?.bounds();
            let body_camera = Camera::framing(blo.as_vec3(), bhi.as_vec3(), a.width, a.height);
            views.push(voxray::bench::peers::PeerView {
                name: format!("body at depth {}", body.depth),
                triangles: &body_triangles,
                svo: body,
                camera: body_camera,
                whole_frame: false,
            });
        }
        let mut threads = vec![1, rayon::current_num_threads()];
        threads.dedup();
        let input = voxray::bench::peers::PeerScene {
            views,
            threads,
            warmup: a.warmup,
            frames: a.frames as usize,
            command: command.clone(),
            machine: cfg.machine.clone(),
        };
        let mut peer_records = voxray::bench::peers::run(&input, &mut |w| pb.set_message(w.to_string()))?;
        if on_file {
            let file = a.source.scene[0].file_name().map_or_else(String::new, |f| f.to_string_lossy().into_owned());
            for r in &mut peer_records {
                r.group = "scene-peers".into();
                r.setting = format!("{file}: {}", r.setting);
            }
        }
        records.extend(peer_records);
        pb.inc(4);
    }
    if gi_scaling {
        let sc = voxray::bench::gi::ScalingConfig {
            cars: a.gi_cars.clone(),
            res: a.gi_res,
            repeats: a.gi_repeats as usize,
            command: command.clone(),
            machine: cfg.machine.clone(),
        };
        use voxray::backend::BackendKind;
        // The CPU reference for cpu and auto; the GPU passes for gpu, and for auto on a
        // hardware adapter (as Backend::open decides).
        if a.backends.iter().any(|k| *k != BackendKind::Gpu) {
            records.extend(voxray::bench::gi::scaling(&sc, &mesh, &the_car()?.parts, &mut |w| {
                pb.set_message(w.to_string())
            })?);
        }
        #[cfg(feature = "gpu")]
        if a.backends.iter().any(|k| *k != BackendKind::Cpu) {
            if let Some(ctx) = bench_gpu(&a.backends, &pb, "gi-scaling") {
                records.extend(voxray::bench::gi::scaling_gpu(&sc, &mesh, &the_car()?.parts, ctx, &mut |w| {
                    pb.set_message(w.to_string())
                })?);
            }
        }
        pb.inc(1);
    }
    if gi_volume {
        let lc = voxray::bench::gi::LayoutConfig {
            size: (160, 120),
            resolutions: vec![64, 128, 256, 512, 1024],
            repeats: a.gi_repeats as usize,
            command: command.clone(),
            machine: cfg.machine.clone(),
        };
        use voxray::backend::BackendKind;
        // As gi-scaling: the CPU for cpu and auto, the GPU for gpu and auto on a hardware adapter.
        if a.backends.iter().any(|k| *k != BackendKind::Gpu) {
            records.extend(voxray::bench::gi::layouts(&lc, &mut |w| pb.set_message(w.to_string()))?);
        }
        #[cfg(feature = "gpu")]
        if a.backends.iter().any(|k| *k != BackendKind::Cpu) {
            if let Some(ctx) = bench_gpu(&a.backends, &pb, "gi-volume") {
                let mut say = |w: &str| {
                    if w.contains("left out") {
                        pb.suspend(|| eprintln!("{w}"));
                    } else {
                        pb.set_message(w.to_string());
                    }
                };
                records.extend(voxray::bench::gi::layouts_gpu(&lc, ctx, &mut say)?);
            }
        }
        pb.inc(1);
    }
    if gi_accuracy {
        let (w, h) = a
            .accuracy_size
            .split_once(['x', '×'])
            .and_then(|(w, h)| Some((w.trim().parse::<u32>().ok()?, h.trim().parse::<u32>().ok()?)))
            .filter(|&(w, h)| (1..=4096).contains(&w) && (1..=4096).contains(&h))
            .ok_or_else(|| usage(&format!("--accuracy-size '{}' must be WxH, each 1…4096", a.accuracy_size)))?;
        let ac = voxray::bench::gi::AccuracyConfig {
            size: (w, h),
            depth: 8,
            spp: a.spp,
            repeats: a.gi_repeats as usize,
            resolutions: vec![32, 64, 128, 256],
            cones: vec![1, 3, 6, 9, 16],
            bounces: vec![1, 2, 3],
            command: command.clone(),
            machine: cfg.machine.clone(),
        };
        use voxray::backend::BackendKind;
        // As gi-scaling: the CPU sweep for cpu and auto, the GPU's own knob for gpu and auto on
        // a hardware adapter.
        if a.backends.iter().any(|k| *k != BackendKind::Gpu) {
            records.extend(voxray::bench::gi::accuracy(&ac, &mut |w| pb.set_message(w.to_string()))?);
            records.extend(voxray::bench::gi::flicker(&ac, &mut |w| pb.set_message(w.to_string()))?);
        }
        #[cfg(feature = "gpu")]
        if a.backends.iter().any(|k| *k != BackendKind::Cpu) {
            if let Some(ctx) = bench_gpu(&a.backends, &pb, "gi-accuracy") {
                records.extend(voxray::bench::gi::accuracy_gpu(&ac, ctx, &mut |w| pb.set_message(w.to_string()))?);
            }
        }
        pb.inc(1);
    }
    pb.finish_and_clear();

    write_records(&a, records)
}

/// Merges `records` with the earlier ones in `--out-dir`, then writes the JSON, the CSV, the
/// charts and the Markdown sections.
pub(crate) fn write_records(a: &BenchArgs, records: Vec<voxray::bench::Record>) -> Result<(), Error> {
    use voxray::bench::{report, Record};
    // Merge with earlier records, then JSON, CSV, charts and the Markdown section.
    let json_path = a.out_dir.join("bench.json");
    let old: Vec<Record> = if a.fresh {
        Vec::new()
    } else {
        match std::fs::read_to_string(&json_path) {
            Ok(text) => serde_json::from_str(&text).map_err(|e| with_path(&json_path, e))?,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
            Err(source) => return Err(Error::Io { path: json_path.display().to_string(), source }),
        }
    };
    let all = report::merge(old, &records);
    let write = |p: &Path, text: &str| -> Result<(), Error> {
        if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|source| Error::Io { path: dir.display().to_string(), source })?;
        }
        output::write_file(p, text.as_bytes()).map_err(|source| Error::Io { path: p.display().to_string(), source })
    };
    let json = serde_json::to_string_pretty(&all).map_err(|e| with_path(&json_path, e))?;
    write(&json_path, &json)?;
    let csv_path = a.out_dir.join("bench.csv");
    write(&csv_path, &report::to_csv(&all))?;
    let charts_dir = match &a.charts_dir {
        Some(dir) => dir.clone(),
        None if a.no_docs => a.out_dir.clone(),
        None => PathBuf::from("docs/images"),
    };
    let charts = voxray::bench::chart::draw_all(&all, &charts_dir).map_err(|e| usage(&e.to_string()))?;
    // Chart links relative to the Markdown file's folder.
    let doc_dir = a.docs.parent().map(Path::to_path_buf).unwrap_or_default();
    let rel = relative(&doc_dir, &charts_dir);
    let links: Vec<(String, String)> =
        charts.iter().map(|(g, f)| (g.clone(), rel.join(f).to_string_lossy().replace('\\', "/"))).collect();
    let md = report::markdown(&all, &links);
    println!("{}", report::markdown(&records, &[]));
    // A scene file's sweeps have no section of the docs: a table of them here.
    let file_rows: Vec<&Record> = records.iter().filter(|r| r.group.starts_with("scene-")).collect();
    if !file_rows.is_empty() {
        println!("| measurement | backend | median ms | p95 ms | Mrays/s | reused |");
        println!("|---|---|---|---|---|---|");
        for r in file_rows {
            let name = if r.group == "scene-peers" { format!("{} ({})", r.name, r.setting) } else { r.name.clone() };
            println!(
                "| {} | {} | {:.2} | {:.2} | {:.2} | {:.1}% |",
                name,
                r.backend,
                r.median_ms,
                r.p95_ms,
                r.mrays_per_s,
                100.0 * r.reused_fraction
            );
        }
    }
    println!("wrote {} and {} ({} records)", json_path.display(), csv_path.display(), all.len());
    for (_, f) in &charts {
        println!("wrote {}", charts_dir.join(f).display());
    }
    // A scene file's records change no section of the docs.
    if !a.no_docs && a.source.scene.is_empty() {
        let doc = match std::fs::read_to_string(&a.docs) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => "# Benchmarks\n".to_string(),
            Err(source) => return Err(Error::Io { path: a.docs.display().to_string(), source }),
        };
        write(&a.docs, &report::splice(&doc, &md))?;
        println!("regenerated {}", a.docs.display());
        if all.iter().any(|r| r.group == "gi-accuracy") {
            let acc_dir = a.accuracy_docs.parent().map(Path::to_path_buf).unwrap_or_default();
            let rel = relative(&acc_dir, &charts_dir);
            let links: Vec<(String, String)> =
                charts.iter().map(|(g, f)| (g.clone(), rel.join(f).to_string_lossy().replace('\\', "/"))).collect();
            let doc = match std::fs::read_to_string(&a.accuracy_docs) {
                Ok(t) => t,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => "# GI accuracy\n".to_string(),
                Err(source) => return Err(Error::Io { path: a.accuracy_docs.display().to_string(), source }),
            };
            write(&a.accuracy_docs, &report::splice(&doc, &report::accuracy_markdown(&all, &links)))?;
            println!("regenerated {}", a.accuracy_docs.display());
        }
    }
    Ok(())
}
