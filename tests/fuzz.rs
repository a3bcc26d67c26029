//! A mutation fuzzer over the inputs a user hands voxray: OBJ with its MTL, `.svo` files
//! (with their checksum recomputed, so mutations reach the structure checks behind it) and
//! the camera and lights JSON. Every mutated input must give a result or a typed error,
//! never a panic; what loads is voxelized and built too.
//!
//! Cases per input kind: 300 by default, `VOXRAY_FUZZ_CASES=n` for more. The mutations are
//! seeded, so a failure names a case that replays.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use voxray::mesh::{load_obj_text, MeshError};
use voxray::rng::Rng;
use voxray::scene::{Camera, Lights};
use voxray::voxelize::{voxelize, Resolution, VoxelizeOptions};

fn cases() -> usize {
    std::env::var("VOXRAY_FUZZ_CASES").ok().and_then(|s| s.parse().ok()).unwrap_or(300)
}

/// Tokens that often break parsers of these formats.
const TOKENS: &[&str] = &[
    "nan",
    "inf",
    "-inf",
    "-1",
    "0",
    "1e39",
    "-1e39",
    "1e-45",
    "4294967296",
    "-2147483649",
    "999999999999",
    "/",
    "//",
    "///",
    " ",
    "\n",
    "\t",
    "\r\n",
    "f",
    "v",
    "vn",
    "vt",
    "o",
    "g",
    "s",
    "usemtl",
    "mtllib",
    "newmtl",
    "Kd",
    "Ke",
    "Ks",
    "Ns",
    "map_Kd",
    "#",
    "\\",
    "\u{feff}",
    "é",
    "\0",
    "{",
    "}",
    "[",
    "]",
    ":",
    ",",
    "\"",
    "null",
    "true",
    "1.5",
    "-0",
    "0x10",
    "1,2,3",
];

/// One mutation of `seed`: flip, insert a token, delete, duplicate or truncate (1–4 times).
fn mutate(rng: &mut Rng, seed: &[u8]) -> Vec<u8> {
    let mut b = seed.to_vec();
    for _ in 0..1 + rng.below(4) {
        let at = |rng: &mut Rng, len: usize| rng.below(len as u64 + 1) as usize;
        match rng.below(6) {
            0 if !b.is_empty() => {
                let i = at(rng, b.len() - 1);
                b[i] ^= 1 << rng.below(8);
            }
            1 => {
                let i = at(rng, b.len());
                let t = TOKENS[rng.below(TOKENS.len() as u64) as usize].as_bytes();
                b.splice(i..i, t.iter().copied());
            }
            2 if !b.is_empty() => {
                let i = at(rng, b.len() - 1);
                let n = (1 + rng.below(16) as usize).min(b.len() - i);
                b.drain(i..i + n);
            }
            3 if !b.is_empty() => {
                let i = at(rng, b.len() - 1);
                let n = (1 + rng.below(64) as usize).min(b.len() - i);
                let piece = b[i..i + n].to_vec();
                let j = at(rng, b.len());
                b.splice(j..j, piece);
            }
            4 => {
                let n = at(rng, b.len());
                b.truncate(n);
            }
            _ if !b.is_empty() => {
                // A random byte anywhere.
                let i = at(rng, b.len() - 1);
                b[i] = rng.below(256) as u8;
            }
            _ => {}
        }
    }
    b
}

/// Runs `f` on `cases()` mutations of `seed`; returns how many loaded, and the panics.
fn fuzz(name: &str, seed: &[u8], salt: u64, f: &dyn Fn(&[u8]) -> bool) -> (usize, Vec<String>) {
    let mut rng = Rng::new(0x5eed ^ salt);
    let (mut loaded, mut panics) = (0, Vec::new());
    for case in 0..cases() {
        let input = mutate(&mut rng, seed);
        match catch_unwind(AssertUnwindSafe(|| f(&input))) {
            Ok(ok) => loaded += ok as usize,
            Err(p) => {
                let msg = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                panics.push(format!("{name} case {case}: {msg}\n--- input ---\n{}", String::from_utf8_lossy(&input)));
            }
        }
    }
    (loaded, panics)
}

/// Loads OBJ text with one MTL file; what loads is voxelized coarsely and built.
fn obj_with_mtl(obj: &[u8], mtl: &[u8]) -> bool {
    let text = String::from_utf8_lossy(obj);
    let mtl = String::from_utf8_lossy(mtl).to_string();
    let read = |_: &Path| -> Result<String, MeshError> { Ok(mtl.clone()) };
    let Ok(mesh) = load_obj_text(&text, "fuzz.obj", "fuzz", None, &read) else { return false };
    let opts = VoxelizeOptions { resolution: Resolution::Depth(4), solid: false };
    for part in &mesh.parts {
        if let Ok(grid) = voxelize(part, &mesh.materials, &opts, &|_, _| {}) {
            let _ = voxray::svo::build(&grid);
        }
    }
    true
}

#[test]
fn mutated_inputs_never_panic() {
    // Panics are caught and reported below; the default hook would print every one.
    std::panic::set_hook(Box::new(|_| {}));
    let obj = std::fs::read("models/test/two_parts.obj").unwrap();
    let mtl = std::fs::read("models/test/two_parts.mtl").unwrap();
    let cube_obj = std::fs::read("models/test/cube.obj").unwrap();
    let cube_mtl = std::fs::read("models/test/cube.mtl").unwrap();
    // A polygon face with normals and texture coordinates, for the face paths.
    let poly = b"mtllib m.mtl\nv 0 0 0\nv 4 0 0\nv 4 4 0\nv 2 1 0\nv 0 4 0\nvt 0 0\nvt 1 1\nvn 0 0 1\n\
                 usemtl m\nf 3/1/1 4/2/1 5/1/1 1/2/1 2/1/1\n"
        .to_vec();
    let poly_mtl = b"newmtl m\nKd 0.5 0.6 0.7\nKe 1 2 3\nKs 0.1 0.1 0.1\nNs 40\nd 1\nillum 2\n".to_vec();

    let mut report = Vec::new();
    let mut all_panics = Vec::new();
    let mut run = |name: &str, seed: &[u8], salt: u64, f: &dyn Fn(&[u8]) -> bool| {
        let (loaded, panics) = fuzz(name, seed, salt, f);
        report.push(format!("{name}: {} cases, {loaded} loaded, {} panics", cases(), panics.len()));
        all_panics.extend(panics);
        loaded
    };
    run("OBJ (two parts)", &obj, 1, &|b| obj_with_mtl(b, &mtl));
    run("MTL (two parts)", &mtl, 2, &|b| obj_with_mtl(&obj, b));
    run("OBJ (cube)", &cube_obj, 3, &|b| obj_with_mtl(b, &cube_mtl));
    run("OBJ (polygon)", &poly, 4, &|b| obj_with_mtl(b, &poly_mtl));
    run("MTL (polygon)", &poly_mtl, 5, &|b| obj_with_mtl(&poly, b));

    // .svo: the cube's SVO, mutated, its checksum made right again.
    let mesh = voxray::mesh::load_obj(Path::new("models/test/cube.obj")).unwrap();
    let opts = VoxelizeOptions { resolution: Resolution::Depth(5), solid: false };
    let svo = voxray::svo::build(&voxelize(&mesh.parts[0], &mesh.materials, &opts, &|_, _| {}).unwrap()).unwrap();
    let bytes = voxray::svo::io::to_bytes(&svo);
    let svo_loaded = run("SVO", &bytes, 6, &|b| {
        let mut b = b.to_vec();
        if b.len() >= 4 {
            let body = b.len() - 4;
            let crc = voxray::svo::io::crc32(&b[..body]);
            b[body..].copy_from_slice(&crc.to_le_bytes());
        }
        match voxray::svo::io::from_bytes(&b) {
            Ok(s) => {
                // What loads must be traversable.
                let r = voxray::ray::Ray { origin: glam::Vec3::splat(-1.0), dir: glam::Vec3::ONE };
                let _ = voxray::traverse::trace(&s, &r, &Default::default());
                true
            }
            Err(_) => false,
        }
    });

    let camera = br#"{"eye":[4,3,5],"target":[0,0.5,0],"up":[0,1,0],"vfov_deg":50,"width":64,"height":48}"#;
    run("camera JSON", camera, 7, &|b| Camera::from_json(&String::from_utf8_lossy(b)).is_ok());
    let lights = br#"{"sun":{"to_sun":[0.4,1,0.3],"irradiance":[3,3,3]},"ambient":{"radiance":[0.2,0.3,0.4]},"emitter_samples":4,"points":[{"position":[1,2,3],"intensity":[5,5,5]}],"spots":[{"position":[0,3,0],"direction":[0,-1,0],"intensity":[9,9,9],"inner_deg":20,"outer_deg":30}]}"#;
    run("lights JSON", lights, 8, &|b| Lights::from_json(&String::from_utf8_lossy(b)).is_ok());

    let _ = std::panic::take_hook();
    println!("{}", report.join("\n"));
    assert!(all_panics.is_empty(), "{} panics; the first:\n{}", all_panics.len(), all_panics[0]);
    // Mutations must not all be rejected at the door, or the fuzzer tests only the door.
    assert!(svo_loaded > 0, "no mutated .svo loaded: {report:?}");
}
