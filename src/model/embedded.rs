//! The default car, embedded in the binary so `voxray` renders it from anywhere.

/// (file name, contents) of `models/car/`, parts in load order (instance numbering).
pub const CAR_FILES: &[(&str, &str)] = &[
    ("body.obj", include_str!("../../models/car/body.obj")),
    ("wheel_fl.obj", include_str!("../../models/car/wheel_fl.obj")),
    ("wheel_fr.obj", include_str!("../../models/car/wheel_fr.obj")),
    ("wheel_rl.obj", include_str!("../../models/car/wheel_rl.obj")),
    ("wheel_rr.obj", include_str!("../../models/car/wheel_rr.obj")),
    ("door_l.obj", include_str!("../../models/car/door_l.obj")),
    ("door_r.obj", include_str!("../../models/car/door_r.obj")),
    ("steering_wheel.obj", include_str!("../../models/car/steering_wheel.obj")),
    ("body.mtl", include_str!("../../models/car/body.mtl")),
    ("wheel_fl.mtl", include_str!("../../models/car/wheel_fl.mtl")),
    ("wheel_fr.mtl", include_str!("../../models/car/wheel_fr.mtl")),
    ("wheel_rl.mtl", include_str!("../../models/car/wheel_rl.mtl")),
    ("wheel_rr.mtl", include_str!("../../models/car/wheel_rr.mtl")),
    ("door_l.mtl", include_str!("../../models/car/door_l.mtl")),
    ("door_r.mtl", include_str!("../../models/car/door_r.mtl")),
    ("steering_wheel.mtl", include_str!("../../models/car/steering_wheel.mtl")),
    ("rig.json", include_str!("../../models/car/rig.json")),
];

/// Loads the embedded default car: one part per OBJ file, in the order of [`CAR_FILES`].
#[cfg(feature = "obj")]
pub fn load_default_car() -> Result<crate::mesh::Mesh, crate::mesh::MeshError> {
    use crate::mesh::{load_obj_text, Mesh, MeshError};
    let read = |p: &std::path::Path| -> Result<String, MeshError> {
        let name = p.to_string_lossy();
        CAR_FILES
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, t)| t.to_string())
            .ok_or_else(|| MeshError::NotFound { path: format!("(embedded car)/{name}") })
    };
    let mut mesh = Mesh::default();
    for (name, text) in CAR_FILES.iter().filter(|(n, _)| n.ends_with(".obj")) {
        let stem = name.trim_end_matches(".obj");
        mesh.append(load_obj_text(text, &format!("(embedded car)/{name}"), stem, None, &read)?);
    }
    Ok(mesh)
}
