//! `voxray`: render, voxelize, inspect and test sparse voxel octrees from the command line.
//! With no subcommand it opens the demo window (without a display: renders `voxray.png`).

// What the subcommands use; each of their modules takes it with `use super::*`.
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;
use voxray::backend::Backend;
use voxray::cache::SvoCache;
use voxray::import::SceneKind;
use voxray::mesh::Mesh;
use voxray::mesh::Part;
use voxray::pipeline::{build_part, shared_resolution};
use voxray::render::{output, Features, Frame, FramePlan, RenderOptions};
use voxray::scene::animation::Rig;
use voxray::scene::{add_ground, stage_cars, Animated, Camera, Instance, Lights, Scene, Staged, Transform};
use voxray::svo::Svo;
use voxray::voxelize::{Resolution, VoxelizeOptions};
use voxray::Error;

mod args;
mod bench;
mod common;
mod demo;
mod info;
mod model;
mod render;
mod stability;
mod voxelize;

use args::*;
use bench::*;
use common::*;
use demo::*;
use info::*;
use model::*;
use render::*;
use stability::*;
use voxelize::*;

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Some(n) = cli.threads {
        if let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(n as usize).build_global() {
            eprintln!("warning: could not set {n} threads: {e}");
        }
    }
    if let Some(b) = cli.memory_budget {
        voxray::memory::set_budget(b);
    }
    // Ctrl-C stops at once: the outputs being written are removed (each is written beside its
    // final name and renamed when complete), those finished are kept.
    let interrupted = ctrlc::set_handler(|| {
        // Held until the exit: no writer can create a temporary after the clean-up.
        let stopped = voxray::partial::stop_writes();
        let removed = stopped.removed;
        let what = if removed == 0 { String::new() } else { format!(" ({removed} unfinished file(s) removed)") };
        eprintln!("\nvoxray: interrupted{what}; files already written are complete and kept");
        std::process::exit(130);
    });
    if let Err(e) = interrupted {
        eprintln!("warning: Ctrl-C will not clean up: {e}");
    }
    let result = match cli.cmd {
        None => default_cmd(),
        Some(Cmd::Render(a)) => render_cmd(a),
        Some(Cmd::Voxelize(a)) => voxelize_cmd(a),
        Some(Cmd::Info { file }) => info_cmd(&file),
        Some(Cmd::Stability { rays, out }) => stability_cmd(rays as usize, out),
        Some(Cmd::Bench(a)) => bench_cmd(a),
        Some(Cmd::Demo(a)) => demo_cmd(a),
        Some(Cmd::Model { name, out_dir }) => model_cmd(&name, out_dir.as_deref()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            if let Some(h) = hint(&e) {
                eprintln!("hint: {h}");
            }
            ExitCode::FAILURE
        }
    }
}

/// The command-line flags that fix an error the library describes in its own terms.
fn hint(e: &Error) -> Option<&'static str> {
    use voxray::voxelize::VoxelizeError;
    match e {
        Error::Voxelize(VoxelizeError::TooManyVoxels { .. } | VoxelizeError::TooManyVoxelsCounted { .. }) => {
            Some("use a smaller --depth or a larger --voxel-size")
        }
        #[cfg(feature = "gpu")]
        Error::Gpu(voxray::gpu::GpuError::NoAdapter(_)) => Some("--backend cpu renders on the CPU"),
        #[cfg(feature = "gpu")]
        Error::Gpu(voxray::gpu::GpuError::OutOfMemory(_) | voxray::gpu::GpuError::TooLarge { .. }) => {
            Some("lower --width/--height or --gi-res, try --gi-volume sparse, or use --backend cpu")
        }
        #[cfg(feature = "gpu")]
        Error::Gpu(voxray::gpu::GpuError::Memory(_)) => {
            Some("lower --width/--height or --gi-res, try --gi-volume sparse, or raise --memory-budget")
        }
        _ => None,
    }
}

/// A subcommand's arguments with every option at its default (environment variables such as
/// VOXRAY_BACKEND still apply).
fn defaults<T: clap::Args + clap::FromArgMatches>() -> Result<T, Error> {
    let cmd = T::augment_args(clap::Command::new("voxray"));
    T::from_arg_matches(&cmd.get_matches_from(["voxray"])).map_err(|e| usage(&e.to_string()))
}

/// No subcommand: the demo window; without a display, a still of the car to voxray.png.
fn default_cmd() -> Result<(), Error> {
    if let Err(e) = voxray::viewer::check_display() {
        eprintln!("voxray: {e}");
        eprintln!("voxray: rendering the default car to voxray.png instead (see `voxray render --help`)");
        return render_cmd(defaults()?);
    }
    demo_cmd(defaults()?)
}
