//! The default car: the committed files are what the generator writes, the embedded copy
//! loads as eight parts that form the assembled car, and the rig's pivots sit where the
//! parts turn.

use glam::Vec3;
use voxray::mesh::{Mesh, Part};
use voxray::model::embedded::load_default_car;

fn bounds(p: &Part) -> (Vec3, Vec3) {
    p.triangles
        .iter()
        .flat_map(|t| t.positions)
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)))
}

fn part<'a>(m: &'a Mesh, name: &str) -> &'a Part {
    m.parts.iter().find(|p| p.name == name).unwrap_or_else(|| panic!("no part {name}"))
}

#[test]
fn committed_files_match_the_generator() {
    for (name, text) in voxray::model::car::files() {
        let on_disk = std::fs::read_to_string(format!("models/car/{name}")).expect("committed model file");
        assert!(on_disk == text, "models/car/{name} is stale: run `voxray model car`");
    }
}

/// The GI test box too, and its OBJ loads back as the same three parts and materials.
#[test]
fn committed_box_matches_the_generator_and_loads() {
    for (name, text) in voxray::model::room::files() {
        let on_disk = std::fs::read_to_string(format!("models/box/{name}")).expect("committed model file");
        assert!(on_disk == text, "models/box/{name} is stale: run `voxray model box`");
    }
    let loaded = voxray::mesh::load_obj(std::path::Path::new("models/box/box.obj")).unwrap();
    let built = voxray::model::room::mesh();
    let names = |m: &Mesh| m.parts.iter().map(|p| (p.name.clone(), p.triangles.len())).collect::<Vec<_>>();
    assert_eq!(names(&loaded), names(&built));
    // The loader may add its default material; every generated one must be there as written.
    for m in &built.materials {
        assert!(loaded.materials.iter().any(|l| l.name == m.name && l.albedo == m.albedo), "{}", m.name);
    }
}

#[test]
fn embedded_car_has_every_part_in_place() {
    let m = load_default_car().unwrap();
    let names: Vec<&str> = m.parts.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["body", "wheel_fl", "wheel_fr", "wheel_rl", "wheel_rr", "door_l", "door_r", "steering_wheel"]);
    let tris = m.triangle_count();
    assert!((20_000..200_000).contains(&tris), "{tris} triangles");
    assert!(m.warnings.is_empty(), "{:?}", m.warnings);
    let (blo, bhi) = bounds(part(&m, "body"));
    for w in ["wheel_fl", "wheel_fr", "wheel_rl", "wheel_rr"] {
        let (lo, hi) = bounds(part(&m, w));
        assert!(lo.y.abs() < 0.01, "{w} stands on the ground");
        assert!(lo.x > blo.x && hi.x < bhi.x, "{w} under the body");
    }
    assert!(bounds(part(&m, "wheel_fl")).1.z < 0.0 && bounds(part(&m, "wheel_fr")).0.z > 0.0);
    assert!(bounds(part(&m, "door_l")).1.z < 0.0 && bounds(part(&m, "door_r")).0.z > 0.0);
    // Emissive headlights survive loading.
    assert!(m.materials.iter().any(|mat| mat.name == "headlight" && mat.emission.x > 0.0));
}

#[test]
fn rig_pivots_match_the_geometry() {
    let m = load_default_car().unwrap();
    let rig: serde_json::Value = serde_json::from_str(include_str!("../models/car/rig.json")).unwrap();
    let parts = rig["parts"].as_array().unwrap();
    assert_eq!(parts.len(), 8);
    for p in parts {
        let name = p["name"].as_str().unwrap();
        let v = |k: &str| {
            Vec3::new(
                p[k][0].as_f64().unwrap() as f32,
                p[k][1].as_f64().unwrap() as f32,
                p[k][2].as_f64().unwrap() as f32,
            )
        };
        let (pivot, axis) = (v("pivot"), v("axis"));
        assert!((axis.length() - 1.0).abs() < 1e-3, "{name}: axis not unit");
        let (lo, hi) = bounds(part(&m, name));
        if name.starts_with("wheel") {
            // The axle is the centre of the wheel's bounding box, along z.
            assert!((pivot - (lo + hi) * 0.5).length() < 0.005, "{name}: pivot {pivot} vs centre {}", (lo + hi) * 0.5);
            assert_eq!(axis, Vec3::Z);
        } else if name.starts_with("door") {
            // The hinge is at the front edge, on the door's side, vertical.
            assert!((pivot.x - hi.x).abs() < 0.01 && pivot.z.signum() == lo.z.signum(), "{name}: hinge {pivot}");
            assert!(axis.y.abs() > 0.99);
        } else if name == "steering_wheel" {
            assert!(pivot.cmpge(lo).all() && pivot.cmple(hi).all(), "steering pivot inside the wheel");
        }
    }
}

/// The memory goal: at depth 9 every part of the car takes at most one byte of
/// geometry (what traversal reads) per voxel; version 2's descriptors took about 2.6.
#[test]
fn car_geometry_takes_under_a_byte_per_voxel() {
    let mesh = load_default_car().unwrap();
    let parts = voxray::pipeline::build_parts(&mesh, voxray::voxelize::Resolution::Depth(9)).unwrap();
    let (mut geometry, mut voxels) = (0, 0);
    for (p, svo) in mesh.parts.iter().zip(&parts) {
        let s = svo.stats();
        println!(
            "{}: {} voxels, {:.3} B/voxel geometry, {:.2} attributes",
            p.name,
            s.voxels,
            s.geometry_bytes_per_voxel(),
            s.attribute_bytes_per_voxel()
        );
        assert!(s.geometry_bytes_per_voxel() <= 1.0, "{}: {s:?}", p.name);
        geometry += s.geometry_bytes;
        voxels += s.voxels;
    }
    assert!(geometry as f64 / (voxels as f64) < 0.75, "{geometry} bytes for {voxels} voxels");
}
