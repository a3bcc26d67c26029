//! The harness end to end at toy sizes: a CPU run and a GPU run (lavapipe in CI) write JSON
//! and CSV records that parse, PNG charts that are pictures, and a regenerated Markdown
//! section; the second run merges into the first. Bad options fail with clear errors.
#![cfg(feature = "cli")]

mod common;

use common::TempDir;
use std::path::Path;
use std::process::Command;

fn tmp(name: &str) -> TempDir {
    TempDir::new("voxray-bench", name)
}

fn bench(d: &Path, extra: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_voxray"))
        .current_dir(d)
        .args(["bench", "--depth", "5", "--frames", "2", "--warmup", "1", "--width", "48", "--height", "32"])
        .args(["--sweep-cars", "1,3", "--sweep-frames", "1", "--sweep-width", "40", "--sweep-height", "24"])
        .args(["--resolutions", "24x16,48x32", "--lod-levels", "3,4"])
        .args(["--out-dir", "data", "--charts-dir", "docs/images", "--docs", "docs/benchmarks.md"])
        .arg("--cache-dir")
        .arg(d.join("cache"))
        .args(extra)
        .output()
        .unwrap()
}

/// Splits one CSV line, honouring double quotes.
fn fields(line: &str) -> Vec<String> {
    let (mut out, mut cur, mut quoted) = (Vec::new(), String::new(), false);
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '"' if quoted && chars.peek() == Some(&'"') => {
                cur.push('"');
                chars.next();
            }
            '"' => quoted = !quoted,
            ',' if !quoted => out.push(std::mem::take(&mut cur)),
            _ => cur.push(c),
        }
    }
    out.push(cur);
    out
}

#[test]
fn a_tiny_bench_writes_json_csv_charts_and_the_docs_section() {
    let d = tmp("tiny");
    std::fs::create_dir_all(d.join("docs")).unwrap();
    std::fs::write(d.join("docs/benchmarks.md"), "# Benchmarks\n\nHand-written text stays.\n").unwrap();
    let o = bench(&d, &["--backends", "cpu"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");

    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("data/bench.json")).unwrap()).expect("bench.json is JSON");
    let records = json.as_array().expect("an array of records");
    // paper 4 + instances 2×2 + resolution 2 + depth (full + 2 levels) = 13
    assert_eq!(records.len(), 13, "{json:#}");
    for r in records {
        let median = r["median_ms"].as_f64().unwrap();
        assert!(median > 0.0 && median.is_finite(), "{r}");
        assert!(r["mrays_per_s"].as_f64().unwrap() > 0.0, "{r}");
        assert_eq!(r["backend_kind"], "cpu");
        assert!(r["command"].as_str().unwrap().starts_with("voxray bench"), "{r}");
        assert!(r["plan"].is_object(), "{r}");
        // Every frame's posing and update is part of it.
        assert!(r["pose_ms"].as_f64().is_some_and(|p| p > 0.0 && p <= median), "{r}");
        assert!(r["gpu_submit_ms"].is_null(), "{r}");
    }
    // Depth records carry the error against full depth: zero for full, positive when coarser.
    let depth: Vec<_> = records.iter().filter(|r| r["group"] == "depth").collect();
    assert_eq!(depth[0]["error"]["rmse"].as_f64(), Some(0.0));
    assert!(depth[1]["error"]["rmse"].as_f64().unwrap() > 0.0, "{:?}", depth[1]);
    assert!(depth[1]["error"]["rmse"].as_f64() > depth[2]["error"]["rmse"].as_f64(), "level 3 vs 4: {depth:?}");

    let csv = std::fs::read_to_string(d.join("data/bench.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 14);
    let header = fields(lines[0]);
    for l in &lines[1..] {
        assert_eq!(fields(l).len(), header.len(), "{l}");
    }
    let col = header.iter().position(|h| h == "median_ms").unwrap();
    assert!(lines[1..].iter().all(|l| fields(l)[col].parse::<f64>().is_ok_and(|v| v > 0.0)));

    for chart in ["bench-paper.png", "bench-instances.png", "bench-resolution.png", "bench-depth.png"] {
        let img = image::open(d.join("docs/images").join(chart)).unwrap().to_rgb8();
        let mut colours: Vec<[u8; 3]> = img.pixels().map(|p| p.0).collect();
        colours.sort();
        colours.dedup();
        // Text (anti-aliased), axes and coloured series: many colours, not a blank page.
        assert!(colours.len() > 20, "{chart}: {} colours", colours.len());
    }

    let md = std::fs::read_to_string(d.join("docs/benchmarks.md")).unwrap();
    assert!(md.contains("Hand-written text stays."));
    assert!(md.contains("<!-- BEGIN GENERATED") && md.contains("(images/bench-depth.png)"), "{md}");
    assert!(md.contains("| level 3 | cpu |"), "{md}");

    // A GPU run of one scenario merges into the CPU records.
    let o = bench(&d, &["--backends", "gpu", "--scenarios", "paper"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let ci = std::env::var("CI").is_ok_and(|v| v == "true");
    if err.contains("skipping backend") {
        assert!(!ci, "CI has the software Vulkan driver: {err}");
        return;
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("data/bench.json")).unwrap()).unwrap();
    let records = json.as_array().unwrap();
    assert_eq!(records.len(), 17);
    let gpu: Vec<_> = records.iter().filter(|r| r["backend_kind"] == "gpu").collect();
    assert_eq!(gpu.len(), 4);
    assert!(gpu.iter().all(|r| r["gpu_bytes"].as_u64().is_some_and(|b| b > 0)), "{gpu:?}");
    // Host round trips are counted: timed GPU frames stay on the GPU and read back only their
    // statistics and pass times (tens of bytes, not the 64×48 image's records).
    let small = |b: f64| b > 0.0 && b < 1024.0;
    assert!(gpu.iter().all(|r| r["gpu_read_back_per_frame"].as_f64().is_some_and(small)), "{gpu:?}");
    assert!(gpu.iter().all(|r| r["gpu_buffers_per_frame"].as_f64().is_some()), "{gpu:?}");
    // The host's part up to the submit is kept, and is less than the whole frame.
    let within = |r: &&serde_json::Value| {
        let median = r["median_ms"].as_f64().unwrap_or(0.0);
        r["gpu_submit_ms"].as_f64().is_some_and(|s| s > 0.0 && s < median)
    };
    assert!(gpu.iter().all(within), "{gpu:?}");
    let md = std::fs::read_to_string(d.join("docs/benchmarks.md")).unwrap();
    assert_eq!(md.matches("<!-- BEGIN GENERATED").count(), 1);
    assert!(md.contains("| gpu |"), "{md}");
    assert!(md.contains("read back per frame"), "{md}");
}

/// With `--no-docs` and no `--charts-dir`, the charts go beside the records: the charts the
/// docs show stay the ones drawn with them.
#[test]
fn without_the_docs_the_charts_go_beside_the_records() {
    let d = tmp("no-docs");
    let o = Command::new(env!("CARGO_BIN_EXE_voxray"))
        .current_dir(&d)
        .args(["bench", "--depth", "4", "--frames", "1", "--warmup", "0", "--scenarios", "resolution"])
        .args(["--resolutions", "24x16", "--backends", "cpu", "--out-dir", "data", "--no-docs", "--cache-dir"])
        .arg(d.join("cache"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let png = std::fs::read(d.join("data/bench-resolution.png")).expect("the chart beside the records");
    assert!(png.starts_with(b"\x89PNG"), "not a PNG");
    assert!(!d.join("docs").exists(), "--no-docs wrote under docs/");
}

#[test]
fn bad_bench_options_fail_clearly() {
    let d = tmp("bad");
    for (args, needle) in [
        (&["--resolutions", "0x5"][..], "1…16384"),
        (&["--resolutions", "big"][..], "not WxH"),
        (&["--scenarios", "warp"][..], "unknown scenario"),
        (&["--sweep-cars", "0"][..], "car counts"),
        (&["--gi-cars", "0", "--scenarios", "gi-scaling"][..], "--gi-cars 0: car counts"),
        (&["--lod-levels", "99", "--scenarios", "depth"][..], "levels must be 1…20"),
        (&["--lod-levels", "4", "--scenarios", "depth"][..], "4 levels deep"),
        (&["--frames", "0"][..], "frames"),
    ] {
        let o = Command::new(env!("CARGO_BIN_EXE_voxray"))
            .current_dir(&d)
            .args(["bench", "--out-dir", "data", "--no-docs", "--depth", "4", "--cache-dir"])
            .arg(d.join("cache"))
            .args(args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    assert!(!d.join("data/bench.json").exists(), "a failed run wrote records");
}

/// On a scene file the harness runs the paper comparison (against the file's triangles merged
/// at time 0) and the resolution and depth sweeps on the file's animation, says which car
/// scenarios it skipped, and leaves the docs alone.
#[test]
fn the_harness_runs_on_a_scene_file() {
    let d = tmp("scene");
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/third-party/BoxAnimated/BoxAnimated.gltf");
    let o = bench(&d, &["--backends", "cpu", "--scene", file.to_str().unwrap(), "--animation", "all"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("skipping instances"), "{err}");
    let json = std::fs::read_to_string(d.join("data/bench.json")).unwrap();
    let records: Vec<serde_json::Value> = serde_json::from_str(&json).unwrap();
    let names: Vec<&str> = records.iter().filter_map(|r| r["name"].as_str()).collect();
    assert_eq!(
        names,
        [
            "BoxAnimated.gltf: a: static single-SVO scene",
            "BoxAnimated.gltf: b: animated parts, no optimizations",
            "BoxAnimated.gltf: c: animated, culling + sorting + hit buffer",
            "BoxAnimated.gltf: d: animated, every optimization + shadow rays",
            "BoxAnimated.gltf: 24×16",
            "BoxAnimated.gltf: 48×32",
            "BoxAnimated.gltf: LOD level 5 (full)",
            "BoxAnimated.gltf: LOD level 3",
            "BoxAnimated.gltf: LOD level 4"
        ]
    );
    assert!(records.iter().all(|r| r["group"].as_str().is_some_and(|g| g.starts_with("scene-"))));
    assert!(records.iter().all(|r| r["median_ms"].as_f64().is_some_and(|m| m > 0.0)));
    assert!(!d.join("docs/benchmarks.md").exists(), "a scene file's records change no docs");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("| BoxAnimated.gltf: 48×32 | CPU"), "{out}");
}

/// The splat scenario times both renderers on the same clips and records the splat frames'
/// error against the traced ones, in a table and a chart of their own.
#[test]
fn the_splat_scenario_compares_squares_with_rays() {
    let d = tmp("splat");
    let o = bench(&d, &["--backends", "cpu", "--scenarios", "splat"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json = std::fs::read_to_string(d.join("data/bench.json")).unwrap();
    let records: Vec<serde_json::Value> = serde_json::from_str(&json).unwrap();
    let splats: Vec<&serde_json::Value> = records.iter().filter(|r| r["setting"] == "splat").collect();
    let traces = records.iter().filter(|r| r["setting"] == "trace").count();
    // Cars 1 and 3, and levels 3, 4 and the full 5.
    assert_eq!((splats.len(), traces), (5, 5));
    for r in &splats {
        let mismatch = r["error"]["mismatch"].as_f64().expect("each splat row has its error against the traced frame");
        assert!((0.0..0.5).contains(&mismatch), "{}: mismatch {mismatch}", r["name"]);
    }
    let md = std::fs::read_to_string(d.join("docs/benchmarks.md")).unwrap();
    assert!(md.contains("### Square splats against ray tracing") && md.contains("| 3 cars | cpu |"), "{md}");
    assert!(d.join("docs/images/bench-splat.png").exists());
}

/// The caster's rays on both backends (lavapipe in CI): per backend and scene (the car, and
/// the parked crowd through its instance BVH) a batch of every pixel's camera ray and one of
/// ambient-occlusion rays from their hits, asked for nearest hits, and the same
/// ambient-occlusion rays asked for any hit within their reach, timed, with its table.
#[test]
fn the_cast_scenario_times_a_callers_rays_on_each_backend() {
    let d = tmp("cast");
    let o = bench(&d, &["--backends", "cpu,gpu", "--scenarios", "cast"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json = std::fs::read_to_string(d.join("data/bench.json")).unwrap();
    let records: Vec<serde_json::Value> = serde_json::from_str(&json).unwrap();
    let skipped = String::from_utf8_lossy(&o.stderr).contains("skipping backend");
    assert!(!(skipped && std::env::var("CI").is_ok_and(|v| v == "true")), "CI has the software Vulkan driver");
    let kinds: &[&str] = if skipped { &["cpu"] } else { &["cpu", "gpu"] };
    for kind in kinds {
        let of: Vec<&serde_json::Value> =
            records.iter().filter(|r| r["group"] == "cast" && r["backend_kind"] == *kind).collect();
        assert_eq!(of.len(), 6, "{kind}: {json}");
        for (scene, instances) in [(&of[..3], 9), (&of[3..], 801)] {
            // Every pixel of the 48 × 32 view; the cars fill some of them, each hit one AO ray.
            assert_eq!(scene[0]["x"].as_f64(), Some(48.0 * 32.0));
            let ao = scene[1]["x"].as_f64().unwrap();
            assert!(ao > 0.0 && ao < 48.0 * 32.0, "{ao}");
            assert_eq!(scene[2]["x"].as_f64(), Some(ao), "the occlusion batch is the AO rays");
            assert!(scene[2]["name"].as_str().is_some_and(|n| n.contains("any hit within")), "{}", scene[2]);
            assert!(scene.iter().all(|r| r["instances"].as_u64() == Some(instances)), "{kind}: {json}");
        }
        for r in &of {
            assert!(r["median_ms"].as_f64().unwrap() > 0.0 && r["mrays_per_s"].as_f64().unwrap() > 0.0, "{r}");
            assert_eq!(r["frames"].as_u64(), Some(2));
        }
    }
    let md = std::fs::read_to_string(d.join("docs/benchmarks.md")).unwrap();
    assert!(
        md.contains("### Rays of your own: the scene caster")
            && md.contains("| camera rays | cpu | 1536 |")
            && md.contains("| ambient-occlusion rays, any hit within 0.5 | cpu |")
            && md.contains("| 100 cars: camera rays | cpu | 1536 |"),
        "{md}"
    );
}

/// The GPU's instance sweep poses the crowd on the GPU: its BVH records' plans say so and
/// carry the crowd passes' time, and the sorted-sphere points (the host's posing) do not;
/// with `--crowd-posing host` none does.
#[test]
fn the_gpu_instance_sweep_poses_the_cars_on_the_gpu() {
    let d = tmp("gpu-instances");
    let o = bench(&d, &["--backends", "gpu", "--scenarios", "instances", "--no-docs"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    if err.contains("skipping backend") {
        assert!(!std::env::var("CI").is_ok_and(|v| v == "true"), "CI has the software Vulkan driver: {err}");
        return;
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("data/bench.json")).unwrap()).unwrap();
    let records = json.as_array().unwrap();
    assert_eq!(records.len(), 4, "{records:?}");
    let on_gpu = |r: &serde_json::Value| {
        let reasons = r["plan"]["reasons"].as_array().expect("the plan's reasons");
        reasons.iter().any(|x| x.as_str().is_some_and(|s| s.starts_with("pose: on the GPU")))
    };
    for r in records {
        assert_eq!(on_gpu(r), r["setting"] == "BVH", "{r}");
        assert_eq!(r["gpu_crowd_ms"].as_f64().is_some(), r["setting"] == "BVH", "{r}");
        assert!(r["median_ms"].as_f64().is_some_and(|m| m > 0.0), "{r}");
    }
    let d = tmp("gpu-instances-host");
    let o = bench(&d, &["--backends", "gpu", "--scenarios", "instances", "--no-docs", "--crowd-posing", "host"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("data/bench.json")).unwrap()).unwrap();
    let records = json.as_array().unwrap();
    assert_eq!(records.len(), 4, "{records:?}");
    assert!(records.iter().all(|r| !on_gpu(r) && r["gpu_crowd_ms"].is_null()), "{records:?}");
}
