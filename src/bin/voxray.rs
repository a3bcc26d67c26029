//! `voxray`: render, voxelize, inspect and test sparse voxel octrees from the command line.
//! With no subcommand it renders the embedded default car to `voxray.png`.

use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;
use voxray::cache::SvoCache;
use voxray::mesh::Mesh;
use voxray::pipeline::{build_part, shared_resolution};
use voxray::render::{output, render, RenderOptions};
use voxray::scene::{Camera, Lights};
use voxray::svo::Svo;
use voxray::voxelize::{Resolution, VoxelizeOptions};
use voxray::Error;

#[derive(Parser)]
#[command(
    name = "voxray",
    version,
    about = "Ray tracing of sparse voxel octrees (Laine–Karras SVOs, Revelles traversal)."
)]
#[command(long_about = "Ray tracing of sparse voxel octrees. With no subcommand, renders the embedded default car \
to voxray.png (the same as `voxray render`).")]
struct Cli {
    #[command(subcommand)]
    cmd: Option<Cmd>,
    /// Worker threads (default: one per core).
    #[arg(long, global = true)]
    threads: Option<usize>,
}

#[derive(Subcommand)]
enum Cmd {
    /// Render OBJ parts (default: the embedded car) to PNG/EXR, with optional AOVs.
    Render(RenderArgs),
    /// Voxelize OBJ parts and write one .svo file per part, with size statistics.
    Voxelize(VoxelizeArgs),
    /// Validate an .svo file and print its statistics.
    Info {
        /// The .svo file.
        file: PathBuf,
    },
    /// Run the numerical stability suite against the brute-force DDA oracle.
    Stability {
        /// Rays in the random families (the adversarial families have fixed sizes).
        #[arg(long, default_value_t = 1_000_000)]
        rays: usize,
        /// Also write the table, with the command that produced it, to this Markdown file.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Regenerate a built-in model's files.
    Model {
        /// Which model (only `car`).
        #[arg(value_parser = ["car"])]
        name: String,
        /// Output folder.
        #[arg(long, default_value = "models/car")]
        out_dir: PathBuf,
    },
}

#[derive(Args, Clone)]
struct SourceArgs {
    /// OBJ files; each object/group (or file) is a part. Default: the embedded car.
    #[arg(long, num_args = 1..)]
    obj: Vec<PathBuf>,
    /// Voxels along the largest part's longest side, as 2^DEPTH; all parts share that voxel size.
    #[arg(long, default_value_t = 9, conflicts_with = "voxel_size", value_parser = clap::value_parser!(u32).range(1..=20))]
    depth: u32,
    /// Voxel edge length in OBJ units (instead of --depth).
    #[arg(long)]
    voxel_size: Option<f32>,
    /// Fill closed surfaces (depth ≤ 9).
    #[arg(long)]
    solid: bool,
    /// Folder of the SVO cache (default: $VOXRAY_CACHE_DIR, $XDG_CACHE_HOME/voxray or ~/.cache/voxray).
    #[arg(long)]
    cache_dir: Option<PathBuf>,
    /// Always voxelize; neither read nor write the cache.
    #[arg(long)]
    no_cache: bool,
}

#[derive(Args, Clone)]
struct RenderArgs {
    #[command(flatten)]
    source: SourceArgs,
    /// Camera JSON (eye, target, up, vfov_deg, width, height). Default: a three-quarter view framing the model.
    #[arg(long)]
    camera_json: Option<PathBuf>,
    /// Lights JSON (sun, ambient, use_mtl_emitters). Default: afternoon sun and a pale sky.
    #[arg(long)]
    lights_json: Option<PathBuf>,
    /// Image width (overrides the camera JSON).
    #[arg(long)]
    width: Option<u32>,
    /// Image height (overrides the camera JSON).
    #[arg(long)]
    height: Option<u32>,
    /// Output image: .png (sRGB 8-bit) or .exr (linear float radiance).
    #[arg(long, default_value = "voxray.png")]
    out: PathBuf,
    /// Write t.npy, instance.npy and normal.npy into this folder.
    #[arg(long)]
    aov_dir: Option<PathBuf>,
    /// No shadow rays.
    #[arg(long)]
    no_shadows: bool,
    /// Level-of-detail: stop this many levels below the root.
    #[arg(long)]
    lod: Option<u32>,
}

#[derive(Args)]
struct VoxelizeArgs {
    #[command(flatten)]
    source: SourceArgs,
    /// Where to write <part>.svo files.
    #[arg(long, default_value = "svo")]
    out_dir: PathBuf,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Some(n) = cli.threads {
        if let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(n.max(1)).build_global() {
            eprintln!("warning: could not set {n} threads: {e}");
        }
    }
    let result = match cli.cmd {
        None => render_cmd(RenderArgs::parse_from(["render"])),
        Some(Cmd::Render(a)) => render_cmd(a),
        Some(Cmd::Voxelize(a)) => voxelize_cmd(a),
        Some(Cmd::Info { file }) => info_cmd(&file),
        Some(Cmd::Stability { rays, out }) => stability_cmd(rays, out),
        Some(Cmd::Model { out_dir, .. }) => model_cmd(&out_dir),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

impl RenderArgs {
    fn parse_from<const N: usize>(args: [&str; N]) -> RenderArgs {
        #[derive(Parser)]
        struct Only {
            #[command(flatten)]
            r: RenderArgs,
        }
        Only::parse_from(args).r
    }
}

fn bar(len: u64, what: &str) -> ProgressBar {
    let b = ProgressBar::new(len);
    b.set_style(
        ProgressStyle::with_template("{msg:>24} [{bar:40}] {pos}/{len} ({eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    b.set_message(what.to_string());
    b
}

fn load_mesh(src: &SourceArgs) -> Result<Mesh, Error> {
    let mesh = if src.obj.is_empty() {
        voxray::model::embedded::load_default_car()?
    } else {
        let mut m = Mesh::default();
        for p in &src.obj {
            m.append(voxray::mesh::load_obj(p)?);
        }
        m
    };
    for w in &mesh.warnings {
        eprintln!("warning: {w}");
    }
    if mesh.degenerate_skipped > 0 {
        eprintln!("note: skipped {} degenerate triangles", mesh.degenerate_skipped);
    }
    Ok(mesh)
}

/// Voxelizes and builds every part, printing a statistics table.
fn build_parts(mesh: &Mesh, src: &SourceArgs) -> Result<Vec<Svo>, Error> {
    let res = match src.voxel_size {
        Some(v) => Resolution::VoxelSize(v),
        None => Resolution::Depth(src.depth),
    };
    let opts = VoxelizeOptions { resolution: shared_resolution(mesh, res)?, solid: src.solid };
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
        out.push(built.svo);
    }
    Ok(out)
}

fn read_text(p: &Path) -> Result<String, Error> {
    std::fs::read_to_string(p).map_err(|source| Error::Io { path: p.display().to_string(), source })
}

fn render_cmd(a: RenderArgs) -> Result<(), Error> {
    let t0 = Instant::now();
    let mesh = load_mesh(&a.source)?;
    let mut camera = match &a.camera_json {
        Some(p) => Camera::from_json(&read_text(p)?).map_err(|e| with_path(p, e))?,
        None => {
            let (mut lo, mut hi) = (glam::Vec3::splat(f32::INFINITY), glam::Vec3::splat(f32::NEG_INFINITY));
            for t in mesh.parts.iter().flat_map(|p| &p.triangles) {
                for v in t.positions {
                    lo = lo.min(v);
                    hi = hi.max(v);
                }
            }
            Camera::framing(lo, hi, 1280, 768)
        }
    };
    camera.width = a.width.unwrap_or(camera.width);
    camera.height = a.height.unwrap_or(camera.height);
    camera.validate()?;
    let lights = match &a.lights_json {
        Some(p) => Lights::from_json(&read_text(p)?).map_err(|e| with_path(p, e))?,
        None => Lights::default(),
    };
    let t_load = t0.elapsed();

    let t1 = Instant::now();
    let parts = build_parts(&mesh, &a.source)?;
    let t_build = t1.elapsed();

    let t2 = Instant::now();
    let pb = bar(camera.height as u64, "rendering rows");
    let opts = RenderOptions { shadows: !a.no_shadows, max_level: a.lod.unwrap_or(u32::MAX) };
    let frame = render(&parts, &camera, &lights, &opts, &|d, _| pb.set_position(d as u64));
    pb.finish_and_clear();
    let t_render = t2.elapsed();

    let t3 = Instant::now();
    output::write_image(&frame, &a.out)?;
    if let Some(dir) = &a.aov_dir {
        output::write_aovs(&frame, dir)?;
    }
    let t_write = t3.elapsed();
    let rays = frame.primary_rays + frame.shadow_rays;
    eprintln!(
        "timings: load {:.2}s | voxelize+build {:.2}s | render {:.3}s | write {:.2}s",
        t_load.as_secs_f64(),
        t_build.as_secs_f64(),
        t_render.as_secs_f64(),
        t_write.as_secs_f64()
    );
    eprintln!(
        "rays: {} primary + {} shadow = {:.2} Mrays/s on {} threads ({}x{})",
        frame.primary_rays,
        frame.shadow_rays,
        rays as f64 / t_render.as_secs_f64() / 1e6,
        rayon::current_num_threads(),
        camera.width,
        camera.height
    );
    println!("wrote {}", a.out.display());
    if let Some(dir) = &a.aov_dir {
        println!("wrote {}/{{t,instance,normal}}.npy", dir.display());
    }
    Ok(())
}

fn with_path<E: std::fmt::Display>(p: &Path, e: E) -> Error {
    Error::Io {
        path: p.display().to_string(),
        source: std::io::Error::new(std::io::ErrorKind::InvalidData, e.to_string()),
    }
}

fn voxelize_cmd(a: VoxelizeArgs) -> Result<(), Error> {
    let mesh = load_mesh(&a.source)?;
    let parts = build_parts(&mesh, &a.source)?;
    std::fs::create_dir_all(&a.out_dir)
        .map_err(|source| Error::Io { path: a.out_dir.display().to_string(), source })?;
    for (part, svo) in mesh.parts.iter().zip(&parts) {
        let safe: String =
            part.name.chars().map(|c| if c.is_alphanumeric() || c == '_' || c == '-' { c } else { '_' }).collect();
        let path = a.out_dir.join(format!("{safe}.svo"));
        voxray::svo::io::save(svo, &path)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

fn info_cmd(file: &Path) -> Result<(), Error> {
    let svo = voxray::svo::io::load(file)?;
    let s = svo.stats();
    println!("{}: valid", file.display());
    println!("  bounds: min {:?}, size {}", svo.bounds.min, svo.bounds.size);
    println!("  depth {}, voxel size {}", s.depth, svo.bounds.voxel_size(s.depth));
    println!("  voxels {}, nodes {}, far pointers {}, attributes {}", s.voxels, s.nodes, s.far_slots, s.attributes);
    println!(
        "  geometry {} B ({:.2} B/voxel), attributes {} B ({:.2} B/voxel)",
        s.geometry_bytes,
        s.geometry_bytes_per_voxel(),
        s.attribute_bytes,
        s.attribute_bytes_per_voxel()
    );
    Ok(())
}

fn stability_cmd(rays: usize, out: Option<PathBuf>) -> Result<(), Error> {
    use voxray::stability::{run_case, standard_cases, table};
    let t = Instant::now();
    let cases = standard_cases(rays);
    let pb = bar(cases.len() as u64, "stability cases");
    let reports: Vec<_> = cases
        .iter()
        .map(|c| {
            let r = run_case(c);
            pb.inc(1);
            r
        })
        .collect();
    pb.finish_and_clear();
    let tbl = table(&reports);
    println!("{tbl}");
    let bad: u64 = reports.iter().map(|r| r.mismatches + r.nan + r.aborted).sum();
    println!(
        "{} rays in {:.1}s; {bad} failures",
        reports.iter().map(|r| r.rays).sum::<u64>(),
        t.elapsed().as_secs_f64()
    );
    if let Some(p) = out {
        let md = format!(
            "# Stability suite\n\nProduced by `voxray stability --rays {rays} --out {}` (release build; `cargo test` runs \
             the same cases through `tests/stability.rs` and fails on any NaN, mismatch or aborted loop).\n\n\
             Each row traces a family of stiff or adversarial rays through an SVO and compares every ray with the \
             brute-force Amanatides–Woo DDA oracle (`src/oracle.rs`, f64, no octree). Columns:\n\n\
             - **oracle hits**: rays the oracle says hit a voxel (the rest must miss).\n\
             - **NaN**: results with a non-finite t or normal.\n\
             - **misses vs oracle**: wrong voxel, wrong t, or hit/miss disagreement.\n\
             - **accepted ties**: the ray passes exactly through an edge or corner (or starts on a face), so several \
             voxels are touched at the same t; the answer is accepted only if the voxel named is occupied, touched \
             within 10⁻⁶ (relative) at that t, and no voxel is entered for longer than that before it.\n\
             - **max rel. |Δt|**: largest |t − exact f64 entry t of the voxel| / max(|t|, one cube width in t); the \
             bound is 10⁻⁵.\n\
             - **max loop count / loop bound**: iterations of the traversal loop against the proven bound \
             5·(3·(2^depth − 1) + depth) + 1 (`traverse::step_bound`).\n\n{tbl}",
            p.display()
        );
        std::fs::write(&p, md).map_err(|source| Error::Io { path: p.display().to_string(), source })?;
        println!("wrote {}", p.display());
    }
    if bad > 0 {
        return Err(Error::Io {
            path: "stability".into(),
            source: std::io::Error::other(format!("{bad} rays disagree with the oracle")),
        });
    }
    Ok(())
}

fn model_cmd(out_dir: &Path) -> Result<(), Error> {
    std::fs::create_dir_all(out_dir).map_err(|source| Error::Io { path: out_dir.display().to_string(), source })?;
    for (name, text) in voxray::model::car::files() {
        let p = out_dir.join(&name);
        std::fs::write(&p, text).map_err(|source| Error::Io { path: p.display().to_string(), source })?;
        println!("wrote {}", p.display());
    }
    Ok(())
}
