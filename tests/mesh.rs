//! OBJ/MTL loading: parts, materials, textures, and clear typed errors for bad input.

mod common;

use common::TempDir;
use glam::{Vec2, Vec3};
use std::path::{Path, PathBuf};
use voxray::mesh::{load_obj, MeshError};
use voxray::voxelize::{voxelize, Resolution, VoxelizeOptions};

fn tmp(name: &str) -> TempDir {
    TempDir::new("voxray-mesh", name)
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn parts_materials_and_degenerates() {
    let m = load_obj(Path::new("models/test/two_parts.obj")).unwrap();
    let names: Vec<&str> = m.parts.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["left", "right"]);
    assert_eq!(m.parts[0].triangles.len(), 2, "material change must not split the part");
    assert_eq!(m.degenerate_skipped, 1);
    let mat = |p: usize, t: usize| &m.materials[m.parts[p].triangles[t].material as usize];
    assert_eq!(mat(0, 0).name, "red");
    assert_eq!(mat(0, 1).name, "green");
    assert_eq!(mat(1, 0).emission, Vec3::splat(5.0));
    let cube = load_obj(Path::new("models/test/cube.obj")).unwrap();
    assert_eq!(cube.triangle_count(), 12);
    assert_eq!(cube.materials[cube.parts[0].triangles[0].material as usize].albedo, Vec3::new(0.1, 0.2, 0.8));
}

#[test]
fn missing_files_name_the_file() {
    let e = load_obj(Path::new("models/test/nope.obj")).unwrap_err();
    assert!(matches!(&e, MeshError::NotFound { path } if path.contains("nope.obj")), "{e}");
    let d = tmp("mtl");
    let p = write(&d, "a.obj", "mtllib gone.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let e = load_obj(&p).unwrap_err();
    assert!(e.to_string().contains("gone.mtl"), "{e}");
}

#[test]
fn parse_errors_carry_line_numbers() {
    let d = tmp("parse");
    let cases = [
        ("v 0 0 0\nv 1 zero 0\n", 2, "not a number"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", 4, "out of range"),
        ("v 0 0 0\nv 1 0 0\nf 1 2\n", 3, "at least 3"),
        ("v 0 0\n", 1, "needs 3"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n", 4, "out of range"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//2\n", 5, "out of range (1 normals"),
        ("v 0 0 0\nvn 0 nan 1\n", 2, "'vn' needs 3 finite numbers"),
    ];
    for (i, (text, line, what)) in cases.iter().enumerate() {
        let p = write(&d, &format!("bad{i}.obj"), text);
        let e = load_obj(&p).unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, MeshError::Parse { line: Some(l), .. } if l == *line), "case {i}: {msg}");
        assert!(msg.contains(what) && msg.contains(&format!("bad{i}.obj:{line}")), "case {i}: {msg}");
    }
    // MTL errors name their file and line too; tobj panicked on a colour of fewer than three
    // numbers.
    let obj = write(&d, "m.obj", "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n");
    for (i, (mtl, what)) in [
        ("newmtl m\nKd 0.5\n", "'Kd' needs 3 numbers"),
        ("newmtl m\nKd 1 1 1\nNs\n", "'Ns' needs a number"),
        ("newmtl m\nKe 1 x 1\n", "'x' is not a number"),
        ("newmtl m\nKs 1 inf 1\n", "'inf' is not finite"),
    ]
    .iter()
    .enumerate()
    {
        write(&d, "m.mtl", mtl);
        let e = load_obj(&obj).unwrap_err();
        let msg = e.to_string();
        let line = mtl.lines().count();
        assert!(matches!(e, MeshError::Parse { line: Some(l), .. } if l == line), "MTL case {i}: {msg}");
        assert!(msg.contains(what) && msg.contains(&format!("m.mtl:{line}")), "MTL case {i}: {msg}");
    }
    // A usemtl naming no material is a warning with its line, not a silent grey.
    write(&d, "m.mtl", "newmtl m\nKd 1 0 0\n");
    let p = write(&d, "u.obj", "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl nothere\nf 1 2 3\n");
    let m = load_obj(&p).unwrap();
    assert!(m.warnings.iter().any(|w| w.contains("u.obj:5: usemtl 'nothere' names no material")), "{:?}", m.warnings);
}

#[test]
fn non_finite_coordinates_name_line_and_object() {
    let d = tmp("nan");
    for bad in ["nan", "inf", "-inf", "NaN"] {
        let p = write(&d, "n.obj", &format!("o good\nv 0 0 0\no wheel\nv 1 {bad} 0\nv 0 1 0\nf 1 2 3\n"));
        let e = load_obj(&p).unwrap_err();
        assert!(matches!(&e, MeshError::NonFinite { line: 4, object, .. } if object == "wheel"), "{bad}: {e}");
    }
}

#[test]
fn empty_and_all_degenerate_meshes_are_errors() {
    let d = tmp("empty");
    for (name, text) in
        [("e1.obj", ""), ("e2.obj", "# only a comment\nv 0 0 0\n"), ("e3.obj", "v 0 0 0\nv 1 1 1\nv 2 2 2\nf 1 2 3\n")]
    {
        let p = write(&d, name, text);
        assert!(matches!(load_obj(&p), Err(MeshError::Empty { .. })), "{name}");
    }
}

#[test]
fn textures_are_sampled_at_the_triangle_uvs() {
    let d = tmp("tex");
    // 4x1 texture: left half pure red, right half pure blue (sRGB 255 → linear 1).
    let img =
        image::RgbImage::from_fn(4, 1, |x, _| if x < 2 { image::Rgb([255, 0, 0]) } else { image::Rgb([0, 0, 255]) });
    img.save(d.join("t.png")).unwrap();
    write(&d, "t.mtl", "newmtl tex\nKd 1 1 1\nmap_Kd t.png\n");
    // Two quads side by side: the left one maps to u in [0.2, 0.35] (bilinear footprint within
    // the red texels), the right one to [0.65, 0.8] (blue).
    let p = write(
        &d,
        "t.obj",
        "mtllib t.mtl\nusemtl tex\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 3 0 0\nv 3 1 0\nv 2 1 0\n\
         vt 0.2 0\nvt 0.35 0\nvt 0.35 1\nvt 0.2 1\nvt 0.65 0\nvt 0.8 0\nvt 0.8 1\nvt 0.65 1\n\
         f 1/1 2/2 3/3 4/4\nf 5/5 6/6 7/7 8/8\n",
    );
    let m = load_obj(&p).unwrap();
    assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    let tex = m.materials[0].texture.as_ref().expect("texture loaded");
    assert_eq!((tex.width, tex.height), (4, 1));
    assert!((tex.sample(Vec2::new(0.3, 0.5)) - Vec3::X).length() < 1e-6);
    assert!((tex.sample(Vec2::new(0.7, 0.5)) - Vec3::Z).length() < 1e-6);
    let opts = VoxelizeOptions { resolution: Resolution::Depth(4), solid: false };
    let g = voxelize(&m.parts[0], &m.materials, &opts, &|_, _| {}).unwrap();
    let (mut red, mut blue) = (0, 0);
    for (v, c) in g.voxels.iter().zip(g.coords()) {
        // Cube covers x in [-0.5, 3.5): voxels 0..=5 hold the left quad, 10..16 the right.
        if c[0] <= 5 && v.albedo.x > 0.9 && v.albedo.z < 0.1 {
            red += 1;
        }
        if c[0] >= 10 && v.albedo.z > 0.9 && v.albedo.x < 0.1 {
            blue += 1;
        }
    }
    assert!(red > 10 && blue > 10, "red {red} blue {blue}");
    // A missing texture is a warning and the material falls back to Kd.
    write(&d, "t.mtl", "newmtl tex\nKd 0.3 0.3 0.3\nmap_Kd missing.png\n");
    let m = load_obj(&p).unwrap();
    assert!(m.materials[0].texture.is_none() && m.warnings.len() == 1, "{:?}", m.warnings);
    // So is one whose header claims 12000² texels (1.7 GB once loaded): refused from its
    // header, before decoding (its image data is still the 4×1 one's).
    let mut png = std::fs::read(d.join("t.png")).unwrap();
    png[16..20].copy_from_slice(&12000u32.to_be_bytes());
    png[20..24].copy_from_slice(&12000u32.to_be_bytes());
    let crc = voxray::svo::io::crc32(&png[12..29]);
    png[29..33].copy_from_slice(&crc.to_be_bytes());
    std::fs::write(d.join("huge.png"), &png).unwrap();
    write(&d, "t.mtl", "newmtl tex\nKd 0.3 0.3 0.3\nmap_Kd huge.png\n");
    let m = load_obj(&p).unwrap();
    assert!(m.materials[0].texture.is_none() && m.warnings.len() == 1, "{:?}", m.warnings);
    assert!(
        m.warnings[0].contains("12000×12000 texels") && m.warnings[0].contains("scale it down"),
        "{:?}",
        m.warnings
    );
}

/// MTL `Ks` and `Ns` become the specular lobe, voxelized into the SVO's attributes; a `Ks`
/// that would make the surface reflect more than it receives is lowered with a warning; bad
/// values are errors naming the field.
#[test]
fn specular_materials_reach_the_voxels() {
    let d = tmp("glossy");
    let obj = "mtllib g.mtl\nusemtl g\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n";
    write(&d, "g.mtl", "newmtl g\nKd 0.5 0.4 0.3\nKs 0.2 0.2 0.2\nNs 100\n");
    let p = write(&d, "g.obj", obj);
    let m = load_obj(&p).unwrap();
    assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    assert!((m.materials[0].specular - 0.2).abs() < 1e-6 && m.materials[0].shininess == 100.0);
    let opts = VoxelizeOptions { resolution: Resolution::Depth(3), solid: false };
    let g = voxelize(&m.parts[0], &m.materials, &opts, &|_, _| {}).unwrap();
    let svo = voxray::svo::build(&g).unwrap();
    let gloss = voxray::render::brdf::gloss_of_shininess(100.0);
    for a in &svo.attrs {
        assert!((a.specular() - 0.2).abs() < 0.03, "ks {}", a.specular());
        assert!((a.gloss() - gloss).abs() <= 0.5 / 15.0 + 1e-6, "gloss {}", a.gloss());
    }
    // Kd 0.8 + Ks 0.5 would reflect 1.3: Ks is lowered to 0.2 and the user is told.
    write(&d, "g.mtl", "newmtl g\nKd 0.8 0.8 0.8\nKs 0.5 0.5 0.5\nNs 250\n");
    let m = load_obj(&p).unwrap();
    assert!((m.materials[0].specular - 0.2).abs() < 1e-5, "{}", m.materials[0].specular);
    assert!(m.warnings.len() == 1 && m.warnings[0].contains("Ks"), "{:?}", m.warnings);
    for (mtl, field) in [("Ks -1 0 0", "Ks"), ("Ns -5", "Ns"), ("Ks nan 0 0", "Ks"), ("Ke 1e5 0 0", "Ke")] {
        write(&d, "g.mtl", &format!("newmtl g\nKd 0.5 0.5 0.5\n{mtl}\n"));
        let e = load_obj(&p).unwrap_err().to_string();
        assert!(e.contains(field), "{mtl}: {e}");
    }
    // Kd above 1 is stored as 1, and the user is told; a bright Ke of its own colour is kept.
    write(&d, "g.mtl", "newmtl g\nKd 1.5 0.5 0.5\nKe 17 12 4\n");
    let m = load_obj(&p).unwrap();
    assert!(m.warnings.len() == 1 && m.warnings[0].contains("Kd"), "{:?}", m.warnings);
    assert_eq!(m.materials[0].emission, Vec3::new(17.0, 12.0, 4.0));
}

/// A concave face keeps its notch: the face starts at the corner from which a fan would
/// cover the notch (the fan's triangles add up to 22 where the face has area 10), and every
/// corner's texture coordinate goes with it. A face that crosses itself is split too, with a
/// warning.
#[test]
fn concave_faces_keep_their_notches() {
    let d = tmp("concave");
    let p = write(
        &d,
        "notch.obj",
        "v 0 0 0\nv 4 0 0\nv 4 4 0\nv 2 1 0\nv 0 4 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0.5 0.25\nvt 0 1\n\
         f 3/3 4/4 5/5 1/1 2/2\n",
    );
    let m = load_obj(&p).unwrap();
    assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    let tris = &m.parts[0].triangles;
    assert_eq!(tris.len(), 3);
    let area: f32 = tris
        .iter()
        .map(|t| (t.positions[1] - t.positions[0]).cross(t.positions[2] - t.positions[0]).length() / 2.0)
        .sum();
    assert!((area - 10.0).abs() < 1e-4, "area {area}");
    for t in tris {
        // The face's winding (+z) and each corner's own uv (u = x/4, v = y/4).
        assert!((t.positions[1] - t.positions[0]).cross(t.positions[2] - t.positions[0]).z > 0.0);
        for (pos, uv) in t.positions.iter().zip(t.uvs.expect("uvs")) {
            assert_eq!(uv, Vec2::new(pos.x / 4.0, pos.y / 4.0));
        }
    }
    // No voxel in the notch (around (2, 3)), voxels beside it.
    let opts = VoxelizeOptions { resolution: Resolution::Depth(5), solid: false };
    let g = voxelize(&m.parts[0], &m.materials, &opts, &|_, _| {}).unwrap();
    let size = g.bounds.size / 32.0;
    let centres: Vec<Vec3> =
        g.coords().map(|c| g.bounds.min + (Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32) + 0.5) * size).collect();
    let near = |x: f32, y: f32| centres.iter().any(|c| (c.x - x).abs() < size && (c.y - y).abs() < size);
    assert!(!near(2.0, 3.0), "the notch is filled");
    assert!(near(2.0, 0.5) && near(0.5, 3.0) && near(3.5, 3.0));

    let bow = write(&d, "bow.obj", "v 0 0 0\nv 2 2 0\nv 2 0 0\nv 0 2 0\nf 1 2 3 4\n");
    let m = load_obj(&bow).unwrap();
    assert_eq!(m.parts[0].triangles.len(), 2);
    assert!(m.warnings.iter().any(|w| w.contains("cross themselves")), "{:?}", m.warnings);
}
