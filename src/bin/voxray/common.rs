//! What several subcommands share: loading and voxelizing the model, staging the scene,
//! progress bars and error helpers.

use super::*;

pub(crate) fn bar(len: u64, what: &str) -> ProgressBar {
    let b = ProgressBar::new(len);
    b.set_style(
        ProgressStyle::with_template("{msg:>24} [{bar:40}] {pos}/{len} ({eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    b.set_message(what.to_string());
    b
}

/// The model's triangles and, for a glTF scene, its node hierarchy and animation.
pub(crate) fn load_input(src: &SourceArgs) -> Result<(Mesh, Option<Rig>), Error> {
    let kinds = src.scene.iter().map(|p| SceneKind::of(p)).collect::<Result<Vec<_>, _>>()?;
    if let Some(k) = kinds.iter().position(|k| matches!(k, SceneKind::Svo | SceneKind::Vox)) {
        return Err(usage(&format!(
            "{}: an .svo or .vox file holds voxels, not triangles: give it alone to render, demo or bench (it cannot be voxelized or path-traced as triangles)",
            src.scene[k].display()
        )));
    }
    if src.animation.is_some() && !kinds.contains(&SceneKind::Gltf) {
        return Err(usage("--animation chooses among a glTF or .vox scene's animations; give one with --scene"));
    }
    let (mut mesh, rig) = if src.scene.is_empty() {
        (voxray::model::embedded::load_default_car()?, None)
    } else if kinds.contains(&SceneKind::Gltf) {
        if src.scene.len() > 1 {
            return Err(usage("a glTF scene is given alone (its nodes place its meshes)"));
        }
        let start = Instant::now();
        let imported = voxray::import::load_gltf(&src.scene[0])?;
        eprintln!(
            "loaded {}: {} meshes, {} triangles, {} nodes, {} animations in {:.2}s",
            src.scene[0].display(),
            imported.mesh.parts.len(),
            imported.mesh.triangle_count(),
            imported.rig.nodes.len(),
            imported.rig.clips.len(),
            start.elapsed().as_secs_f64()
        );
        (imported.mesh, Some(imported.rig))
    } else {
        let mut m = Mesh::default();
        for p in &src.scene {
            m.append(voxray::mesh::load_obj(p)?);
        }
        (m, None)
    };
    if src.lambertian {
        mesh.make_lambertian();
    }
    for w in &mesh.warnings {
        eprintln!("warning: {w}");
    }
    if mesh.degenerate_skipped > 0 {
        eprintln!("note: skipped {} degenerate triangles", mesh.degenerate_skipped);
    }
    Ok((mesh, rig))
}

/// The model's triangles (a glTF scene's meshes, unplaced).
pub(crate) fn load_mesh(src: &SourceArgs) -> Result<Mesh, Error> {
    Ok(load_input(src)?.0)
}

/// The clip `--animation` names (default: the first; `none`: the rest pose; `all`: every
/// animation of the file played together, added to the rig as one more clip).
fn chosen_clip(rig: &mut Rig, which: Option<&str>) -> Result<Option<usize>, Error> {
    match which {
        None => Ok((!rig.clips.is_empty()).then_some(0)),
        Some(w) if w.eq_ignore_ascii_case("none") => Ok(None),
        Some(w) if w.eq_ignore_ascii_case("all") && rig.find_clip(w).is_none() => {
            let channels = rig.clips.iter().flat_map(|c| c.channels.clone()).collect();
            rig.clips.push(voxray::scene::animation::Clip::new("all".into(), channels));
            Ok(Some(rig.clips.len() - 1))
        }
        Some(w) => rig.find_clip(w).map(Some).ok_or_else(|| {
            let names: Vec<String> = rig.clips.iter().enumerate().map(|(i, c)| format!("{i}: '{}'", c.name)).collect();
            usage(&format!(
                "--animation {w}: no such animation (the file has {})",
                if names.is_empty() { "none".to_string() } else { names.join(", ") }
            ))
        }),
    }
}

/// Voxelizes and builds every part, printing a statistics table.
pub(crate) fn build_parts(mesh: &Mesh, src: &SourceArgs) -> Result<Vec<Arc<Svo>>, Error> {
    let res = match src.voxel_size {
        Some(v) => Resolution::VoxelSize(v),
        None => Resolution::Depth(src.depth),
    };
    let opts = VoxelizeOptions { resolution: shared_resolution(mesh, res)?, solid: src.solid };
    if let Some(v) = src.voxel_size {
        // Not an error (a blocky stand-in can be wanted), but rarely what was meant.
        for p in &mesh.parts {
            let corners = p.triangles.iter().flat_map(|t| t.positions);
            let (lo, hi) =
                corners.fold((glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY), |(lo, hi), c| (lo.min(c), hi.max(c)));
            let extent = (hi.as_dvec3() - lo.as_dvec3()).max_element();
            if v as f64 > extent {
                eprintln!(
                    "warning: --voxel-size {v} is larger than part '{}' ({extent} across): it becomes a few voxels of {v}",
                    p.name
                );
            }
        }
    }
    let cache = if src.no_cache {
        None
    } else {
        src.cache_dir.clone().or_else(SvoCache::default_dir).map(|dir| SvoCache { dir })
    };
    eprintln!(
        "{:<16} {:>9} {:>6} {:>10} {:>9} {:>9} {:>9} {:>8}",
        "part", "triangles", "depth", "voxels", "nodes", "geom B/v", "attr B/v", "time"
    );
    let mut out = Vec::new();
    for (i, part) in mesh.parts.iter().enumerate() {
        let pb = bar(part.triangles.len() as u64, &part.name);
        let built = build_part(mesh, i, &opts, cache.as_ref(), &|d, _| pb.set_position(d as u64))?;
        pb.finish_and_clear();
        if let Some(w) = &built.cache_warning {
            eprintln!("warning: {w}");
        }
        let s = built.svo.stats();
        let time = if built.cached {
            "cached".to_string()
        } else {
            format!("{:.2}s", (built.voxelize + built.build).as_secs_f64())
        };
        eprintln!(
            "{:<16} {:>9} {:>6} {:>10} {:>9} {:>9.2} {:>9.2} {:>8}",
            part.name,
            part.triangles.len(),
            s.depth,
            s.voxels,
            s.nodes,
            s.geometry_bytes_per_voxel(),
            s.attribute_bytes_per_voxel(),
            time
        );
        out.push(Arc::new(built.svo));
    }
    Ok(out)
}

pub(crate) fn read_text(p: &Path) -> Result<String, Error> {
    Ok(voxray::input::read_text_limited(p, voxray::input::MAX_JSON_BYTES, "a JSON input")?)
}

/// Loads the parts and places them: the default car animated (or merged into one static SVO),
/// or the given OBJ parts at the identity.
pub(crate) fn stage(
    src: &SourceArgs,
    cars: u32,
    in_place: bool,
    static_car: bool,
    with_ground: bool,
) -> Result<Staged, Error> {
    let default_car = src.scene.is_empty();
    if !default_car && (cars > 1 || static_car || in_place) {
        return Err(usage("--cars, --in-place and --static-car apply to the default car only"));
    }
    if let [file] = &src.scene[..] {
        let kind = SceneKind::of(file)?;
        if kind == SceneKind::Vox {
            return stage_vox(file, src);
        }
        if kind == SceneKind::Svo {
            let svo = voxray::svo::io::load(file)?;
            let mut scene = Scene::new(vec![Arc::new(svo)]);
            scene.add(Instance { part: 0, parent: None, local: Transform::IDENTITY })?;
            scene.update()?;
            let bounds = scene.bounds();
            return Ok(Staged::new(scene, Vec::new(), bounds, None));
        }
    }
    let (mut mesh, rig) = load_input(src)?;
    if default_car && !static_car {
        let parts = build_parts(&mesh, src)?;
        return stage_cars(&parts, cars as usize, !in_place, with_ground);
    }
    if let Some(mut rig) = rig {
        let clip = chosen_clip(&mut rig, src.animation.as_deref())?;
        let mut scene = Scene::new(build_parts(&mesh, src)?);
        rig.instantiate(&mut scene, 0, clip)?;
        scene.update()?;
        let bounds = rig.clip_bounds(&mut scene, clip)?;
        if let Some(c) = clip {
            let c = &rig.clips[c];
            eprintln!("animation '{}': {:.2} s, {} channels, looping", c.name, c.duration, c.channels.len());
        }
        return Ok(Staged::new(scene, Vec::new(), bounds, Some(Animated { rig, clip })));
    }
    if static_car {
        let merged: Vec<_> = mesh.parts.iter().flat_map(|p| p.triangles.iter().copied()).collect();
        mesh.parts = vec![Part { name: "car (static)".into(), triangles: merged }];
    }
    let mut scene = Scene::new(build_parts(&mesh, src)?);
    for part in 0..scene.parts.len() {
        scene.add(Instance { part, parent: None, local: Transform::IDENTITY })?;
    }
    scene.update()?;
    let bounds = scene.bounds();
    if default_car && with_ground {
        add_ground(&mut scene, bounds)?;
    }
    Ok(Staged::new(scene, Vec::new(), bounds, None))
}

/// A MagicaVoxel scene: its models as parts (no voxelization), placed and animated by its
/// scene graph.
fn stage_vox(file: &Path, src: &SourceArgs) -> Result<Staged, Error> {
    let start = Instant::now();
    let pb = bar(1, "models");
    let v = voxray::import::load_vox_with_progress(file, &|done, all| {
        pb.set_length(all as u64);
        pb.set_position(done as u64);
    })?;
    pb.finish_and_clear();
    let voxels: u64 = v.svos.iter().map(|s| s.voxel_count).sum();
    eprintln!(
        "loaded {}: {} models, {voxels} voxels, SVOs built in {:.2}s",
        file.display(),
        v.svos.len(),
        start.elapsed().as_secs_f64()
    );
    for w in &v.warnings {
        eprintln!("warning: {w}");
    }
    eprintln!("{:<16} {:>6} {:>10} {:>9} {:>9} {:>9}", "model", "depth", "voxels", "nodes", "geom B/v", "attr B/v");
    for (name, svo) in v.names.iter().zip(&v.svos) {
        let s = svo.stats();
        eprintln!(
            "{:<16} {:>6} {:>10} {:>9} {:>9.2} {:>9.2}",
            name,
            s.depth,
            s.voxels,
            s.nodes,
            s.geometry_bytes_per_voxel(),
            s.attribute_bytes_per_voxel()
        );
    }
    let mut rig = v.rig;
    let clip = chosen_clip(&mut rig, src.animation.as_deref())?;
    let mut scene = Scene::new(v.svos.into_iter().map(Arc::new).collect());
    rig.instantiate(&mut scene, 0, clip)?;
    scene.update()?;
    let bounds = rig.clip_bounds(&mut scene, clip)?;
    Ok(Staged::new(scene, Vec::new(), bounds, Some(Animated { rig, clip })))
}

pub(crate) fn usage(msg: &str) -> Error {
    Error::Io {
        path: "arguments".into(),
        source: std::io::Error::new(std::io::ErrorKind::InvalidInput, msg.to_string()),
    }
}

/// `to` relative to `from` when both are relative paths under the same root (e.g. docs and
/// docs/images → images); otherwise `to` as given.
pub(crate) fn relative(from: &Path, to: &Path) -> PathBuf {
    match to.strip_prefix(from) {
        Ok(r) => r.to_path_buf(),
        Err(_) if from.is_relative() && to.is_relative() => {
            let ups = from.components().count();
            let mut p = PathBuf::new();
            for _ in 0..ups {
                p.push("..");
            }
            p.join(to)
        }
        Err(_) => to.to_path_buf(),
    }
}

pub(crate) fn with_path<E: std::fmt::Display>(p: &Path, e: E) -> Error {
    Error::Io {
        path: p.display().to_string(),
        source: std::io::Error::new(std::io::ErrorKind::InvalidData, e.to_string()),
    }
}
