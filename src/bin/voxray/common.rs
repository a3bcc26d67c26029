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

pub(crate) fn load_mesh(src: &SourceArgs) -> Result<Mesh, Error> {
    let mut mesh = if src.obj.is_empty() {
        voxray::model::embedded::load_default_car()?
    } else {
        let mut m = Mesh::default();
        for p in &src.obj {
            m.append(voxray::mesh::load_obj(p)?);
        }
        m
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
    Ok(mesh)
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
    let default_car = src.obj.is_empty();
    if !default_car && (cars > 1 || static_car || in_place) {
        return Err(usage("--cars, --in-place and --static-car apply to the default car only"));
    }
    let mut mesh = load_mesh(src)?;
    if default_car && !static_car {
        let parts = build_parts(&mesh, src)?;
        return stage_cars(&parts, cars as usize, !in_place, with_ground);
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
    Ok(Staged { scene, cars: Vec::new(), bounds })
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
