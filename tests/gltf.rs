//! glTF 2.0 scenes: a third-party animated file (Khronos' BoxAnimated, CC BY 4.0, in
//! models/third-party) against the same geometry posed by hand from the file's keys, the
//! binary container against the JSON one, and malformed files (named errors, never a panic).

#![cfg(feature = "gltf")]

use glam::{DAffine3, DQuat, DVec3};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use voxray::import::{load_gltf, ImportError, Imported};
use voxray::pipeline::build_parts;
use voxray::render::{render, Features, Frame, FramePlan, RenderOptions};
use voxray::scene::animation::Clip;
use voxray::scene::{Camera, Instance, Lights, Scene, Transform};
use voxray::voxelize::Resolution;

fn box_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models/third-party/BoxAnimated")
}

fn box_animated() -> Imported {
    load_gltf(&box_dir().join("BoxAnimated.gltf")).expect("BoxAnimated loads")
}

fn camera() -> Camera {
    Camera {
        eye: DVec3::new(3.0, 2.5, 5.0),
        target: DVec3::new(0.0, 1.0, 0.0),
        up: DVec3::Y,
        vfov_deg: 45.0,
        width: 96,
        height: 72,
    }
}

fn frame(scene: &Scene) -> Frame {
    let lights = Lights::default();
    let features = Features::default();
    let plan = FramePlan::new(scene, &camera(), &lights, &features, None);
    render(scene, &camera(), &lights, &plan, &RenderOptions::default(), None, &|_, _| {}).expect("renders")
}

#[test]
fn box_animated_loads_as_two_parts_under_its_hierarchy() {
    let im = box_animated();
    let names: Vec<&str> = im.mesh.parts.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["outer_box", "inner_box"], "scene order: node 3 (outer) first, then node 0's subtree");
    assert_eq!(im.mesh.parts[0].triangles.len(), 192);
    assert_eq!(im.mesh.parts[1].triangles.len(), 62);
    assert_eq!(im.rig.nodes.len(), 4);
    assert_eq!(im.rig.clips.len(), 2);
    assert!((im.rig.clips[0].duration - 2.5).abs() < 1e-6);
    assert!((im.rig.clips[1].duration - 3.708329916).abs() < 1e-6);
    let outer = im.mesh.materials[im.mesh.parts[0].triangles[0].material as usize].albedo;
    assert!((outer - glam::Vec3::new(0.301604, 0.533542, 0.8)).abs().max_element() < 1e-5, "{outer}");
}

/// The inner box's world transform at time t of both clips played together, from the
/// file's keys by hand: node 0 (no mesh) translates up 2.52 and back over 3.708 s; node 2
/// (the inner box, under nodes 0 and 1) turns half a turn about x between 1.25 and 2.5 s.
fn inner_by_hand(t: f64) -> Transform {
    let keys = [0.0, 1.25, 2.5, 3.708329916000366];
    let ys = [0.0, 2.5199999809265137, 2.5199999809265137, 0.0];
    let k = keys.iter().rposition(|&x| x <= t).unwrap_or(0).min(2);
    let u = ((t - keys[k]) / (keys[k + 1] - keys[k])).clamp(0.0, 1.0);
    let y = ys[k] + (ys[k + 1] - ys[k]) * u;
    let q0 = DQuat::from_xyzw(-0.0, -0.0, -0.0, -1.0);
    let q1 = DQuat::from_xyzw(1.0, 0.0, 0.0, 4.4896593387466766e-11);
    let s = ((t - 1.25) / 1.25).clamp(0.0, 1.0);
    // Node 0's rest rotation (0, 0, 0, −1) is the identity.
    Transform { translation: DVec3::new(0.0, y, 0.0), rotation: q0.slerp(q1, s), scale: DVec3::ONE }
}

#[test]
fn the_animated_file_renders_the_hits_of_the_same_geometry_posed_by_hand() {
    let mut im = box_animated();
    let parts = build_parts(&im.mesh, Resolution::Depth(6)).expect("voxelizes");
    // Both clips together, as viewers play this file.
    let all: Vec<_> = im.rig.clips.iter().flat_map(|c| c.channels.clone()).collect();
    im.rig.clips.push(Clip::new("all".into(), all));
    let clip = Some(2);
    let mut by_file = Scene::new(parts.clone());
    im.rig.instantiate(&mut by_file, 0, clip).expect("instances");
    let mut by_hand = Scene::new(parts);
    by_hand.add(Instance { part: 0, parent: None, local: Transform::IDENTITY }).unwrap();
    by_hand.add(Instance { part: 1, parent: None, local: Transform::IDENTITY }).unwrap();
    let mut moved = 0;
    let mut previous: Option<Vec<i32>> = None;
    for t in [0.0, 0.9, 1.6, 2.2, 3.1, 3.708329916 + 1.6] {
        im.rig.pose(&mut by_file, clip, t).unwrap();
        by_file.update().unwrap();
        // The clip loops: 3.708 + 1.6 s looks like 1.6 s.
        let local = if t > 3.708329916 { t - 3.708329916000366 } else { t };
        by_hand.set_local(1, inner_by_hand(local)).unwrap();
        by_hand.update().unwrap();
        for i in 0..2 {
            let (a, b) = (by_file.world(i), by_hand.world(i));
            assert!(a.abs_diff_eq(b, 1e-6), "t = {t}, instance {i}: {a:?} vs {b:?}");
        }
        let (f, h) = (frame(&by_file), frame(&by_hand));
        let differ = f.instance.iter().zip(&h.instance).filter(|(a, b)| a != b).count();
        // The world matrices agree to rounding; only a pixel grazing an edge could flip.
        assert!(differ <= 2, "t = {t}: {differ} pixels see another instance");
        assert!(f.instance.contains(&1), "t = {t}: the inner box is in view");
        for k in 0..f.t.len() {
            if f.instance[k] == h.instance[k] && f.instance[k] >= 0 {
                assert!((f.t[k] - h.t[k]).abs() <= 1e-4 * h.t[k], "t = {t} pixel {k}: {} vs {}", f.t[k], h.t[k]);
            }
        }
        if previous.as_ref().is_some_and(|p| *p != f.instance) {
            moved += 1;
        }
        previous = Some(f.instance);
    }
    assert!(moved >= 3, "the animation moves the inner box between samples ({moved})");
}

/// Packs a glTF JSON and one buffer into a GLB container.
fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut j = json.as_bytes().to_vec();
    while j.len() % 4 != 0 {
        j.push(b' ');
    }
    let mut b = bin.to_vec();
    while b.len() % 4 != 0 {
        b.push(0);
    }
    let total = 12 + 8 + j.len() + 8 + b.len();
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(j.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&j);
    out.extend_from_slice(&(b.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&b);
    out
}

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("voxray-gltf-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn box_json() -> String {
    std::fs::read_to_string(box_dir().join("BoxAnimated.gltf")).unwrap()
}

fn box_bin() -> Vec<u8> {
    std::fs::read(box_dir().join("BoxAnimated0.bin")).unwrap()
}

#[test]
fn binary_gltf_loads_as_the_json_one() {
    let json = box_json().replace("\"uri\": \"BoxAnimated0.bin\"", "\"_uri\": 0");
    assert!(json.contains("\"_uri\""));
    let dir = temp_dir("glb");
    let p = dir.join("box.glb");
    std::fs::write(&p, glb(&json, &box_bin())).unwrap();
    let (a, b) = (load_gltf(&p).expect("GLB loads"), box_animated());
    assert_eq!(a.mesh, b.mesh);
    assert_eq!(a.rig, b.rig);
    // A data URI holds the same bytes.
    use base64::Engine;
    let data = base64::engine::general_purpose::STANDARD.encode(box_bin());
    let embedded = box_json()
        .replace("\"uri\": \"BoxAnimated0.bin\"", &format!("\"uri\": \"data:application/octet-stream;base64,{data}\""));
    let p = dir.join("embedded.gltf");
    std::fs::write(&p, embedded).unwrap();
    let c = load_gltf(&p).expect("embedded buffer loads");
    assert_eq!(c.mesh, b.mesh);
    assert_eq!(c.rig, b.rig);
    std::fs::remove_dir_all(&dir).ok();
}

/// Writes a variant of BoxAnimated (JSON and buffer changed by `edit`) and loads it.
fn load_variant(name: &str, json: &str, bin: &[u8]) -> Result<Imported, ImportError> {
    let dir = temp_dir(name);
    std::fs::write(dir.join("BoxAnimated0.bin"), bin).unwrap();
    let p = dir.join("scene.gltf");
    std::fs::write(&p, json).unwrap();
    let r = load_gltf(&p);
    std::fs::remove_dir_all(&dir).ok();
    r
}

fn expect_error(name: &str, json: &str, bin: &[u8], words: &[&str]) {
    match load_variant(name, json, bin) {
        Ok(_) => panic!("{name}: loaded"),
        Err(e) => {
            let msg = e.to_string();
            for w in words {
                assert!(msg.contains(w), "{name}: '{msg}' lacks '{w}'");
            }
        }
    }
}

#[test]
fn malformed_files_get_errors_that_name_the_element() {
    let (json, bin) = (box_json(), box_bin());
    // NaN in an animation's keys (the translation keys' second y value).
    let mut nan = bin.clone();
    nan[32 + 16..32 + 20].copy_from_slice(&f32::NAN.to_le_bytes());
    expect_error("nan-key", &json, &nan, &["animation 'animation 1' channel 0", "not finite"]);
    // Key times that go backwards.
    let mut back = bin.clone();
    back[7768 + 8..7768 + 12].copy_from_slice(&0.5f32.to_le_bytes());
    expect_error("backwards", &json, &back, &["animation 'animation 1' channel 0", "key time 2"]);
    // An accessor past its buffer view.
    let huge = json.replacen("\"count\": 186", "\"count\": 1860000", 1);
    expect_error("accessor", &huge, &bin, &["mesh 'inner_box' primitive 0", "accessor 0", "run past"]);
    // A truncated buffer.
    expect_error("truncated", &json, &bin[..4000], &["buffer 0", "byteLength is 9308"]);
    // A missing buffer file.
    let missing = json.replace("BoxAnimated0.bin", "nowhere.bin");
    expect_error("missing", &missing, &bin, &["buffer 0", "nowhere.bin", "not found"]);
    // An index past the vertices.
    let mut idx = bin.clone();
    idx[7784..7786].copy_from_slice(&500u16.to_le_bytes());
    expect_error("index", &json, &idx, &["mesh 'inner_box' primitive 0", "index 500"]);
    // A scene without meshes.
    let empty = json.replace("\"nodes\": [\n                3,\n                0\n            ]", "\"nodes\": []");
    assert_ne!(empty, json);
    expect_error("empty", &empty, &bin, &["scene", "no mesh"]);
    // Not JSON at all.
    expect_error("garbage", "{ this is not json", &bin, &["file"]);
    // A node that is its own child.
    let cycle = json.replacen(
        "\"children\": [\n                2\n            ]",
        "\"children\": [\n                1\n            ]",
        1,
    );
    assert_ne!(cycle, json);
    assert!(load_variant("cycle", &cycle, &bin).is_err(), "a cycle is refused");
}

/// Bounded fuzz: thousands of byte-level mutations of the JSON and the buffer load or fail
/// with an error; none may panic.
#[test]
fn mutated_files_never_panic() {
    let (json, bin) = (box_json().into_bytes(), box_bin());
    let dir = temp_dir("fuzz");
    let p = dir.join("scene.gltf");
    let mut rng = voxray::rng::Rng::new(0x6c7f);
    let mut loaded = 0;
    for case in 0..600 {
        let (mut j, mut b) = (json.clone(), bin.clone());
        for _ in 0..1 + case % 4 {
            let target: &mut Vec<u8> = if rng.f64() < 0.5 { &mut j } else { &mut b };
            let at = (rng.f64() * target.len() as f64) as usize % target.len();
            match case % 3 {
                0 => target[at] = (rng.f64() * 256.0) as u8,
                1 => target[at] = b"0123456789-.e,]}\"".get(at % 17).copied().unwrap_or(b'9'),
                _ => target.truncate(at.max(1)),
            }
        }
        std::fs::write(&p, &j).unwrap();
        std::fs::write(dir.join("BoxAnimated0.bin"), &b).unwrap();
        let r = std::panic::catch_unwind(|| load_gltf(&p));
        match r {
            Ok(Ok(im)) => {
                loaded += 1;
                // Whatever loads must also voxelize, pose and render without a panic.
                let mut im = im;
                if let Ok(parts) = build_parts(&im.mesh, Resolution::Depth(4)) {
                    let mut scene = Scene::new(parts.into_iter().map(Arc::unwrap_or_clone).map(Arc::new).collect());
                    if im.rig.instantiate(&mut scene, 0, (!im.rig.clips.is_empty()).then_some(0)).is_ok() {
                        let _ = scene.update();
                    }
                }
            }
            Ok(Err(_)) => {}
            Err(_) => panic!("case {case}: the loader panicked"),
        }
    }
    std::fs::remove_dir_all(&dir).ok();
    assert!(loaded > 0, "some mutations (in unused bytes) still load");
}

#[test]
fn a_node_under_a_sheared_empty_is_refused_by_name() {
    use voxray::scene::animation::{decompose, Node, Rest, Rig};
    let mut rig = Rig {
        nodes: vec![
            Node {
                name: "stretch".into(),
                parent: None,
                rest: Rest::Trs(DVec3::ZERO, DQuat::IDENTITY, DVec3::new(1.0, 3.0, 1.0)),
                part: None,
            },
            Node {
                name: "tilted".into(),
                parent: Some(0),
                rest: Rest::Trs(DVec3::ZERO, DQuat::from_rotation_z(0.6), DVec3::ONE),
                part: Some(0),
            },
        ],
        ..Default::default()
    };
    let im = box_animated();
    let parts = build_parts(&im.mesh, Resolution::Depth(4)).unwrap();
    let mut scene = Scene::new(parts);
    let e = rig.instantiate(&mut scene, 0, None).unwrap_err();
    assert!(e.to_string().contains("'tilted'") && e.to_string().contains("shear"), "{e}");
    assert!(decompose(&DAffine3::IDENTITY).is_some());
}

/// A generated file with what BoxAnimated lacks: a matrix node, a mirrored non-uniform scale
/// with a quaternion off unit length, and an empty (no mesh) driven by a CUBICSPLINE
/// translation above a child turned by a STEP rotation. World matrices against the same
/// products formed by hand.
#[test]
fn matrices_mirrors_and_every_interpolation_place_parts_as_written() {
    use base64::Engine;
    let mut bin: Vec<u8> = Vec::new();
    let f32s = |bin: &mut Vec<u8>, v: &[f32]| {
        let at = bin.len();
        bin.extend(v.iter().flat_map(|x| x.to_le_bytes()));
        at
    };
    // An L of two triangles (asymmetric, so a mirror shows).
    let pos = f32s(&mut bin, &[0., 0., 0., 1., 0., 0., 0., 2., 0., 0., 0., 0., 0.5, 0., 0., 0., 0., 1.]);
    let times = f32s(&mut bin, &[0.0, 2.0]);
    let step_times = f32s(&mut bin, &[0.0, 1.0]);
    // CUBICSPLINE: in-tangent, value, out-tangent per key (tangents per second).
    let cubic = f32s(&mut bin, &[0., 0., 0., 5., 0., 0., 1., 1., 0., 0., 0., 0., 9., 0., 4., 0., 0., 0.]);
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let steps = f32s(&mut bin, &[0., 0., 0., 1., 0., h, 0., h]);
    let data = base64::engine::general_purpose::STANDARD.encode(&bin);
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0,1,2]}}],
        "nodes":[
          {{"name":"matrix","mesh":0,"matrix":[0.8660254,0.5,0,0, -0.5,0.8660254,0,0, 0,0,1,0, 1,2,3,1]}},
          {{"name":"mirror","mesh":0,"scale":[-1,2,0.5],"rotation":[0,0,0.6,1.2],"translation":[0,1,0]}},
          {{"name":"empty","translation":[5,0,0],"children":[3]}},
          {{"name":"child","mesh":0,"translation":[0,0,1]}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
        "accessors":[
          {{"bufferView":0,"componentType":5126,"count":6,"type":"VEC3","min":[0,0,0],"max":[1,2,1]}},
          {{"bufferView":1,"componentType":5126,"count":2,"type":"SCALAR","min":[0],"max":[2]}},
          {{"bufferView":2,"componentType":5126,"count":6,"type":"VEC3"}},
          {{"bufferView":3,"componentType":5126,"count":2,"type":"VEC4"}},
          {{"bufferView":4,"componentType":5126,"count":2,"type":"SCALAR","min":[0],"max":[1]}}],
        "bufferViews":[
          {{"buffer":0,"byteOffset":{pos},"byteLength":72}},
          {{"buffer":0,"byteOffset":{times},"byteLength":8}},
          {{"buffer":0,"byteOffset":{cubic},"byteLength":72}},
          {{"buffer":0,"byteOffset":{steps},"byteLength":32}},
          {{"buffer":0,"byteOffset":{step_times},"byteLength":8}}],
        "buffers":[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{data}"}}],
        "animations":[{{"name":"move","samplers":[
            {{"input":1,"output":2,"interpolation":"CUBICSPLINE"}},
            {{"input":4,"output":3,"interpolation":"STEP"}}],
          "channels":[
            {{"sampler":0,"target":{{"node":2,"path":"translation"}}}},
            {{"sampler":1,"target":{{"node":3,"path":"rotation"}}}}]}}]}}"#,
        bin.len()
    );
    let dir = temp_dir("kinds");
    let p = dir.join("kinds.gltf");
    std::fs::write(&p, json).unwrap();
    let mut im = load_gltf(&p).expect("loads");
    std::fs::remove_dir_all(&dir).ok();
    assert!(
        im.mesh.warnings.iter().any(|w| w.contains("'mirror'") && w.contains("normalized")),
        "{:?}",
        im.mesh.warnings
    );
    let parts = build_parts(&im.mesh, Resolution::Depth(4)).unwrap();
    let mut scene = Scene::new(parts);
    im.rig.instantiate(&mut scene, 0, Some(0)).unwrap();
    let q = DQuat::from_xyzw(0.0, 0.0, 0.6, 1.2).normalize();
    let mirror = DAffine3::from_scale_rotation_translation(DVec3::new(-1.0, 2.0, 0.5), q, DVec3::Y);
    let matrix = DAffine3::from_cols_array(&[0.8660254, 0.5, 0.0, -0.5, 0.8660254, 0.0, 0.0, 0.0, 1.0, 1.0, 2.0, 3.0]);
    // The clip lasts 2 s (its last key) and loops: 2.5 s looks like 0.5 s.
    for (t, local) in [(0.0, 0.0), (0.5, 0.5), (0.999, 0.999), (1.0, 1.0), (1.5, 1.5), (2.5, 0.5)] {
        im.rig.pose(&mut scene, Some(0), t).unwrap();
        scene.update().unwrap();
        // Hermite from (5,0,0) with tangent (1,1,0)/s to (9,0,4) with tangent 0 over 2 s.
        let u: f64 = local / 2.0;
        let (h00, h10, h01) =
            (2.0 * u.powi(3) - 3.0 * u * u + 1.0, u.powi(3) - 2.0 * u * u + u, -2.0 * u.powi(3) + 3.0 * u * u);
        let empty =
            DVec3::new(5.0, 0.0, 0.0) * h00 + DVec3::new(1.0, 1.0, 0.0) * 2.0 * h10 + DVec3::new(9.0, 0.0, 4.0) * h01;
        let turn = if local < 1.0 { DQuat::IDENTITY } else { DQuat::from_rotation_y(std::f64::consts::FRAC_PI_2) };
        let child = DAffine3::from_translation(empty) * DAffine3::from_rotation_translation(turn, DVec3::Z);
        for (i, want) in [(0, matrix), (1, mirror), (2, child)] {
            assert!(scene.world(i).abs_diff_eq(want, 1e-6), "t = {t}, instance {i}: {:?} vs {want:?}", scene.world(i));
        }
        assert!(scene.world(1).matrix3.determinant() < 0.0, "the mirror stays a mirror");
    }
}
