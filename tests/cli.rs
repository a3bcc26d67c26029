//! The `voxray` command line, end to end: images, AOVs in DESIGN.md's conventions, the SVO
//! cache, and clear errors for bad input.

mod common;

use common::TempDir;
use std::path::Path;
use std::process::{Command, Output};

fn voxray(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_voxray")).args(args).output().expect("run voxray")
}

fn tmp(name: &str) -> TempDir {
    TempDir::new("voxray-cli", name)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Reads a little-endian .npy file: (descr, shape, data bytes).
fn read_npy(p: &Path) -> (String, Vec<usize>, Vec<u8>) {
    let b = std::fs::read(p).unwrap();
    assert_eq!(&b[..8], b"\x93NUMPY\x01\x00");
    let hl = u16::from_le_bytes([b[8], b[9]]) as usize;
    assert_eq!((10 + hl) % 64, 0, "header padded to 64 bytes");
    let header = std::str::from_utf8(&b[10..10 + hl]).unwrap();
    let descr = header.split("'descr': '").nth(1).unwrap().split('\'').next().unwrap().to_string();
    let shape_s = header.split("'shape': (").nth(1).unwrap().split(')').next().unwrap();
    let shape = shape_s.split(',').filter(|x| !x.trim().is_empty()).map(|x| x.trim().parse().unwrap()).collect();
    assert!(header.contains("'fortran_order': False"));
    (descr, shape, b[10 + hl..].to_vec())
}

fn f32s(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
}

#[test]
fn help_lists_the_subcommands() {
    let o = voxray(&["--help"]);
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    for cmd in ["render", "voxelize", "info", "stability", "model"] {
        assert!(text.contains(cmd), "{cmd} missing from --help");
    }
}

#[test]
fn render_writes_image_and_aovs_by_the_conventions() {
    let d = tmp("aov");
    // Looking straight down at the 2x2 plane from 3 units up; 60° vertical field of view, so
    // the image spans ±1.73 at the plane and the corners miss.
    std::fs::write(
        d.join("cam.json"),
        r#"{"eye":[0,3,0],"target":[0,0,0],"up":[0,0,-1],"vfov_deg":60,"width":48,"height":32}"#,
    )
    .unwrap();
    let (cache, cam, aov, png) = (d.join("cache"), d.join("cam.json"), d.join("aov"), d.join("plane.png"));
    let args = [
        "render",
        "--obj",
        "models/test/plane.obj",
        "--camera-json",
        s(&cam),
        "--aov-dir",
        s(&aov),
        "--out",
        s(&png),
        "--cache-dir",
        s(&cache),
    ];
    let o = voxray(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("Mrays/s") && err.contains("setup (load, voxelize, build)"), "timings printed: {err}");
    let img = image::open(d.join("plane.png")).unwrap();
    assert_eq!((img.width(), img.height()), (48, 32));

    let (descr, shape, data) = read_npy(&d.join("aov/t.npy"));
    assert_eq!((descr.as_str(), shape.as_slice()), ("<f4", &[32usize, 48][..]));
    let t = f32s(&data);
    let (_, ishape, idata) = read_npy(&d.join("aov/instance.npy"));
    assert_eq!(ishape, [32, 48]);
    let inst: Vec<i32> = idata.chunks_exact(4).map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    let (_, nshape, ndata) = read_npy(&d.join("aov/normal.npy"));
    assert_eq!(nshape, [32, 48, 3]);
    let n = f32s(&ndata);
    // Centre pixel: hits the plane's top voxel layer (voxel 2/512) at t ≈ 3, normal +Y.
    let c = 16 * 48 + 24;
    let cos = {
        // Pixel (24, 16) is half a pixel off the axis in each direction.
        let tan_half = (30f64).to_radians().tan();
        let sx = (2.0 * 24.5 / 48.0 - 1.0) * tan_half * 48.0 / 32.0;
        let sy = (1.0 - 2.0 * 16.5 / 32.0) * tan_half;
        1.0 / (1.0 + sx * sx + sy * sy).sqrt()
    };
    let expect = 3.0 / cos;
    assert!((t[c] as f64 - expect).abs() < 2.0 * 2.0 / 512.0 / cos, "t {} expected ≈ {expect}", t[c]);
    assert_eq!(inst[c], 0);
    assert!((n[3 * c + 1] - 1.0).abs() < 1e-3, "normal {:?}", &n[3 * c..3 * c + 3]);
    // Corners: misses are +inf, −1 and a zero normal.
    assert!(t[0].is_infinite() && t[0] > 0.0);
    assert_eq!(inst[0], -1);
    assert_eq!(&n[0..3], &[0.0, 0.0, 0.0]);
    assert!(t.iter().all(|v| !v.is_nan()) && n.iter().all(|v| v.is_finite()));

    // A second run loads the SVO from the cache.
    let o = voxray(&args);
    assert!(String::from_utf8_lossy(&o.stderr).contains("cached"));
    // A corrupted cache entry is reported and rebuilt, not fatal.
    for e in std::fs::read_dir(&cache).unwrap() {
        let p = e.unwrap().path();
        let mut b = std::fs::read(&p).unwrap();
        let last = b.len() - 10;
        b[last] ^= 0xFF;
        std::fs::write(&p, b).unwrap();
    }
    let o = voxray(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() && err.contains("checksum mismatch") && err.contains("rebuilding"), "{err}");
}

#[test]
fn exr_holds_linear_radiance() {
    let d = tmp("exr");
    std::fs::write(
        d.join("cam.json"),
        r#"{"eye":[0,3,0],"target":[0,0,0],"up":[0,0,-1],"vfov_deg":60,"width":16,"height":16}"#,
    )
    .unwrap();
    // Sun straight above with irradiance π: a default-grey (0.7) plane reflects 0.7·π·1/π = 0.7
    // plus ambient 0.1·0.7; a miss shows the sky radiance 0.1.
    std::fs::write(d.join("lights.json"), r#"{"sun":{"to_sun":[0,1,0],"irradiance":[3.14159265,3.14159265,3.14159265]},"ambient":{"radiance":[0.1,0.1,0.1]}}"#).unwrap();
    let o = voxray(&[
        "render",
        "--obj",
        "models/test/plane.obj",
        "--camera-json",
        s(&d.join("cam.json")),
        "--lights-json",
        s(&d.join("lights.json")),
        "--out",
        s(&d.join("p.exr")),
        "--no-cache",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = image::open(d.join("p.exr")).unwrap().to_rgb32f();
    let centre = img.get_pixel(8, 8)[0];
    assert!((centre - 0.77).abs() < 0.01, "centre radiance {centre}");
    assert!((img.get_pixel(0, 0)[0] - 0.1).abs() < 1e-6);
}

#[test]
fn bad_input_gives_clear_errors() {
    let d = tmp("bad");
    let run = |args: &[&str]| {
        let o = voxray(args);
        (o.status.code(), String::from_utf8_lossy(&o.stderr).to_string())
    };
    let (code, err) = run(&["render", "--obj", "does/not/exist.obj", "--no-cache"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("does/not/exist.obj: file not found"), "{err}");

    std::fs::write(
        d.join("cam.json"),
        r#"{"eye":[0,0,0],"target":[0,0,0],"up":[0,1,0],"vfov_deg":60,"width":8,"height":8}"#,
    )
    .unwrap();
    let (code, err) =
        run(&["render", "--obj", "models/test/cube.obj", "--camera-json", s(&d.join("cam.json")), "--no-cache"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("eye and target coincide"), "{err}");

    std::fs::write(d.join("broken.json"), "{ not json").unwrap();
    let (code, err) =
        run(&["render", "--obj", "models/test/cube.obj", "--lights-json", s(&d.join("broken.json")), "--no-cache"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("broken.json") && err.contains("lights JSON"), "{err}");

    // Silent mistakes are named: a misspelt light, lights that give none, a level of detail
    // below every part, a GI volume smaller than a speck, emitters left off.
    std::fs::write(d.join("typo.json"), r#"{"sunn": {}}"#).unwrap();
    let (code, err) =
        run(&["render", "--obj", "models/test/cube.obj", "--lights-json", s(&d.join("typo.json")), "--no-cache"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("unknown field `sunn`"), "{err}");
    std::fs::write(d.join("none.json"), "{}").unwrap();
    let out = s(&d.join("quiet.png")).to_string();
    let small = ["--width", "16", "--height", "12", "--backend", "cpu", "--no-cache", "--out", &out];
    let (code, err) = run(&[
        &["render", "--obj", "models/test/cube.obj", "--lights-json", s(&d.join("none.json")), "--lod", "20"][..],
        &small[..],
    ]
    .concat());
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("the lights give no light") && err.contains("--lod 20 is at or below"), "{err}");
    let (code, err) =
        run(&[&["render", "--obj", "models/test/cube.obj", "--voxel-size", "50"][..], &small[..]].concat());
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("--voxel-size 50 is larger than part 'cube'"), "{err}");
    let (code, err) =
        run(&[&["render", "--obj", "models/test/cube.obj", "--gi", "--gi-extent", "1e-30"][..], &small[..]].concat());
    // (This once overflowed an integer cell number in the level chain's sampling.)
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("--gi-extent 1e-30 is under a thousandth") && err.contains("into 0 of"), "{err}");
    let (code, err) =
        run(&[&["render", "--obj", "models/test/cube.obj", "--gi", "--gi-extent", "1e-3"][..], &small[..]].concat());
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("--gi-extent 1e-3 is under a thousandth"), "{err}");

    std::fs::write(d.join("junk.svo"), b"VOXRSVO\0 truncated").unwrap();
    let (code, err) = run(&["info", s(&d.join("junk.svo"))]);
    assert_eq!(code, Some(1));
    assert!(err.contains("truncated"), "{err}");

    // Inputs are checked before they are read whole: a 12 GB file (sparse, no disk used) is
    // refused by its magic number or its header's length, a device without end by the limit.
    let big = d.join("big.svo");
    let f = std::fs::File::create(&big).unwrap();
    f.set_len(12 << 30).unwrap();
    drop(f);
    let (code, err) = run(&["info", s(&big)]);
    assert_eq!(code, Some(1));
    assert!(err.contains("magic"), "{err}");
    let mut header = std::fs::read("tests/data/legacy-v2.svo").unwrap_or_default();
    if header.len() >= 64 {
        header.truncate(64);
        let f = std::fs::OpenOptions::new().write(true).open(&big).unwrap();
        std::os::unix::fs::FileExt::write_all_at(&f, &header, 0).unwrap();
        let (code, err) = run(&["info", s(&big)]);
        assert_eq!(code, Some(1));
        assert!(err.contains("12884901888"), "the header's length against the file's: {err}");
    }
    std::fs::remove_file(&big).unwrap();
    if Path::new("/dev/zero").exists() {
        let (code, err) = run(&["render", "--obj", "/dev/zero", "--no-cache"]);
        assert_eq!(code, Some(1));
        assert!(err.contains("/dev/zero: larger than") && err.contains("an OBJ file"), "{err}");
    }

    // A solid fill is counted before its interior is written (a 12-triangle cube at depth 9
    // would be 134 million voxels, 7.5 GB).
    let (code, err) = run(&[
        "voxelize",
        "--obj",
        "models/test/cube.obj",
        "--solid",
        "--depth",
        "9",
        "--out-dir",
        s(&d),
        "--no-cache",
    ]);
    assert_eq!(code, Some(1));
    assert!(err.contains("about 135 million voxels (the limit is 60 million)"), "{err}");
    // The library's message, then the flags that change it.
    assert!(err.contains("hint: use a smaller --depth or a larger --voxel-size"), "{err}");

    // A byte-order mark before JSON is not an error.
    std::fs::write(d.join("bom.json"), "\u{feff}{\"sun\": null}").unwrap();
    let (code, err) = run(&[
        "render",
        "--obj",
        "models/test/cube.obj",
        "--lights-json",
        s(&d.join("bom.json")),
        "--no-cache",
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        s(&d.join("bom.png")),
    ]);
    assert_eq!(code, Some(0), "{err}");

    let (code, _) = run(&["render", "--depth", "0"]);
    assert_eq!(code, Some(2), "clap rejects out-of-range depth");
    // Count flags are bounded before anything starts (clap's exit code 2): no hang starting
    // 100 000 threads, no 12.8 TB allocation for 10¹² stability rays. Each other bad flag gets
    // its own message, and every scenario is listed (exit code 1).
    for (args, want, needle) in [
        (&["--threads", "100000", "info", "x.svo"][..], 2, "1..=1024"),
        (&["--threads", "0", "info", "x.svo"][..], 2, "1..=1024"),
        (&["stability", "--rays", "1000000000000"][..], 2, "1..=100000000"),
        (&["render", "--fps", "0"][..], 1, "--fps 0: frames per second must be a positive number"),
        (&["render", "--time", "inf"][..], 1, "--time inf: the clip time must be a finite number"),
        (&["render", "--orbit", "NaN"][..], 1, "--orbit NaN: the camera's turn must be a finite number"),
        (
            &["bench", "--scenarios", "gi-scaling", "--gi-res", "3"][..],
            1,
            "--gi-res 3: the GI scenarios' volume needs a power of two",
        ),
        (
            // Frames of this size fit 11 GiB; the caster's rays and hits do not.
            &[
                "bench",
                "--scenarios",
                "cast",
                "--backends",
                "cpu",
                "--depth",
                "5",
                "--no-cache",
                "--width",
                "16384",
                "--height",
                "4096",
                "--memory-budget",
                "11G",
                "--no-docs",
            ][..],
            1,
            "the cast scenario's rays and hits needs about",
        ),
        (
            &["bench", "--scenarios", "bogus"][..],
            1,
            "paper, instances, resolution, depth, splat, cast, peers, gi-scaling, gi-volume, gi-accuracy",
        ),
    ] {
        let (code, err) = run(args);
        assert_eq!(code, Some(want), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
    }
    // The cube rendered at 8×8 with `extra` flags.
    let tiny = |extra: &[&str]| {
        let base = ["render", "--obj", "models/test/cube.obj", "--no-cache", "--width", "8", "--height", "8"];
        run(&[&base[..], extra].concat())
    };
    let (code, err) = tiny(&["--out", s(&d.join("x.bmp"))]);
    assert_eq!(code, Some(1));
    assert!(err.contains("unknown image format"), "{err}");
    // An AOV folder that cannot be made is refused before rendering: no image is written.
    std::fs::write(d.join("a_file"), "").unwrap();
    let image = d.join("never.png");
    let (code, err) = tiny(&["--aov-dir", s(&d.join("a_file").join("aovs")), "--out", s(&image)]);
    assert_eq!(code, Some(1));
    assert!(err.contains("a_file/aovs"), "{err}");
    assert!(!image.exists(), "rendered before checking the AOV folder");
}

/// The memory budget refuses, before allocating and with what to change, voxelization, frames,
/// GIF clips and GI volumes that need more than it; by default it follows `ulimit -v`, so a
/// capped process gets the error instead of an out-of-memory abort.
#[test]
fn memory_budget_refuses_before_allocating() {
    let d = tmp("budget");
    let run = |args: &[&str]| {
        let o = voxray(args);
        (o.status.code(), String::from_utf8_lossy(&o.stderr).to_string())
    };
    let cube = ["--obj", "models/test/cube.obj", "--no-cache", "--backend", "cpu"];
    let out = |name: &str| d.join(name).to_str().unwrap().to_string();
    let cases: Vec<(Vec<String>, &str, Option<String>)> = vec![
        (
            ["--memory-budget", "64M", "voxelize", "--depth", "10", "--out-dir", &out("v")]
                .iter()
                .map(|s| s.to_string())
                .chain(cube[..3].iter().map(|s| s.to_string()))
                .collect(),
            "voxelizing part 'cube' at depth 10 (about 6.3 million voxels) needs about 1.3 GiB, more than the memory budget of 64.0 MiB",
            None,
        ),
        (
            ["--memory-budget", "300M", "render", "--depth", "4", "--width", "2048", "--height", "2048", "--out", &out("big.png")]
                .iter()
                .chain(cube.iter())
                .map(|s| s.to_string())
                .collect(),
            "rendering 2048×2048 needs about 640.0 MiB, more than the memory budget of 300.0 MiB",
            Some(out("big.png")),
        ),
        (
            ["--memory-budget", "100M", "render", "--depth", "4", "--width", "256", "--height", "256", "--frames", "500", "--out", &out("clip.gif")]
                .iter()
                .chain(cube.iter())
                .map(|s| s.to_string())
                .collect(),
            "into a GIF of 500 frames needs about 135.0 MiB",
            Some(out("clip.gif")),
        ),
        (
            ["--memory-budget", "100M", "render", "--depth", "4", "--width", "32", "--height", "32", "--gi", "--gi-res", "512", "--gi-volume", "dense", "--out", &out("gi.png")]
                .iter()
                .chain(cube.iter())
                .map(|s| s.to_string())
                .collect(),
            "a dense GI volume of 512³ cells and its level chain needs about",
            Some(out("gi.png")),
        ),
        (
            ["--memory-budget", "100M", "bench", "--resolutions", "320x192,4096x4096", "--no-docs", "--out-dir", &out("bench")]
                .iter()
                .map(|s| s.to_string())
                .collect(),
            "benchmark frames of 4096×4096 needs about 2.5 GiB",
            Some(out("bench")),
        ),
    ];
    for (args, needle, file) in cases {
        let args: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
        let (code, err) = run(&args);
        assert_eq!(code, Some(1), "{args:?}: {err}");
        assert!(err.contains(needle) && err.contains("memory budget"), "{args:?}: {err}");
        if let Some(f) = file {
            assert!(!Path::new(&f).exists(), "{f} written");
        }
    }
    // Under an address-space cap of 3 GB, without --memory-budget: the default budget follows
    // the cap, and a 13 GB frame is refused with a message instead of aborting.
    let exe = env!("CARGO_BIN_EXE_voxray");
    let script = format!(
        "ulimit -v 3000000 && exec '{exe}' render --obj models/test/cube.obj --no-cache --backend cpu --depth 4 \
         --width 16384 --height 4096 --out '{}'",
        out("capped.png")
    );
    let o = std::process::Command::new("bash").args(["-c", &script]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("rendering 16384×4096 needs about 10.0 GiB, more than the memory budget of 2.1 GiB"), "{err}");
}

/// Each input that used to abort with an out-of-memory error (exit 134, nothing written), run
/// under an address-space cap of 2.4 GiB with the default memory budget (which follows the
/// cap): a clear error and exit code 1 instead, before the allocation.
#[test]
fn inputs_that_aborted_get_clear_errors_under_a_memory_cap() {
    let d = tmp("capped");
    // 14 400 needles 2 units long and 10⁻⁶ wide, spread over a 2-unit cube.
    let mut slivers = String::new();
    for i in 0..14_400 {
        let (y, z) = ((i % 120) as f64 / 60.0, (i / 120) as f64 / 60.0);
        slivers += &format!("v 0 {y} {z}\nv 2 {y} {z}\nv 2 {} {z}\n", y + 1e-6);
        slivers += &format!("f {} {} {}\n", 3 * i + 1, 3 * i + 2, 3 * i + 3);
    }
    std::fs::write(d.join("slivers.obj"), slivers).unwrap();
    // Three axis planes through the origin: every voxel face they lie on touches two voxels.
    let planes = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nv -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\n\
                  v 0 -1 -1\nv 0 1 -1\nv 0 1 1\nv 0 -1 1\nf 1 2 3 4\nf 5 6 7 8\nf 9 10 11 12\n";
    std::fs::write(d.join("planes.obj"), planes).unwrap();
    let out = |name: &str| d.join(name).to_str().unwrap().to_string();
    let (slivers, planes) = (out("slivers.obj"), out("planes.obj"));
    // A command line: its words (the temporary folder's paths have no spaces), then the
    // output, then the model.
    let line = |words: &str, out_flag: &str, name: &str, model: &[&str]| -> Vec<String> {
        let mut v: Vec<String> = words.split(' ').map(String::from).collect();
        v.extend([out_flag.to_string(), out(name)]);
        v.extend(model.iter().map(|s| s.to_string()));
        v
    };
    let cube = ["--obj", "models/test/cube.obj", "--no-cache"];
    let big = "render --backend cpu --depth 4 --width 8192 --height 8192";
    let cases: Vec<(Vec<String>, &str)> = vec![
        (line("voxelize --solid --depth 9", "--out-dir", "v1", &cube), "million voxels"),
        (line(&format!("voxelize --depth 12 --no-cache --obj {slivers}"), "--out-dir", "v2", &[]), "million voxels"),
        (line(&format!("voxelize --depth 12 --no-cache --obj {planes}"), "--out-dir", "v3", &[]), "million voxels"),
        (line(&format!("{big} --reference"), "--out", "r.exr", &cube), "memory budget"),
        (line(&format!("{big} --aov-dir {}", out("aov")), "--out", "a.png", &cube), "memory budget"),
        (
            line("render --backend cpu --depth 4 --width 1024 --height 1024 --frames 1000", "--out", "c.gif", &cube),
            "memory budget",
        ),
    ];
    let exe = env!("CARGO_BIN_EXE_voxray");
    for (args, needle) in cases {
        let quoted: Vec<String> = args.iter().map(|a| format!("'{a}'")).collect();
        let script = format!("ulimit -v 2500000 && exec '{exe}' {}", quoted.join(" "));
        let o = Command::new("bash").args(["-c", &script]).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(needle) && !err.contains("panicked"), "{args:?}: {err}");
    }
    for f in ["r.exr", "a.png", "c.gif", "aov"] {
        assert!(!d.join(f).exists(), "{f} written");
    }
}

/// Ctrl-C during a clip: exit code 130 with a message; every frame on disk is complete and no
/// temporary file is left beside them.
#[test]
fn ctrl_c_stops_a_clip_leaving_only_complete_frames() {
    let d = tmp("interrupt");
    let out = d.join("clip.png");
    let child = Command::new(env!("CARGO_BIN_EXE_voxray"))
        .args(["render", "--obj", "models/test/cube.obj", "--no-cache", "--backend", "cpu", "--depth", "5"])
        .args(["--width", "192", "--height", "128", "--frames", "5000", "--out", s(&out)])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run voxray");
    let started = std::time::Instant::now();
    while !d.join("clip_0003.png").exists() && started.elapsed().as_secs() < 120 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let kill = Command::new("kill").args(["-INT", &child.id().to_string()]).status().expect("kill");
    assert!(kill.success());
    let o = child.wait_with_output().expect("wait");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(err.contains("voxray: interrupted") && err.contains("files already written are complete"), "{err}");
    let names: Vec<String> =
        std::fs::read_dir(&d).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    eprintln!("{} frames before Ctrl-C, {:?}", names.len(), started.elapsed());
    assert!(names.len() >= 4 && names.len() < 5000, "{names:?}");
    for n in &names {
        assert!(n.starts_with("clip_") && n.ends_with(".png"), "left behind: {n}");
        let b = std::fs::read(d.join(n)).unwrap();
        assert!(b.len() > 20 && b[b.len() - 8..b.len() - 4] == *b"IEND", "{n} is not a complete PNG");
    }
}

#[test]
fn voxelize_and_info_round_trip() {
    let d = tmp("vox");
    let o =
        voxray(&["voxelize", "--obj", "models/test/two_parts.obj", "--depth", "6", "--out-dir", s(&d), "--no-cache"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for part in ["left", "right"] {
        let o = voxray(&["info", s(&d.join(format!("{part}.svo")))]);
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success() && out.contains("valid") && out.contains("B/voxel"), "{out}");
    }
    // Parts whose file names would collide each get a file, with a warning.
    let obj = d.join("same.obj");
    std::fs::write(&obj, "o a b\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\no a_b\nv 2 0 0\nv 3 0 0\nv 2 1 0\nf 4 5 6\n")
        .unwrap();
    let out = d.join("same");
    let o = voxray(&["voxelize", "--obj", s(&obj), "--depth", "4", "--out-dir", s(&out), "--no-cache"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(out.join("a_b.svo").exists() && out.join("a_b_2.svo").exists(), "{err}");
    assert!(err.contains("writing this one as a_b_2.svo"), "{err}");
}

#[test]
fn frame_sequences_gifs_and_per_frame_aovs() {
    let d = tmp("seq");
    let cache = d.join("cache");
    let common = ["--depth", "6", "--width", "48", "--height", "32", "--cache-dir", s(&cache)];
    let png = d.join("car.png");
    let aov = d.join("aov");
    let mut args = vec!["render", "--frames", "3", "--fps", "10", "--out", s(&png), "--aov-dir", s(&aov), "--explain"];
    args.extend(common);
    let o = voxray(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    for f in 0..3 {
        assert!(d.join(format!("car_{f:04}.png")).exists(), "frame {f} image");
        for a in ["t", "instance", "normal"] {
            assert!(aov.join(format!("frame_{f:04}/{a}.npy")).exists(), "frame {f} {a}.npy");
        }
    }
    // The plan is printed for the first frame and again when it changes (the hit buffer
    // turns on once there is a previous frame).
    assert!(
        err.contains("frame 0: frame plan (9 instances)") && err.contains("hit_buffer: off (first frame)"),
        "{err}"
    );
    assert!(err.contains("frame 1: frame plan") && err.contains("hit_buffer: on (camera static)"), "{err}");

    let gif = d.join("car.gif");
    let mut args = vec!["render", "--frames", "4", "--out", s(&gif), "--orbit", "30"];
    args.extend(common);
    let o = voxray(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    use image::AnimationDecoder;
    let dec = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(std::fs::File::open(&gif).unwrap())).unwrap();
    assert_eq!(dec.into_frames().count(), 4);
    assert!(String::from_utf8_lossy(&o.stderr).contains("0.0% of pixels reused"), "a moving camera reuses nothing");
}

#[test]
fn switches_static_car_and_many_cars() {
    let d = tmp("switch");
    let cache = d.join("cache");
    let out = d.join("x.png");
    let run = |extra: &[&str]| {
        let mut args = vec![
            "render",
            "--depth",
            "6",
            "--width",
            "32",
            "--height",
            "24",
            "--cache-dir",
            s(&cache),
            "--out",
            s(&out),
        ];
        args.extend(extra);
        let o = voxray(&args);
        (o.status.code(), String::from_utf8_lossy(&o.stderr).to_string())
    };
    let (code, err) =
        run(&["--explain", "--no-cull", "--no-sort", "--no-bvh", "--no-hit-buffer", "--no-shadows", "--frames", "2"]);
    assert_eq!(code, Some(0), "{err}");
    for f in ["cull", "bvh", "sort", "hit_buffer", "shadows"] {
        assert!(err.contains(&format!("{f}: off (switched off)")), "{f}: {err}");
    }
    let (code, err) = run(&["--static-car", "--no-ground", "--explain"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(
        err.contains("1 instances") && err.contains("car (static)") && err.contains("cull: off (one instance"),
        "{err}"
    );
    assert!(err.contains("transform: off"), "a single identity instance needs no ray transformation: {err}");
    let (code, err) = run(&["--cars", "5", "--explain"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("41 instances") && err.contains("bvh: on"), "{err}");
    let (code, err) = run(&["--cars", "2", "--obj", "models/test/cube.obj"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("default car only"), "{err}");
    let gif = d.join("one.gif");
    let o = voxray(&[
        "render",
        "--depth",
        "6",
        "--width",
        "32",
        "--height",
        "24",
        "--cache-dir",
        s(&cache),
        "--out",
        s(&gif),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("--frames 2 or more"), "{err}");
}

#[test]
fn gpu_backend_writes_the_same_aovs_as_the_cpu() {
    let d = tmp("backend");
    let cache = d.join("cache");
    let run = |backend: &str| {
        let aov = d.join(format!("aov_{backend}"));
        let png = d.join(format!("{backend}.png"));
        let o = voxray(&[
            "render",
            "--backend",
            backend,
            "--depth",
            "6",
            "--width",
            "64",
            "--height",
            "40",
            "--frames",
            "2",
            "--cache-dir",
            s(&cache),
            "--out",
            s(&png),
            "--aov-dir",
            s(&aov),
        ]);
        (o, aov)
    };
    let (cpu, cpu_aov) = run("cpu");
    assert!(cpu.status.success(), "{}", String::from_utf8_lossy(&cpu.stderr));
    let (gpu, gpu_aov) = run("gpu");
    let err = String::from_utf8_lossy(&gpu.stderr);
    if !gpu.status.success() && err.contains("no GPU adapter") && std::env::var("CI").map_or(true, |v| v != "true") {
        eprintln!("skipping: {err}");
        return;
    }
    assert!(gpu.status.success(), "{err}");
    assert!(err.contains("backend: GPU"), "{err}");
    for f in 0..2 {
        let frame = format!("frame_{f:04}");
        let (_, _, ic) = read_npy(&cpu_aov.join(&frame).join("instance.npy"));
        let (_, _, ig) = read_npy(&gpu_aov.join(&frame).join("instance.npy"));
        let (tc, tg) = (
            f32s(&read_npy(&cpu_aov.join(&frame).join("t.npy")).2),
            f32s(&read_npy(&gpu_aov.join(&frame).join("t.npy")).2),
        );
        let same = ic.chunks(4).zip(ig.chunks(4)).filter(|(a, b)| a == b).count();
        assert!(same * 10_000 >= (ic.len() / 4) * 9_999, "frame {f}: {same} of {} instance ids agree", ic.len() / 4);
        for (a, b) in tc.iter().zip(&tg) {
            assert!(a == b || ((a - b) / a).abs() <= 1e-4, "frame {f}: t {a} vs {b}");
        }
    }
}

#[test]
fn shards_and_resume_give_the_frames_of_one_run() {
    let d = tmp("shards");
    let cache = d.join("cache");
    let clip = |out: &Path, extra: &[&str]| {
        let mut args = vec!["render", "--depth", "6", "--frames", "7", "--width", "64", "--height", "40"];
        args.extend_from_slice(&["--cache-dir", s(&cache), "--out", s(out)]);
        args.extend_from_slice(extra);
        let o = voxray(&args);
        assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let (one, many) = (d.join("one/f.png"), d.join("many/f.png"));
    clip(&one, &[]);
    for i in 0..3 {
        clip(&many, &["--shard", &format!("{i}/3")]);
    }
    let frame = |p: &Path, f: u32| std::fs::read(p.with_file_name(format!("f_{f:04}.png"))).unwrap();
    for f in 0..7 {
        assert_eq!(frame(&one, f), frame(&many, f), "frame {f}: three shards give the single run's image");
    }
    // A frame range renders only its frames, named by their place in the clip.
    let part = d.join("part/f.png");
    clip(&part, &["--frame-range", "2..4"]);
    let names: Vec<String> = std::fs::read_dir(part.parent().unwrap())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into())
        .collect();
    assert_eq!(names.len(), 2, "{names:?}");
    assert_eq!(frame(&part, 3), frame(&one, 3));
    // Resume: a missing frame and a truncated one are rendered again, the rest skipped.
    std::fs::remove_file(many.with_file_name("f_0001.png")).unwrap();
    std::fs::write(many.with_file_name("f_0005.png"), &frame(&one, 5)[..60]).unwrap();
    let log = clip(&many, &["--resume"]);
    assert!(log.contains("2 to render (5 of this range already written)"), "{log}");
    for f in 0..7 {
        assert_eq!(frame(&one, f), frame(&many, f), "frame {f} after resume");
    }
    // Bad ranges and shards are refused before anything is rendered.
    for (flag, value) in
        [("--shard", "3/3"), ("--shard", "1/0"), ("--shard", "x"), ("--frame-range", "5..3"), ("--frame-range", "0..8")]
    {
        let o = voxray(&["render", "--frames", "7", "--out", s(&d.join("bad/f.png")), flag, value]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(flag), "{flag} {value}: {err}");
    }
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn gltf_and_vox_scenes_render_and_animate() {
    let d = tmp("scenes");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let gltf = root.join("models/third-party/BoxAnimated/BoxAnimated.gltf");
    let vox = root.join("models/third-party/dot_vox/axes.vox");
    let o = voxray(&[
        "render",
        "--scene",
        s(&gltf),
        "--animation",
        "all",
        "--depth",
        "6",
        "--frames",
        "3",
        "--fps",
        "1",
        "--width",
        "64",
        "--height",
        "48",
        "--cache-dir",
        s(&d.join("cache")),
        "--out",
        s(&d.join("box/b.png")),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let frames: Vec<Vec<u8>> = (0..3).map(|f| std::fs::read(d.join(format!("box/b_{f:04}.png"))).unwrap()).collect();
    assert!(frames[0] != frames[1] && frames[1] != frames[2], "the animation moves the boxes");
    let o = voxray(&["render", "--scene", s(&vox), "--width", "64", "--height", "48", "--out", s(&d.join("axes.png"))]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stderr).contains("model 3"), "the model table is printed");
    // Errors name the problem.
    let o = voxray(&["render", "--scene", s(&gltf), "--animation", "spin", "--out", s(&d.join("x.png"))]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("no such animation") && err.contains("'animation 1'"), "{err}");
    let o = voxray(&["render", "--scene", s(&vox), s(&gltf), "--out", s(&d.join("x.png"))]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("give it alone"));
    std::fs::write(d.join("notes.txt"), "hello").unwrap();
    let o = voxray(&["render", "--scene", s(&d.join("notes.txt")), "--out", s(&d.join("x.png"))]);
    // No magic number and no known extension: read as OBJ (which has none), whose loader says
    // what is wrong.
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("no non-degenerate triangles"));
    std::fs::remove_dir_all(&d).ok();
}

/// The radiance-cache gather from the command line: it renders the box and reports where its
/// time went; bad knobs are refused by name; the GPU renders it too.
#[test]
fn radiance_caches_render_and_refuse_bad_knobs() {
    let d = tmp("caches");
    let out = s(&d.join("caches.png")).to_string();
    let box_args = [
        "--obj",
        "models/box/box.obj",
        "--camera-json",
        "models/box/camera.json",
        "--lights-json",
        "models/box/lights.json",
        "--width",
        "48",
        "--height",
        "36",
        "--no-cache",
        "--gi",
        "--gi-res",
        "32",
        "--gi-gather",
        "caches",
        "--out",
        &out,
    ];
    let o = voxray(&[&["render", "--backend", "cpu"][..], &box_args[..]].concat());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("GI radiance caches:") && err.contains("cache tracing"), "{err}");
    assert!(std::fs::metadata(&out).is_ok_and(|m| m.len() > 0));
    for (knob, value, says) in [
        ("--gi-cache-res", "12", "cache map resolution must be 4, 8, 16 or 32, not 12"),
        ("--gi-cache-tile", "2", "cache tile must be 4…128 pixels, not 2"),
        ("--gi-cache-count", "0", "caches per tile must be 1…16, not 0"),
        ("--gi-cache-radius", "9", "cache gathering radius must be 1…8 tiles, not 9"),
        ("--gi-cache-placement", "random", "unknown cache placement 'random'"),
        ("--gi-cache-cone", "0", "cache cone width must be 5…100 % of a texel's, not 0"),
    ] {
        let o = voxray(&[&["render", "--backend", "cpu", knob, value][..], &box_args[..]].concat());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{knob} {value} was accepted");
        assert!(err.contains(says), "{knob} {value}: {err}");
        // Refused before the parts are voxelized (their table), not after.
        assert!(!err.contains("triangles"), "{knob} {value} was refused after voxelizing: {err}");
    }
    std::fs::remove_file(&out).unwrap();
    let o = voxray(&[&["render", "--backend", "gpu"][..], &box_args[..]].concat());
    let err = String::from_utf8_lossy(&o.stderr);
    // Without any Vulkan adapter (outside CI) the GPU backend cannot start at all.
    if err.contains("adapter") && !std::env::var("CI").is_ok_and(|v| v == "true") {
        return;
    }
    assert!(o.status.success(), "{err}");
    assert!(std::fs::metadata(&out).is_ok_and(|m| m.len() > 0));
}
