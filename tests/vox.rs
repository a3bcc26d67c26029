//! MagicaVoxel scenes: third-party files (dot_vox's test files, MIT, in models/third-party)
//! traced against the file's own voxels (DDA oracle), their scene graph placed as the file
//! says, a flip-book written by dot_vox played frame by frame, and malformed files.

#![cfg(feature = "vox")]

use glam::{DVec3, Vec3};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use voxray::import::load_vox;
use voxray::oracle::{dda, Contact, VoxelSet};
use voxray::ray::Ray;
use voxray::rng::Rng;
use voxray::scene::Scene;
use voxray::traverse::{trace, TraceOptions};

fn third_party(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models/third-party/dot_vox").join(name)
}

#[test]
fn every_model_traces_as_the_files_voxels() {
    for name in ["axes.vox", "metal-material.vox", "placeholder-with-materials.vox"] {
        let path = third_party(name);
        let scene = load_vox(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        let bytes = std::fs::read(&path).unwrap();
        let data = dot_vox::load_bytes(&bytes).unwrap();
        assert_eq!(scene.svos.len(), data.models.len(), "{name}");
        let mut rng = Rng::new(17);
        for (k, (svo, model)) in scene.svos.iter().zip(&data.models).enumerate() {
            let coords: Vec<[u32; 3]> = model.voxels.iter().map(|v| [v.x as u32, v.y as u32, v.z as u32]).collect();
            let set = VoxelSet::new(svo.depth, coords.iter().copied());
            assert_eq!(svo.voxel_count, set.len() as u64, "{name} model {k}: one SVO voxel per file voxel");
            let (min, size) = (svo.bounds.min.as_dvec3(), svo.bounds.size as f64);
            let (mut hits, mut rays) = (0, 0);
            for _ in 0..4000 {
                // From a sphere around the cube towards a random point inside it.
                let target = DVec3::new(rng.f64(), rng.f64(), rng.f64());
                let from = rng.unit_vector().as_dvec3() * 1.5 + DVec3::splat(0.5);
                let dir = (target - from).normalize();
                let oracle = dda(&set, from, dir, 0.0, f64::INFINITY, Contact::Closed);
                let ray = Ray::new((from * size + min).as_vec3(), (dir * size).as_vec3());
                let got = trace(svo, &ray, &TraceOptions::default());
                rays += 1;
                match (oracle, got) {
                    (None, None) => {}
                    (Some(o), Some(h)) => {
                        hits += 1;
                        assert_eq!(h.coord, o.coord, "{name} model {k}: ray {from} → {dir}");
                        assert!((h.t as f64 - o.t).abs() < 1e-4, "{name} model {k}: t {} vs {}", h.t, o.t);
                    }
                    (o, h) => panic!("{name} model {k}: oracle {o:?}, traversal {:?}", h.map(|h| h.coord)),
                }
            }
            assert!(hits > rays / 20, "{name} model {k}: the rays find the model ({hits} of {rays})");
            // Colours: the palette's (sRGB) as linear albedo.
            let v = model.voxels[0];
            let lin = |s: u8| {
                let s = s as f32 / 255.0;
                if s <= 0.04045 {
                    s / 12.92
                } else {
                    ((s + 0.055) / 1.055).powf(2.4)
                }
            };
            let unit = |x: u8| (x as f64 + 0.5) / (1u64 << svo.depth) as f64;
            let from = DVec3::new(unit(v.x), unit(v.y), 2.0);
            let h = trace(
                svo,
                &Ray::new((from * size + min).as_vec3(), Vec3::new(0.0, 0.0, -1.0)),
                &TraceOptions::default(),
            );
            // The first voxel down that column is the file's topmost one there.
            let top = model.voxels.iter().filter(|w| w.x == v.x && w.y == v.y).max_by_key(|w| w.z).unwrap();
            let c = data.palette[top.i as usize];
            let want_top = Vec3::new(lin(c.r), lin(c.g), lin(c.b));
            let albedo = h.expect("the column hits").albedo();
            let metal = data.materials.iter().any(|m| {
                m.id as usize == top.i as usize + 1 && m.properties.get("_type").is_some_and(|t| t == "_metal")
            });
            if !metal {
                assert!(
                    (albedo - want_top).abs().max_element() < 0.02,
                    "{name} model {k}: albedo {albedo} vs {want_top}"
                );
            }
        }
    }
}

#[test]
fn the_scene_graph_places_models_as_the_file_says() {
    let v = load_vox(&third_party("axes.vox")).unwrap();
    let mut rig = v.rig.clone();
    let mut scene = Scene::new(v.svos.into_iter().map(Arc::new).collect());
    rig.instantiate(&mut scene, 0, None).unwrap();
    scene.update().unwrap();
    assert_eq!(scene.instances().len(), 10);
    // Model 0 three times at file z = 131 − 48, 131, 131 + 48 (translations of nested
    // transforms), which is y in voxray's y-up world; the model's 40³ voxels are centred.
    let mut ys: Vec<f64> =
        (0..10).filter(|&i| scene.instances()[i].part == 0).map(|i| scene.world(i).translation.y).collect();
    ys.sort_by(f64::total_cmp);
    assert_eq!(ys.len(), 3);
    for (y, want) in ys.iter().zip([83.0, 131.0, 179.0]) {
        assert!((y - want).abs() < 1e-9, "{ys:?}");
    }
    // File y becomes −z: the group at file y = 188 (children at −59, 1, 59) lies at negative z.
    let zs: Vec<f64> =
        (0..10).filter(|&i| scene.instances()[i].part == 1).map(|i| scene.world(i).translation.z).collect();
    assert!(zs.iter().all(|&z| z < -100.0), "{zs:?}");
}

fn model(size: u32, voxels: &[(u8, u8, u8)], colour: u8) -> dot_vox::Model {
    dot_vox::Model {
        size: dot_vox::Size { x: size, y: size, z: size },
        voxels: voxels.iter().map(|&(x, y, z)| dot_vox::Voxel { x, y, z, i: colour }).collect(),
    }
}

fn dict(pairs: &[(&str, &str)]) -> dot_vox::Dict {
    pairs.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect()
}

/// A shape listing two models as frames 0 and 3, under a transform that moves at frame 3.
fn flip_book(rotation: &str) -> dot_vox::DotVoxData {
    flip_book_moving(rotation, true)
}

/// [`flip_book`]; with `moving` false the transform has one frame (only the model swaps).
fn flip_book_moving(rotation: &str, moving: bool) -> dot_vox::DotVoxData {
    use dot_vox::{SceneNode, ShapeModel};
    let frame = |f: &str, t: &str| dot_vox::Frame::new(dict(&[("_f", f), ("_t", t), ("_r", rotation)]));
    dot_vox::DotVoxData {
        version: 150,
        index_map: Vec::new(),
        models: vec![model(4, &[(0, 0, 0), (1, 0, 0)], 10), model(4, &[(3, 3, 3)], 20)],
        palette: dot_vox::DEFAULT_PALETTE.to_vec(),
        materials: Vec::new(),
        scenes: vec![
            SceneNode::Transform {
                attributes: dict(&[]),
                frames: vec![dot_vox::Frame::new(dict(&[]))],
                child: 1,
                layer_id: 0,
            },
            SceneNode::Group { attributes: dict(&[]), children: vec![2] },
            SceneNode::Transform {
                attributes: dict(&[("_name", "mover")]),
                frames: if moving {
                    vec![frame("0", "0 0 0"), frame("3", "10 0 0")]
                } else {
                    vec![frame("0", "0 0 0")]
                },
                child: 3,
                layer_id: 0,
            },
            SceneNode::Shape {
                attributes: dict(&[]),
                models: vec![
                    ShapeModel { model_id: 0, attributes: dict(&[("_f", "0")]) },
                    ShapeModel { model_id: 1, attributes: dict(&[("_f", "3")]) },
                ],
            },
        ],
        layers: Vec::new(),
    }
}

fn write(name: &str, data: &dot_vox::DotVoxData) -> PathBuf {
    let p = std::env::temp_dir().join(format!("voxray-vox-{name}-{}.vox", std::process::id()));
    let mut f = std::fs::File::create(&p).unwrap();
    data.write_vox(&mut f).unwrap();
    p
}

#[test]
fn a_flip_book_swaps_models_and_steps_its_transform() {
    let p = write("flip", &flip_book("4"));
    let v = load_vox(&p).unwrap();
    std::fs::remove_file(&p).ok();
    assert_eq!(v.rig.clips.len(), 1);
    let mut rig = v.rig.clone();
    let mut scene = Scene::new(v.svos.into_iter().map(Arc::new).collect());
    rig.instantiate(&mut scene, 0, Some(0)).unwrap();
    let fps = voxray::import::vox::FRAMES_PER_SECOND;
    let at = |scene: &mut Scene, rig: &voxray::scene::animation::Rig, t: f64| {
        rig.pose(scene, Some(0), t).unwrap();
        scene.update().unwrap();
        (scene.instances()[0].part, scene.world(0).translation)
    };
    let (p0, t0) = at(&mut scene, &rig, 0.0);
    let (p1, t1) = at(&mut scene, &rig, 2.9 / fps);
    let (p3, t3) = at(&mut scene, &rig, 3.0 / fps);
    assert_eq!((p0, p1, p3), (0, 0, 1), "frames 0–2 show model 0, frame 3 model 1");
    assert!(t0.abs_diff_eq(DVec3::ZERO, 1e-12) && t1.abs_diff_eq(DVec3::ZERO, 1e-12));
    assert!(t3.abs_diff_eq(DVec3::new(10.0, 0.0, 0.0), 1e-12), "{t3}");
    // The clip loops after the last frame's time.
    let (p4, _) = at(&mut scene, &rig, 4.0 / fps + 1e-9);
    assert_eq!(p4, 0);
}

#[test]
fn malformed_vox_files_get_errors_not_panics() {
    // A rotation byte that is not a signed permutation (the parser itself would panic on it).
    let p = write("badrot", &flip_book("3"));
    let e = load_vox(&p).err().expect("refused").to_string();
    std::fs::remove_file(&p).ok();
    assert!(e.contains("scene node 2") && e.contains("'_r'"), "{e}");
    // A shape naming a model that does not exist.
    let mut data = flip_book("4");
    if let dot_vox::SceneNode::Shape { models, .. } = &mut data.scenes[3] {
        models[1].model_id = 9;
    }
    let p = write("badmodel", &data);
    let e = load_vox(&p).err().expect("refused").to_string();
    std::fs::remove_file(&p).ok();
    assert!(e.contains("scene node 3") && e.contains("model 9"), "{e}");
    // Bounded fuzz: truncations and byte flips of a real file error or load, never panic.
    let bytes = std::fs::read(third_party("axes.vox")).unwrap();
    let mut rng = Rng::new(5);
    let dir = std::env::temp_dir().join(format!("voxray-vox-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("m.vox");
    for case in 0..300 {
        let mut b = bytes.clone();
        for _ in 0..1 + case % 3 {
            let at = rng.below(b.len() as u64) as usize;
            if case % 4 == 0 {
                b.truncate(at.max(8));
            } else {
                b[at] = rng.below(256) as u8;
            }
        }
        std::fs::write(&path, &b).unwrap();
        let r = std::panic::catch_unwind(|| load_vox(&path).map(|v| v.svos.len()));
        assert!(r.is_ok(), "case {case}: the loader panicked");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Swapping a flip-book's model is a change the hit buffer sees: the frame after the swap is
/// the frame rendered afresh, bit for bit.
#[test]
fn a_model_swap_is_not_hidden_by_the_hit_buffer() {
    use voxray::render::{render, Features, FramePlan, HitBuffer, RenderOptions};
    use voxray::scene::{Camera, Lights};
    let p = write("swap", &flip_book_moving("4", false));
    let v = load_vox(&p).unwrap();
    std::fs::remove_file(&p).ok();
    let mut rig = v.rig.clone();
    let mut scene = Scene::new(v.svos.into_iter().map(Arc::new).collect());
    rig.instantiate(&mut scene, 0, Some(0)).unwrap();
    scene.update().unwrap();
    let camera = Camera {
        eye: DVec3::new(6.0, 5.0, 7.0),
        target: DVec3::ZERO,
        up: DVec3::Y,
        vfov_deg: 40.0,
        width: 48,
        height: 40,
    };
    let (lights, features) = (Lights::default(), Features::default());
    let fps = voxray::import::vox::FRAMES_PER_SECOND;
    let frame_at = |scene: &mut Scene, t: f64, hits: Option<&mut HitBuffer>| {
        rig.pose(scene, Some(0), t).unwrap();
        scene.update().unwrap();
        let plan = FramePlan::new(scene, &camera, &lights, &features, hits.as_deref());
        render(scene, &camera, &lights, &plan, &RenderOptions::default(), hits, &|_, _| {}).unwrap()
    };
    let mut hits = HitBuffer::new();
    let before = frame_at(&mut scene, 2.0 / fps, Some(&mut hits));
    let kept = frame_at(&mut scene, 2.5 / fps, Some(&mut hits));
    assert!(kept.reused > 0, "a still frame reuses its pixels");
    let swapped = frame_at(&mut scene, 3.0 / fps, Some(&mut hits));
    let fresh = frame_at(&mut scene, 3.0 / fps, None);
    assert_ne!(before.instance, vec![-1; before.instance.len()], "the model is in view");
    assert_ne!(before.t, swapped.t, "the other model shows");
    assert_eq!(
        swapped.t.iter().map(|t| t.to_bits()).collect::<Vec<_>>(),
        fresh.t.iter().map(|t| t.to_bits()).collect::<Vec<_>>()
    );
    assert_eq!(swapped.radiance, fresh.radiance);
}

/// Huge voxel counts go through the memory budget before anything is built.
#[test]
fn voxel_counts_past_the_budget_are_refused_first() {
    let path = third_party("axes.vox");
    let e = voxray::memory::with_budget(64 << 10, || load_vox(&path)).err().expect("refused under 64 KiB");
    let msg = e.to_string();
    assert!(msg.contains("axes.vox") && msg.contains("voxels") && msg.contains("budget"), "{msg}");
    assert!(voxray::memory::with_budget(1 << 30, || load_vox(&path)).is_ok());
}
