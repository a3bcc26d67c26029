//! The .svo format: round trips, large and deep trees, depth limits, version 1 and 2 files
//! converted on load, and corrupted files giving typed errors (never a panic, never a huge
//! allocation).

use glam::{DVec3, Vec3};
use voxray::oracle::{dda, Contact, VoxelSet};
use voxray::ray::UnitRay;
use voxray::rng::Rng;
use voxray::svo::io::{crc32, from_bytes, to_bytes, validate, SvoFileError, HEADER_LEN, HEADER_LEN_4};
use voxray::svo::{self, Cube, Svo};
use voxray::traverse::{trace_unit, TraceOptions};
use voxray::voxelize::VoxelGrid;

fn unit() -> Cube {
    Cube { min: Vec3::ZERO, size: 1.0 }
}

fn random_svo(depth: u32, n: usize, seed: u64) -> (Svo, Vec<[u32; 3]>) {
    let mut rng = Rng::new(seed);
    let side = 1u64 << depth;
    let coords: Vec<[u32; 3]> = (0..n).map(|_| [0; 3].map(|_: u32| rng.below(side) as u32)).collect();
    let grid = VoxelGrid::from_coords(depth, unit(), coords.iter().copied(), Vec3::splat(0.5));
    (svo::build(&grid).unwrap(), coords)
}

/// Re-seals bytes after tampering so that structural validation, not the checksum, is tested.
fn reseal(b: &mut [u8]) {
    let n = b.len() - 4;
    let c = crc32(&b[..n]);
    b[n..].copy_from_slice(&c.to_le_bytes());
}

/// Flips `tries` random bits within `region` of a file (one at a time, the checksum resealed)
/// and counts the typed structural errors; a flip that loads must give a valid tree, and
/// any other error kind fails.
fn corruptions_caught(bytes: &[u8], region: std::ops::Range<usize>, tries: usize, seed: u64) -> usize {
    let mut rng = Rng::new(seed);
    let mut caught = 0;
    for _ in 0..tries {
        let mut b = bytes.to_vec();
        b[region.start + rng.below(region.len() as u64) as usize] ^= 1 << rng.below(8);
        reseal(&mut b);
        match from_bytes(&b) {
            Err(SvoFileError::Node { .. }) | Err(SvoFileError::Header(_)) => caught += 1,
            Err(e) => panic!("unexpected error kind {e}"),
            Ok(t) => validate(&t).unwrap(),
        }
    }
    caught
}

#[test]
fn round_trip_is_identical() {
    let (s, _) = random_svo(6, 3000, 1);
    let back = from_bytes(&to_bytes(&s)).unwrap();
    assert_eq!(back, s);
    let dir = std::env::temp_dir().join(format!("voxray-svo-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("a.svo");
    svo::io::save(&s, &p).unwrap();
    assert_eq!(svo::io::load(&p).unwrap(), s);
    assert!(matches!(svo::io::load(&dir.join("missing.svo")), Err(SvoFileError::Io { .. })));
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn every_single_byte_flip_and_truncation_is_an_error() {
    let (s, _) = random_svo(4, 60, 2);
    let bytes = to_bytes(&s);
    for i in 0..bytes.len() {
        for bit in [0x01u8, 0x80] {
            let mut b = bytes.clone();
            b[i] ^= bit;
            assert!(from_bytes(&b).is_err(), "flip of bit {bit:#x} at byte {i} accepted");
        }
    }
    for len in 0..bytes.len() {
        assert!(from_bytes(&bytes[..len]).is_err(), "truncation to {len} accepted");
    }
    let mut longer = bytes.clone();
    longer.push(0);
    assert!(matches!(from_bytes(&longer), Err(SvoFileError::Length { .. })));
}

#[test]
fn hostile_headers_and_structures_are_refused() {
    let (s, _) = random_svo(5, 400, 3);
    let bytes = to_bytes(&s);
    // Absurd counts: must not allocate, must say the length is wrong.
    let mut b = bytes.clone();
    b[40..48].copy_from_slice(&u64::MAX.to_le_bytes());
    reseal(&mut b);
    assert!(matches!(from_bytes(&b), Err(SvoFileError::Length { .. })));
    // Version, depth and bounds.
    let mut b = bytes.clone();
    b[8] = 9;
    reseal(&mut b);
    let e = from_bytes(&b).unwrap_err();
    assert!(matches!(e, SvoFileError::Version(9)));
    assert!(
        e.to_string().contains("reads versions 1 to 4") && e.to_string().contains("a newer voxray wrote it"),
        "{e}"
    );
    b[8] = 0;
    reseal(&mut b);
    let e = from_bytes(&b).unwrap_err();
    assert!(e.to_string().contains("no voxray writes version 0"), "{e}");
    let mut b = bytes.clone();
    b[12..16].copy_from_slice(&40u32.to_le_bytes());
    reseal(&mut b);
    assert!(matches!(from_bytes(&b), Err(SvoFileError::Header(_))));
    let mut b = bytes.clone();
    b[28..32].copy_from_slice(&f32::NAN.to_le_bytes());
    reseal(&mut b);
    assert!(matches!(from_bytes(&b), Err(SvoFileError::Header(_))));
    // Denormal and zero-like sizes, and bounds whose corner rounding exceeds a voxel.
    for (min, size) in [(0.0f32, 1e-40f32), (0.0, f32::MIN_POSITIVE), (1e30, 1.0), (1e6, 1e-3)] {
        let mut b = bytes.clone();
        b[16..20].copy_from_slice(&min.to_le_bytes());
        b[28..32].copy_from_slice(&size.to_le_bytes());
        reseal(&mut b);
        let e = from_bytes(&b).unwrap_err();
        assert!(
            matches!(e, SvoFileError::Header(_)) && e.to_string().contains("not representable"),
            "{min} {size}: {e}"
        );
    }
    assert!(matches!(from_bytes(b"not an svo file at all"), Err(SvoFileError::BadMagic)));
    // Every corruption of a child mask that keeps the checksum valid must be caught by the
    // structural checks (the masks no longer describe the stored counts) or leave a tree that
    // still validates.
    let caught = corruptions_caught(&bytes, HEADER_LEN_4..HEADER_LEN_4 + s.masks.len(), 2000, 9);
    assert!(caught > 1000, "only {caught} of 2000 structural corruptions detected");
}

#[test]
fn a_large_random_tree_traverses_like_the_oracle() {
    // ~120k voxels at depth 9: every level wide, links far from their nodes.
    let (s, coords) = random_svo(9, 120_000, 4);
    validate(&s).unwrap();
    assert_eq!(from_bytes(&to_bytes(&s)).unwrap(), s);
    let set = VoxelSet::new(9, coords);
    let mut rng = Rng::new(5);
    for _ in 0..3000 {
        let o = Vec3::new(rng.range(-0.5, 1.5), rng.range(-0.5, 1.5), rng.range(-0.5, 1.5));
        let d = rng.unit_vector();
        let got = UnitRay::from_unit(o.as_dvec3(), d.as_dvec3())
            .and_then(|u| trace_unit(&s, &u, &TraceOptions::default()).hit);
        let want = dda(&set, o.as_dvec3(), d.as_dvec3(), 0.0, f64::INFINITY, Contact::Closed);
        assert_eq!(got.map(|h| h.coord), want.map(|w| w.coord), "ray {o} {d}");
    }
}

#[test]
fn depth_16_and_20_trees_build_and_trace() {
    for depth in [16u32, 20] {
        // A diagonal line of voxels through the whole grid plus a blob near the far corner.
        let n = 1u32 << depth;
        let mut coords: Vec<[u32; 3]> = (0..4096u32).map(|i| [i * (n / 4096); 3]).collect();
        coords.extend((0..512u32).map(|i| [n - 1 - i % 8, n - 1 - (i / 8) % 8, n - 1 - i / 64]));
        let grid = VoxelGrid::from_coords(depth, unit(), coords.iter().copied(), Vec3::ONE);
        let s = svo::build(&grid).unwrap();
        assert_eq!(s.depth, depth);
        assert_eq!(from_bytes(&to_bytes(&s)).unwrap(), s);
        // Aim axis-parallel rays at individual voxels of the line; each must hit exactly it.
        for &c in coords[..4096].iter().step_by(97) {
            let centre = DVec3::new(c[0] as f64 + 0.5, c[1] as f64 + 0.5, c[2] as f64 + 0.5) / n as f64;
            let o = DVec3::new(centre.x, centre.y, -0.25);
            let u = UnitRay::from_unit(o, DVec3::Z).unwrap();
            let hit = trace_unit(&s, &u, &TraceOptions::default()).hit.expect("hit");
            assert_eq!(hit.coord, c, "depth {depth}");
            let expect_t = 0.25 + c[2] as f64 / n as f64;
            assert!((hit.t as f64 - expect_t).abs() <= 1e-6 * expect_t, "depth {depth}: t {} vs {expect_t}", hit.t);
        }
    }
    // Beyond the supported depth: a clear error.
    let grid = VoxelGrid::from_coords(21, unit(), [[0, 0, 0]], Vec3::ONE);
    assert_eq!(svo::build(&grid), Err(svo::BuildError::Depth(21)));
}

#[test]
fn interior_nodes_average_their_children() {
    let mut grid = VoxelGrid::from_coords(1, unit(), [[0, 0, 0], [1, 1, 1]], Vec3::ZERO);
    grid.voxels[0].albedo = Vec3::new(1.0, 0.0, 0.0);
    grid.voxels[1].albedo = Vec3::new(0.0, 0.0, 1.0);
    let s = svo::build(&grid).unwrap();
    let root = s.attrs[0].albedo_linear();
    assert!((root - Vec3::new(0.5, 0.0, 0.5)).abs().max_element() < 0.01, "{root}");
    // LOD 0 returns the root with the averaged colour.
    let u = UnitRay::from_unit(DVec3::new(0.5, 0.5, -1.0), DVec3::Z).unwrap();
    let hit = trace_unit(&s, &u, &TraceOptions { max_level: 0, ..Default::default() }).hit.unwrap();
    assert_eq!(hit.level, 0);
    assert!((hit.t - 1.0).abs() < 1e-6);
}

/// The voxels of the committed version 1 and 2 files in tests/data (written by the version 2
/// builder): a depth-5 grid with attributes that vary per voxel.
fn legacy_grid() -> VoxelGrid {
    let n = 32u32;
    let mut coords = Vec::new();
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                if (x * 7 + y * 13 + z * 29) % 37 == 0 || (x == 3 && y < 20) {
                    coords.push([x, y, z]);
                }
            }
        }
    }
    let mut g = VoxelGrid::from_coords(5, Cube { min: Vec3::new(-1.0, 0.5, 2.0), size: 3.0 }, coords, Vec3::ZERO);
    for v in &mut g.voxels {
        let [x, y, z] = svo::format::morton_decode(v.code);
        let h = n as f32 / 2.0;
        v.albedo = Vec3::new(x as f32, y as f32, z as f32) / n as f32;
        v.normal = Vec3::new(x as f32 - h + 0.25, y as f32 - h, z as f32 - h);
        v.specular = ((x + y) % 5) as f32 / 8.0;
        v.gloss = (z % 4) as f32 / 3.0;
        v.emission = if (x + y + z) % 7 == 0 { Vec3::new(2.0, 1.0, 0.5) } else { Vec3::ZERO };
        v.weight = 1.0 + (x % 3) as f32;
    }
    g
}

fn fixture(name: &str) -> Vec<u8> {
    std::fs::read(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name)).unwrap()
}

/// A version 2 file (Laine–Karras descriptors, attribute bases, depth-first layout) loads as
/// exactly the tree the current builder makes from the same voxels, except that its emission
/// was a multiple of the albedo (version 4 keeps the emitted colour itself): the same voxels
/// emit, with the radiance the old scale gave. So does a version 1 file (snorm16 normals), up
/// to the re-encoded normals.
#[test]
fn version_1_and_2_files_are_converted() {
    let want = svo::build(&legacy_grid()).unwrap();
    let v2 = fixture("legacy-v2.svo");
    assert_eq!(u32::from_le_bytes(v2[8..12].try_into().unwrap()), 2);
    let got = from_bytes(&v2).unwrap();
    let strip = |t: &svo::Svo| svo::Svo {
        attrs: t.attrs.iter().map(|a| svo::Attr { emission: 0, ..*a }).collect(),
        ..t.clone()
    };
    assert_eq!(strip(&got), strip(&want));
    let mut emissive = 0;
    for (old, new) in got.attrs.iter().zip(&want.attrs) {
        // The old scale multiplied the albedo: a black emitter emitted nothing.
        assert!(!old.is_emissive() || new.is_emissive());
        assert!(old.is_emissive() || !new.is_emissive() || old.albedo_linear().max_element() < 0.01);
        if old.is_emissive() {
            emissive += 1;
            // The old scale: the luminance ratio to the albedo, in sixteenths.
            let (e, a) = (old.emission(), old.albedo_linear());
            let k = e.dot(a) / a.dot(a);
            // Within RGB9E5's step (1/256 of the largest channel at worst).
            assert!((e - a * k).abs().max_element() <= e.max_element() / 256.0, "{e} is not a multiple of {a}");
        }
    }
    assert!(emissive > 0);

    let v1 = from_bytes(&fixture("legacy-v1.svo")).unwrap();
    assert_eq!((&v1.masks, &v1.links, v1.voxel_count), (&want.masks, &want.links, want.voxel_count));
    for (old, new) in v1.attrs.iter().zip(&want.attrs) {
        assert_eq!(old.albedo & 0xFF_FFFF, new.albedo & 0xFF_FFFF);
        assert_eq!(old.specular(), 0.0);
        assert!(old.normal().dot(new.normal()) > 0.1f32.to_radians().cos(), "{} vs {}", old.normal(), new.normal());
    }

    // A corrupted descriptor is refused with a typed error (or still converts to a valid tree).
    let nodes = u64::from_le_bytes(v2[40..48].try_into().unwrap()) as usize;
    let caught = corruptions_caught(&v2, HEADER_LEN..HEADER_LEN + 8 * nodes, 1000, 11);
    assert!(caught > 500, "only {caught} of 1000 corrupted descriptors detected");
}

/// Version 4 keeps a part's emissive triangles and RGB emission through a file, and refuses a
/// file whose emitter is degenerate or negative.
#[test]
fn emitters_and_rgb_emission_round_trip() {
    let (mut s, _) = random_svo(5, 300, 21);
    s.emitters = vec![
        svo::Emitter { vertices: [Vec3::ZERO, Vec3::X, Vec3::Y], emission: Vec3::new(17.0, 12.0, 4.0) },
        svo::Emitter { vertices: [Vec3::Z, Vec3::ONE, Vec3::X], emission: Vec3::new(0.0, 0.0, 900.0) },
    ];
    s.attrs[3] = svo::Attr::pack(Vec3::splat(0.78), Vec3::Y, Vec3::new(17.0, 12.0, 4.0));
    let bytes = to_bytes(&s);
    let back = from_bytes(&bytes).unwrap();
    assert_eq!(back, s);
    assert!((back.attrs[3].emission() - Vec3::new(17.0, 12.0, 4.0)).abs().max_element() < 0.04);
    // The last emitter's first corner x, set to NaN, and its emission's red, set negative.
    let at = bytes.len() - 4 - 48;
    for (offset, v) in [(0usize, f32::NAN), (36, -1.0)] {
        let mut b = bytes.clone();
        b[at + offset..at + offset + 4].copy_from_slice(&v.to_le_bytes());
        reseal(&mut b);
        let e = from_bytes(&b).unwrap_err();
        assert!(e.to_string().contains("emissive triangle 1"), "{e}");
    }
    // A collapsed triangle (second corner on the first).
    let mut b = bytes.clone();
    b[at + 12..at + 24].copy_from_slice(&bytes[at..at + 12]);
    reseal(&mut b);
    assert!(from_bytes(&b).is_err());
}
