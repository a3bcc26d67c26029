//! The window: under Xvfb the demo opens, draws 30 frames, writes a screenshot that is not
//! blank and exits 0 — with the CPU renderer and with the GPU renderer on the window's
//! device. Without a display it says so. In CI (CI=true) a missing Xvfb fails the test.
#![cfg(feature = "viewer")]

mod common;

use common::TempDir;
use std::process::Command;

fn xvfb() -> bool {
    let found = Command::new("xvfb-run").arg("--help").output().is_ok();
    if !found && std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("CI needs xvfb-run (Debian: xvfb) for the window tests");
    }
    if !found {
        eprintln!("skipping: xvfb-run not found");
    }
    found
}

fn tmp(name: &str) -> TempDir {
    TempDir::new("voxray-demo", name)
}

/// Runs the demo and checks its screenshot; returns its standard output.
fn demo_under_xvfb(backend: &str, frames: &str) -> String {
    let d = tmp(backend);
    let shot = d.join("shot.png");
    let o = Command::new("xvfb-run")
        .args(["-a", "-s", "-screen 0 800x600x24"])
        .arg(env!("CARGO_BIN_EXE_voxray"))
        .args(["demo", "--frames", frames, "--exit", "--width", "96", "--height", "64", "--depth", "6", "--in-place"])
        .args(["--backend", backend, "--cache-dir"])
        .arg(d.join("cache"))
        .arg("--screenshot")
        .arg(&shot)
        .output()
        .expect("run xvfb-run");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains(&format!("demo: {frames} frames")), "{err}");
    let img = image::open(&shot).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (96, 64));
    // Not blank: the sky, the ground and the red car are all there.
    let mut colours: Vec<[u8; 3]> = img.pixels().map(|p| p.0).collect();
    colours.sort();
    colours.dedup();
    assert!(colours.len() > 50, "only {} distinct colours", colours.len());
    let red = img.pixels().filter(|p| p.0[0] as i32 > p.0[1] as i32 + 60 && p.0[0] as i32 > p.0[2] as i32 + 60).count();
    assert!(red > 300, "only {red} red-car pixels in the screenshot");
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn demo_runs_30_frames_on_the_cpu_renderer() {
    if xvfb() {
        let out = demo_under_xvfb("cpu", "30");
        assert!(!out.contains("gpu steady state"), "{out}");
    }
}

/// The GPU renderer draws on the window's device, and its frames stay there: after the
/// first few, no frame reads anything back or creates a buffer (the screenshot frame, which
/// copies the window, is left out of the averages).
#[test]
fn demo_runs_on_the_gpu_renderer_sharing_the_window_device() {
    if xvfb() {
        let out = demo_under_xvfb("gpu", "30");
        let lines: Vec<&str> = out.lines().filter(|l| l.starts_with("gpu steady state")).collect();
        assert_eq!(lines, ["gpu steady state: read back 0 B/frame, created 0.00 buffers/frame"], "{out}");
    }
}

#[test]
fn demo_without_a_display_says_what_to_do() {
    let o = Command::new(env!("CARGO_BIN_EXE_voxray"))
        .args(["demo", "--frames", "1", "--exit", "--depth", "6"])
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("voxray render"), "{err}");
}

#[test]
fn demo_draws_the_panel_beside_the_image() {
    if !xvfb() {
        return;
    }
    let d = tmp("panel");
    let shot = d.join("panel.png");
    let o = Command::new("xvfb-run")
        .args(["-a", "-s", "-screen 0 800x600x24"])
        .arg(env!("CARGO_BIN_EXE_voxray"))
        .args([
            "demo",
            "--frames",
            "3",
            "--exit",
            "--width",
            "640",
            "--height",
            "400",
            "--depth",
            "6",
            "--in-place",
            "--backend",
            "cpu",
        ])
        .arg("--cache-dir")
        .arg(d.join("cache"))
        .arg("--screenshot")
        .arg(&shot)
        .output()
        .expect("run xvfb-run");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::open(&shot).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (640, 400));
    let dark = |x0: u32, x1: u32| {
        let mut n = 0;
        for y in 0..400 {
            for x in x0..x1 {
                let p = img.get_pixel(x, y).0;
                n += (p[0] < 60 && p[1] < 60 && p[2] < 60) as u32;
            }
        }
        n as f64 / ((x1 - x0) * 400) as f64
    };
    // The panel (dark theme) fills the left 280 px; the image (sky, ground, car) the rest.
    assert!(dark(10, 270) > 0.6, "no panel: {:.2} dark on the left", dark(10, 270));
    assert!(dark(300, 640) < 0.2, "no image beside the panel: {:.2} dark on the right", dark(300, 640));
}

#[test]
fn no_subcommand_without_a_display_renders_a_still_instead() {
    let d = tmp("default");
    let o = Command::new(env!("CARGO_BIN_EXE_voxray"))
        .current_dir(&d)
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .env("VOXRAY_CACHE_DIR", d.join("cache"))
        .env("VOXRAY_BACKEND", "cpu")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("voxray render"), "{err}");
    let img = image::open(d.join("voxray.png")).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (1280, 768));
}

#[test]
fn demo_without_any_gpu_adapter_renders_on_the_cpu_in_a_software_window() {
    if !xvfb() {
        return;
    }
    let d = tmp("noadapter");
    let shot = d.join("shot.png");
    // No Vulkan driver can be found: wgpu has no adapter at all.
    let o = Command::new("xvfb-run")
        .args(["-a", "-s", "-screen 0 800x600x24"])
        .arg(env!("CARGO_BIN_EXE_voxray"))
        .args(["demo", "--frames", "30", "--exit", "--width", "96", "--height", "64", "--depth", "6", "--in-place"])
        .arg("--cache-dir")
        .arg(d.join("cache"))
        .arg("--screenshot")
        .arg(&shot)
        .env("VK_ICD_FILENAMES", d.join("no-such-icd.json"))
        .env("VK_DRIVER_FILES", d.join("no-such-icd.json"))
        .output()
        .expect("run xvfb-run");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("no GPU adapter") && err.contains("rendering on the CPU"), "{err}");
    assert!(err.contains("demo: 30 frames"), "{err}");
    let img = image::open(&shot).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (96, 64));
    let red = img.pixels().filter(|p| p.0[0] as i32 > p.0[1] as i32 + 60 && p.0[0] as i32 > p.0[2] as i32 + 60).count();
    assert!(red > 300, "only {red} red-car pixels in the screenshot");
}

#[test]
fn demo_with_gi_draws_a_different_picture_from_the_same_frames() {
    if !xvfb() {
        return;
    }
    let d = tmp("gi");
    let run = |gi: bool, shot: &std::path::Path| {
        let mut c = Command::new("xvfb-run");
        c.args(["-a", "-s", "-screen 0 800x600x24"])
            .arg(env!("CARGO_BIN_EXE_voxray"))
            .args(["demo", "--frames", "3", "--exit", "--width", "96", "--height", "64", "--depth", "6", "--in-place"])
            .args(["--backend", "cpu", "--cache-dir"])
            .arg(d.join("cache"))
            .arg("--screenshot")
            .arg(shot);
        if gi {
            c.arg("--gi");
        }
        let o = c.output().expect("run xvfb-run");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        image::open(shot).unwrap().to_rgb8()
    };
    let plain = run(false, &d.join("plain.png"));
    let gi = run(true, &d.join("gi.png"));
    let differ = plain.pixels().zip(gi.pixels()).filter(|(a, b)| a != b).count();
    assert!(differ > 500, "GI changed only {differ} pixels");
}

/// A glTF file opened from the command line plays its animation: BoxAnimated's inner (pink)
/// box starts inside the outer one and has risen above it 2 s later (60 scripted frames).
#[test]
fn demo_plays_a_gltf_files_animation() {
    if !xvfb() {
        return;
    }
    let d = tmp("gltf");
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/third-party/BoxAnimated/BoxAnimated.gltf");
    let pink_above = |frames: &str| {
        let shot = d.join(format!("shot_{frames}.png"));
        let o = Command::new("xvfb-run")
            .args(["-a", "-s", "-screen 0 800x600x24"])
            .arg(env!("CARGO_BIN_EXE_voxray"))
            .args(["demo", "--scene"])
            .arg(&file)
            .args([
                "--animation",
                "all",
                "--frames",
                frames,
                "--exit",
                "--width",
                "96",
                "--height",
                "96",
                "--depth",
                "6",
            ])
            .args(["--backend", "cpu", "--cache-dir"])
            .arg(d.join("cache"))
            .arg("--screenshot")
            .arg(&shot)
            .output()
            .expect("run xvfb-run");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let img = image::open(&shot).unwrap().to_rgb8();
        // Pink: red and blue well above green, in the upper half of the image.
        img.enumerate_pixels()
            .filter(|(_, y, p)| *y < 48 && p.0[0] as i32 > p.0[1] as i32 + 40 && p.0[2] as i32 > p.0[1] as i32 + 40)
            .count()
    };
    let (start, later) = (pink_above("1"), pink_above("60"));
    assert!(
        start < 20 && later > 200,
        "pink pixels in the upper half: {start} at the start, {later} two seconds later"
    );
    std::fs::remove_dir_all(&d).ok();
}
