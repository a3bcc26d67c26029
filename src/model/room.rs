//! The coloured-wall box (`voxray model box` writes `models/box/`): a closed room in the
//! manner of the Cornell box — red wall on the left (−X), green on the right (+X), white
//! floor, back, front and ceiling — with a skylight in the ceiling through which the sun
//! strikes the floor and the lower red wall, and two white blocks. Everything beyond the
//! sunlit patch is lit indirectly, so the scene shows colour bleeding and ambient occlusion
//! plainly; it is the GI accuracy scene (docs/accuracy.md).
//!
//! The walls are single sheets whose triangles face into the room. A room of thick slabs lit
//! by the sun had sunlit outer faces, and the GI volume's coarse levels averaged them with the
//! inner faces: light leaked through every wall (isotropic voxel cone tracing's known limit),
//! which this scene is not meant to measure.

use super::obj_writer::{write_mtl, write_obj, MtlMaterial};
use super::shapes::Builder;
use crate::mesh::Mesh;
use crate::scene::{Ambient, Camera, Lights, Sun};
use glam::{Affine3A, DVec3, Quat, Vec3};

/// The room's materials (linear albedo; the Cornell box's classic values).
pub const MATERIALS: &[MtlMaterial] = &[
    MtlMaterial::diffuse("white", Vec3::new(0.73, 0.73, 0.73)),
    MtlMaterial::diffuse("red", Vec3::new(0.63, 0.065, 0.05)),
    MtlMaterial::diffuse("green", Vec3::new(0.14, 0.45, 0.09)),
];

/// Inside half-width of the room (metres); the inside spans x, z ∈ [−1, 1], y ∈ [0, 2].
pub const HALF: f32 = 1.0;
/// The skylight: x and z ranges of the opening in the ceiling.
pub const SKYLIGHT: ([f32; 2], [f32; 2]) = ([-0.45, 0.75], [-0.7, 0.4]);

/// A rectangle (corners in order around it) facing the room's centre.
pub(crate) fn inward(b: &mut Builder, q: [Vec3; 4], mat: &'static str) {
    // Facing a point is facing away from its mirror image through the rectangle's middle.
    let mid = (q[0] + q[1] + q[2] + q[3]) * 0.25;
    facing_away(b, q, mid * 2.0 - Vec3::new(0.0, HALF, 0.0), mat);
}

/// The parts: `room` (walls, floor, ceiling), `tall_block`, `short_block`.
pub fn build() -> Vec<(&'static str, Builder)> {
    let h = HALF;
    let top = 2.0 * h;
    let v = Vec3::new;
    let mut room = Builder::default();
    inward(&mut room, [v(-h, 0.0, -h), v(h, 0.0, -h), v(h, 0.0, h), v(-h, 0.0, h)], "white"); // floor
    inward(&mut room, [v(-h, 0.0, -h), v(h, 0.0, -h), v(h, top, -h), v(-h, top, -h)], "white"); // back
    inward(&mut room, [v(-h, 0.0, h), v(h, 0.0, h), v(h, top, h), v(-h, top, h)], "white"); // front
    inward(&mut room, [v(-h, 0.0, -h), v(-h, 0.0, h), v(-h, top, h), v(-h, top, -h)], "red"); // left
    inward(&mut room, [v(h, 0.0, -h), v(h, 0.0, h), v(h, top, h), v(h, top, -h)], "green"); // right
                                                                                            // The ceiling: four rectangles around the skylight.
    let ([x0, x1], [z0, z1]) = SKYLIGHT;
    let ceiling = |b: &mut Builder, xa: f32, xb: f32, za: f32, zb: f32| {
        inward(b, [v(xa, top, za), v(xb, top, za), v(xb, top, zb), v(xa, top, zb)], "white")
    };
    ceiling(&mut room, -h, x0, -h, h);
    ceiling(&mut room, x1, h, -h, h);
    ceiling(&mut room, x0, x1, -h, z0);
    ceiling(&mut room, x0, x1, z1, h);
    let mut parts = vec![("room", room)];
    parts.extend(blocks());
    parts
}

/// The two white blocks standing on the floor, as parts (shared with the panel room).
pub(crate) fn blocks() -> [(&'static str, Builder); 2] {
    let block = |size: Vec3, turn_deg: f32, at: Vec3| {
        let mut b = Builder::default();
        let m = Affine3A::from_scale_rotation_translation(
            size,
            Quat::from_rotation_y(turn_deg.to_radians()),
            at + Vec3::Y * (size.y * 0.5),
        );
        b.cube(m, "white");
        b
    };
    [
        ("tall_block", block(Vec3::new(0.55, 1.2, 0.55), 20.0, Vec3::new(-0.35, 0.0, -0.4))),
        ("short_block", block(Vec3::new(0.55, 0.55, 0.55), -18.0, Vec3::new(0.4, 0.0, 0.25))),
    ]
}

/// Thickness of the thick-walled box's walls (metres): six cells of the GI volume's default
/// 128³ over the room, so they are solid at the finest levels and blend inner and outer faces
/// only from the third coarser level on.
pub const THICK_WALL: f32 = 0.12;

/// A rectangle (corners in order around it) facing away from `from`.
fn facing_away(b: &mut Builder, q: [Vec3; 4], from: Vec3, mat: &'static str) {
    let normal = (q[2] - q[0]).cross(q[3] - q[1]);
    let mid = (q[0] + q[1] + q[2] + q[3]) * 0.25;
    if normal.dot(mid - from) >= 0.0 {
        b.quad(q[0], q[1], q[2], q[3], mat);
    } else {
        b.quad(q[3], q[2], q[1], q[0], mat);
    }
}

/// The box with walls [`THICK_WALL`] thick: the same room, blocks, skylight, camera and
/// lights, wrapped in an outer shell whose faces look outwards and a well joining the
/// skylight's two openings. The sun lights the shell's roof and two of its walls from outside;
/// none of that light can reach the room except through the skylight, so light seen inside
/// through a wall is a leak (isotropic cone tracing's known failure, docs/gi.md).
pub fn thick_build() -> Vec<(&'static str, Builder)> {
    let mut parts = build();
    let (h, t) = (HALF, THICK_WALL);
    let (o, top, bottom) = (h + t, 2.0 * h + t, -t);
    let v = Vec3::new;
    let centre = v(0.0, h, 0.0);
    let shell = &mut parts[0].1;
    facing_away(shell, [v(-o, bottom, -o), v(o, bottom, -o), v(o, bottom, o), v(-o, bottom, o)], centre, "white");
    facing_away(shell, [v(-o, bottom, -o), v(o, bottom, -o), v(o, top, -o), v(-o, top, -o)], centre, "white");
    facing_away(shell, [v(-o, bottom, o), v(o, bottom, o), v(o, top, o), v(-o, top, o)], centre, "white");
    facing_away(shell, [v(-o, bottom, -o), v(-o, bottom, o), v(-o, top, o), v(-o, top, -o)], centre, "white");
    facing_away(shell, [v(o, bottom, -o), v(o, bottom, o), v(o, top, o), v(o, top, -o)], centre, "white");
    let ([x0, x1], [z0, z1]) = SKYLIGHT;
    let roof = |b: &mut Builder, xa: f32, xb: f32, za: f32, zb: f32| {
        facing_away(b, [v(xa, top, za), v(xb, top, za), v(xb, top, zb), v(xa, top, zb)], centre, "white")
    };
    roof(shell, -o, x0, -o, o);
    roof(shell, x1, o, -o, o);
    roof(shell, x0, x1, -o, z0);
    roof(shell, x0, x1, z1, o);
    // The well: four sides from the ceiling up to the roof, facing the skylight's axis.
    let axis = v((x0 + x1) * 0.5, 2.0 * h + t * 0.5, (z0 + z1) * 0.5);
    let (y0, y1) = (2.0 * h, top);
    for q in [
        [v(x0, y0, z0), v(x1, y0, z0), v(x1, y1, z0), v(x0, y1, z0)],
        [v(x0, y0, z1), v(x1, y0, z1), v(x1, y1, z1), v(x0, y1, z1)],
        [v(x0, y0, z0), v(x0, y0, z1), v(x0, y1, z1), v(x0, y1, z0)],
        [v(x1, y0, z0), v(x1, y0, z1), v(x1, y1, z1), v(x1, y1, z0)],
    ] {
        // Facing the axis is facing away from the mirror image of the axis behind the side.
        let mid = (q[0] + q[1] + q[2] + q[3]) * 0.25;
        facing_away(shell, q, mid * 2.0 - axis, "white");
    }
    parts
}

/// The thick-walled box as an in-memory mesh ([`thick_build`]).
pub fn thick_mesh() -> Mesh {
    let parts = thick_build();
    super::obj_writer::mesh_of(parts.iter().map(|(n, b)| (*n, b)), MATERIALS)
}

/// The room as an in-memory mesh.
pub fn mesh() -> Mesh {
    let parts = build();
    super::obj_writer::mesh_of(parts.iter().map(|(n, b)| (*n, b)), MATERIALS)
}

/// The room with glossy white surfaces (floor, back, front, ceiling and blocks: a Phong lobe
/// of reflectance 0.25 and exponent 100 on the white albedo): the scene on which the
/// specular cone is checked against the path-traced reference.
pub fn glossy_mesh() -> Mesh {
    let mut mesh = mesh();
    for m in mesh.materials.iter_mut().filter(|m| m.name == "white") {
        m.specular = 0.25;
        m.shininess = 100.0;
    }
    mesh
}

/// The camera: standing a little inside the front wall (clear of its voxels at any depth
/// from 4 on), looking at the back wall.
pub fn camera(width: u32, height: u32) -> Camera {
    Camera {
        eye: DVec3::new(0.0, 1.0, 0.9),
        target: DVec3::new(0.0, 0.8, -1.0),
        up: DVec3::Y,
        vfov_deg: 72.0,
        width,
        height,
    }
}

/// The lights: a sun low enough to reach the lower red wall through the skylight, and a sky
/// seen only through it.
pub fn lights() -> Lights {
    Lights {
        sun: Some(Sun { to_sun: Vec3::new(0.75, 1.0, 0.15).normalize(), irradiance: Vec3::new(7.0, 6.8, 6.3) }),
        ambient: Some(Ambient { radiance: Vec3::new(0.25, 0.3, 0.38) }),
        use_mtl_emitters: false,
        ..Lights::default()
    }
}

/// The generated files: (file name, contents), for `models/box/`: one OBJ with the three
/// parts as objects, its MTL, and the camera and lights JSON.
pub fn files() -> Vec<(String, String)> {
    files_of(build(), "voxray coloured-wall box (generated by `voxray model box`)")
}

/// [`files`] of the thick-walled box ([`thick_build`]), for `models/thick-box/`.
pub fn thick_files() -> Vec<(String, String)> {
    files_of(thick_build(), "voxray coloured-wall box with thick walls (generated by `voxray model thick-box`)")
}

fn files_of(parts: Vec<(&'static str, Builder)>, header: &str) -> Vec<(String, String)> {
    let mut obj = String::new();
    for (i, (name, b)) in parts.iter().enumerate() {
        let text = write_obj(header, name, "box.mtl", b);
        // One file, three objects: OBJ indices are global, so later objects' faces shift.
        obj += &if i == 0 { text } else { shift_faces(&text, &obj) };
    }
    let mtl = write_mtl("voxray coloured-wall box materials (generated by `voxray model box`)", MATERIALS);
    let c = camera(640, 480);
    let camera_json = format!(
        "{{\"eye\": [{}, {}, {}], \"target\": [{}, {}, {}], \"up\": [0, 1, 0], \"vfov_deg\": {}, \"width\": {}, \"height\": {}}}\n",
        c.eye.x, c.eye.y, c.eye.z, c.target.x, c.target.y, c.target.z, c.vfov_deg, c.width, c.height
    );
    let l = lights();
    let sun = l.sun.unwrap_or(Sun { to_sun: Vec3::Y, irradiance: Vec3::ZERO });
    let sky = l.sky();
    let lights_json = format!(
        "{{\"sun\": {{\"to_sun\": [{:.6}, {:.6}, {:.6}], \"irradiance\": [{}, {}, {}]}}, \"ambient\": {{\"radiance\": [{}, {}, {}]}}, \"use_mtl_emitters\": false}}\n",
        sun.to_sun.x, sun.to_sun.y, sun.to_sun.z, sun.irradiance.x, sun.irradiance.y, sun.irradiance.z, sky.x, sky.y, sky.z
    );
    vec![
        ("box.obj".into(), obj),
        ("box.mtl".into(), mtl),
        ("camera.json".into(), camera_json),
        ("lights.json".into(), lights_json),
    ]
}

/// Drops the header lines of a later object's OBJ text and offsets its face indices by the
/// vertices already written in `before`.
pub(crate) fn shift_faces(text: &str, before: &str) -> String {
    let base = before.lines().filter(|l| l.starts_with("v ")).count();
    let mut out = String::new();
    for line in text.lines() {
        if line.starts_with('#') || line.starts_with("mtllib") {
            continue;
        }
        if let Some(rest) = line.strip_prefix("f ") {
            let idx: Vec<String> =
                rest.split_whitespace().map(|v| (v.parse::<usize>().unwrap_or(0) + base).to_string()).collect();
            out += &format!("f {}\n", idx.join(" "));
        } else {
            out += line;
            out.push('\n');
        }
    }
    out
}
