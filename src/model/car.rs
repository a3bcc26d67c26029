//! The default car: a procedurally modelled hatchback in parts that can move — body (with
//! cabin, windows, bumpers, lights and a simple interior), four wheels (tyre with tread,
//! recessed rim, five spokes), two front doors and a steering wheel.
//!
//! Every part is written in assembled-car coordinates (so the parts loaded at the identity
//! transform form the whole car) and is modelled around a pivot recorded in `rig.json`:
//! wheels around their axle, doors around their hinge, the steering wheel around its column.
//! Units are metres; +X forward, +Y up, +Z to the car's right; the ground is y = 0.

use super::obj_writer::{write_mtl, write_obj, MtlMaterial};
use super::shapes::{smoothstep, Builder};
use glam::{Affine3A, Quat, Vec3};

/// Half the car's length.
const HALF_LEN: f32 = 2.2;
/// Wheel centre height = tyre radius.
const WHEEL_R: f32 = 0.33;
/// Axle positions along x.
const AXLE_X: [f32; 2] = [1.32, -1.32];
/// Wheel centre |z|.
const TRACK_Z: f32 = 0.79;
/// Top of the lower body / bottom of the windows.
const BELT: f32 = 0.98;
/// Front door extent along x; the hinge is at the front edge.
const DOOR_X: (f32, f32) = (-0.12, 0.9);
/// Door panel bottom.
const DOOR_Y0: f32 = 0.42;
/// How far door surfaces sit outside the body surface they cover.
const DOOR_GAP: f32 = 0.015;

/// The materials of the car (Kd in linear RGB; Ks grey).
pub const MATERIALS: &[MtlMaterial] = &[
    // Clear-coated paint, glass, chrome and rims carry a Phong lobe (Ks, Ns).
    MtlMaterial::glossy("paint", Vec3::new(0.62, 0.06, 0.04), 0.08, 250.0),
    MtlMaterial::glossy("glass", Vec3::new(0.07, 0.12, 0.17), 0.25, 1000.0),
    MtlMaterial::glossy("trim", Vec3::new(0.03, 0.03, 0.035), 0.04, 30.0),
    MtlMaterial::glossy("chrome", Vec3::new(0.25, 0.25, 0.26), 0.7, 600.0),
    MtlMaterial::emitter("headlight", Vec3::new(0.95, 0.93, 0.8), Vec3::new(4.0, 3.8, 3.0)),
    MtlMaterial::emitter("taillight", Vec3::new(0.7, 0.02, 0.02), Vec3::new(1.5, 0.0, 0.0)),
    MtlMaterial::diffuse("interior", Vec3::new(0.09, 0.085, 0.08)),
    MtlMaterial::diffuse("seat", Vec3::new(0.25, 0.2, 0.15)),
    MtlMaterial::glossy("tyre", Vec3::new(0.035, 0.035, 0.035), 0.03, 8.0),
    MtlMaterial::glossy("rim", Vec3::new(0.45, 0.45, 0.47), 0.5, 300.0),
    MtlMaterial::diffuse("rim_dark", Vec3::new(0.08, 0.08, 0.09)),
];

/// One generated part with its pivot.
pub struct CarPart {
    /// Part name (also the OBJ file stem).
    pub name: &'static str,
    /// Geometry.
    pub mesh: Builder,
    /// Pivot point (assembled-car coordinates).
    pub pivot: Vec3,
    /// Rotation axis through the pivot (unit).
    pub axis: Vec3,
    /// What the axis is for.
    pub joint: &'static str,
}

/// Lower body: half-height, centre height and half-width at station x.
fn body_section(x: f32) -> (f32, f32, f32) {
    let mut bottom = 0.3f32;
    for ax in AXLE_X {
        let dx = x - ax;
        let r = WHEEL_R + 0.07;
        if dx.abs() < r {
            bottom = bottom.max(WHEEL_R + (r * r - dx * dx).sqrt() * 0.95);
        }
    }
    let top = BELT - 0.16 * smoothstep(1.45, HALF_LEN, x) - 0.06 * smoothstep(-1.7, -HALF_LEN, x);
    // Round the nose and the tail in plan and in profile.
    let end = smoothstep(1.85, HALF_LEN, x).max(smoothstep(-1.95, -HALF_LEN, x));
    let f = (1.0 - end * end).max(0.0).sqrt();
    let half_w = 0.9 * (0.55 + 0.45 * f);
    let (mut hy, yc) = ((top - bottom) * 0.5, (top + bottom) * 0.5);
    hy *= 0.7 + 0.3 * f;
    (hy, yc, half_w)
}

/// Superellipse ring (exponent 4: a rounded box) of a cross-section at x.
fn ring(x: f32, hy: f32, yc: f32, hz: &dyn Fn(f32) -> f32, n: usize) -> Vec<Vec3> {
    (0..n)
        .map(|j| {
            let a = j as f32 / n as f32 * std::f32::consts::TAU;
            let (s, c) = a.sin_cos();
            let y = yc + hy * s.signum() * s.abs().sqrt();
            let z = hz(y) * c.signum() * c.abs().sqrt();
            Vec3::new(x, y, z)
        })
        .collect()
}

/// |z| of the lower body's side surface at (x, y).
fn body_side_z(x: f32, y: f32) -> f32 {
    let (hy, yc, hw) = body_section(x);
    let v = ((y - yc) / hy).clamp(-1.0, 1.0);
    hw * (1.0 - v.powi(4)).max(0.0).powf(0.25)
}

/// Cabin roof height at x, and its half-widths at the belt line and at the roof.
fn cabin_top(x: f32) -> f32 {
    let roof = 1.44;
    if x > 0.32 {
        roof - (roof - BELT) * smoothstep(0.32, 1.2, x).powf(0.8)
    } else if x < -0.85 {
        roof - (roof - BELT) * smoothstep(-0.85, -1.62, x).powf(0.9)
    } else {
        roof
    }
}
const CABIN_W_BELT: f32 = 0.83;
const CABIN_W_ROOF: f32 = 0.68;

fn cabin_half_w(y: f32) -> f32 {
    let t = ((y - BELT) / (1.44 - BELT)).clamp(0.0, 1.0);
    CABIN_W_BELT + (CABIN_W_ROOF - CABIN_W_BELT) * t * t
}

/// Stations along x, denser near the rounded ends.
fn stations(x0: f32, x1: f32, n: usize) -> Vec<f32> {
    (0..=n)
        .map(|i| {
            let u = i as f32 / n as f32;
            let w = 0.5 - 0.5 * (std::f32::consts::PI * u).cos();
            x0 + (x1 - x0) * (0.35 * u + 0.65 * w)
        })
        .collect()
}

fn body() -> Builder {
    let mut b = Builder::default();
    const N: usize = 56;
    let xs = stations(-HALF_LEN, HALF_LEN, 140);
    let rings: Vec<Vec<Vec3>> = xs
        .iter()
        .map(|&x| {
            let (hy, yc, hw) = body_section(x);
            ring(x, hy, yc, &|_| hw, N)
        })
        .collect();
    b.loft(&rings, true, &|_, _, c, n| {
        let az = c.z.abs();
        let front = c.x > 1.9 && n.x > 0.35;
        let rear = c.x < -2.0 && n.x < -0.35;
        Some(if front && n.x > 0.55 && (0.6..0.74).contains(&c.y) && (0.42..0.78).contains(&az) {
            "headlight"
        } else if front && n.x > 0.55 && (0.44..0.6).contains(&c.y) && az < 0.45 {
            "trim"
        } else if rear && n.x < -0.55 && (0.68..0.84).contains(&c.y) && (0.4..0.78).contains(&az) {
            "taillight"
        } else if c.y < 0.42 && n.y < -0.3 {
            "trim"
        } else if n.z.abs() > 0.6 && (DOOR_X.0..DOOR_X.1).contains(&c.x) && (DOOR_Y0..BELT).contains(&c.y) {
            "interior" // behind the door: seen when it opens
        } else {
            "paint"
        })
    });
    b.cap(&rings[0], "paint");
    let last = rings.last().cloned().unwrap_or_default();
    b.cap(&last.iter().rev().copied().collect::<Vec<_>>(), "paint");

    // Cabin: roof, pillars and glass; the front side windows belong to the doors, so the
    // cabin's sides are open there.
    let xs = stations(-1.62, 1.2, 96);
    let rings: Vec<Vec<Vec3>> = xs
        .iter()
        .map(|&x| {
            let hy = (cabin_top(x) - BELT).max(0.004);
            ring(x, hy, BELT, &|y| cabin_half_w(y), 48)
        })
        .collect();
    b.loft(&rings, true, &|_, _, c, n| {
        if c.y < BELT {
            return None; // inside the lower body
        }
        let top = cabin_top(c.x);
        let side = n.z.abs() > 0.55;
        if side && (DOOR_X.0 + 0.03..DOOR_X.1).contains(&c.x) {
            return None;
        }
        let below_roof = c.y < top - 0.05 && c.y > BELT + 0.05;
        let inside_pillars = c.z.abs() < cabin_half_w(c.y) - 0.08 && c.y > BELT + 0.04;
        Some(if side {
            if below_roof && c.x > -1.38 && !(-0.2..DOOR_X.0 + 0.03).contains(&c.x) {
                "glass"
            } else {
                "paint"
            }
        } else if n.x > 0.3 || n.x < -0.3 {
            // Windshield and rear window, framed by the pillars.
            if inside_pillars && c.y < 1.41 {
                "glass"
            } else {
                "trim"
            }
        } else {
            "paint"
        })
    });

    // Bumpers, mirrors, interior.
    let boxy = |c: Vec3, s: Vec3| Affine3A::from_scale_rotation_translation(s, Quat::IDENTITY, c);
    b.cube(boxy(Vec3::new(2.13, 0.4, 0.0), Vec3::new(0.16, 0.12, 1.5)), "trim");
    b.cube(boxy(Vec3::new(-2.14, 0.42, 0.0), Vec3::new(0.16, 0.12, 1.5)), "trim");
    for s in [-1.0f32, 1.0] {
        b.cube(boxy(Vec3::new(1.0, 1.04, s * 0.92), Vec3::new(0.1, 0.09, 0.16)), "paint");
        b.cube(boxy(Vec3::new(0.945, 1.04, s * 0.93), Vec3::new(0.012, 0.07, 0.13)), "glass");
        // Seats: cushion and backrest.
        b.cube(boxy(Vec3::new(-0.05, 0.55, s * 0.37), Vec3::new(0.5, 0.12, 0.48)), "seat");
        b.cube(
            Affine3A::from_scale_rotation_translation(
                Vec3::new(0.1, 0.6, 0.46),
                Quat::from_rotation_z(0.22),
                Vec3::new(-0.34, 0.86, s * 0.37),
            ),
            "seat",
        );
    }
    b.cube(boxy(Vec3::new(-0.9, 0.6, 0.0), Vec3::new(0.5, 0.2, 1.45)), "seat"); // rear bench
    b.cube(boxy(Vec3::new(0.0, 0.36, 0.0), Vec3::new(3.2, 0.04, 1.6)), "interior"); // floor
    b.cube(boxy(Vec3::new(0.82, 0.86, 0.0), Vec3::new(0.38, 0.22, 1.5)), "interior"); // dashboard
    b
}

fn wheel(centre: Vec3, outward: f32) -> Builder {
    let mut b = Builder::default();
    // Local z = the axle, pointing out of the car.
    let frame = Affine3A::from_rotation_translation(
        if outward > 0.0 { Quat::IDENTITY } else { Quat::from_rotation_y(std::f32::consts::PI) },
        centre,
    );
    let (w, r_rim) = (0.11f32, 0.215f32);
    // Tyre cross-section, from the inner rim edge round the tread to the outer rim edge.
    let tyre: Vec<(f32, f32, &'static str)> = vec![
        (r_rim, -w * 0.85, "tyre"),
        (0.26, -w, "tyre"),
        (0.305, -w * 0.97, "tyre"),
        (WHEEL_R - 0.005, -w * 0.8, "tyre"),
        (WHEEL_R, -w * 0.5, "tyre"),
        (WHEEL_R, 0.0, "tyre"),
        (WHEEL_R, w * 0.5, "tyre"),
        (WHEEL_R - 0.005, w * 0.8, "tyre"),
        (0.305, w * 0.97, "tyre"),
        (0.26, w, "tyre"),
        (r_rim, w * 0.85, "tyre"),
    ];
    // Tread blocks: grooves cut 9 mm into the outer profile points every 1/36 turn.
    b.lathe(frame, &tyre, 144, &|a, k, r| {
        let groove = (a / std::f32::consts::TAU * 36.0).fract() < 0.3;
        if (3..=7).contains(&k) && groove {
            r - 0.009
        } else {
            r
        }
    });
    // Rim: lip, dark recessed dish, hub.
    let rim: Vec<(f32, f32, &'static str)> = vec![
        (r_rim, w * 0.85, "rim"),
        (r_rim - 0.02, w * 0.8, "rim"),
        (r_rim - 0.025, w * 0.35, "rim_dark"),
        (0.06, w * 0.3, "rim"),
        (0.06, w * 0.55, "rim"),
        (0.0, w * 0.6, "rim"),
    ];
    b.lathe(frame, &rim, 72, &|_, _, r| r);
    let back: Vec<(f32, f32, &'static str)> = vec![(0.0, -w * 0.5, "rim_dark"), (r_rim, -w * 0.5, "rim_dark")];
    b.lathe(frame, &back, 36, &|_, _, r| r);
    // Five spokes from the hub to the lip, proud of the dish.
    for k in 0..5 {
        let a = k as f32 / 5.0 * std::f32::consts::TAU;
        let m = frame
            * Affine3A::from_rotation_z(a)
            * Affine3A::from_scale_rotation_translation(
                Vec3::new(0.15, 0.036, 0.03),
                Quat::IDENTITY,
                Vec3::new(0.125, 0.0, w * 0.5),
            );
        b.cube(m, "rim");
    }
    b
}

/// Points of a door surface offset outward from the body (below the belt) or the cabin
/// (above it).
fn door_surface(x: f32, y: f32, side: f32, inset: f32) -> Vec3 {
    // Below the belt follow the body's side, but never tuck under it (near the wheel arch the
    // body's underside rises above the door's bottom edge).
    let z = if y <= BELT { body_side_z(x, y).max(0.93 * body_section(x).2) } else { cabin_half_w(y) };
    Vec3::new(x, y, side * (z + DOOR_GAP - inset))
}

fn door(side: f32) -> Builder {
    let mut b = Builder::default();
    let (nu, nv) = (40usize, 36usize);
    let top = |x: f32| cabin_top(x) - 0.035;
    let grid = |inset: f32| -> Vec<Vec<Vec3>> {
        (0..=nu)
            .map(|i| {
                let x = DOOR_X.0 + (DOOR_X.1 - DOOR_X.0) * i as f32 / nu as f32;
                (0..=nv)
                    .map(|j| {
                        let y = DOOR_Y0 + (top(x) - DOOR_Y0) * j as f32 / nv as f32;
                        door_surface(x, y, side, inset)
                    })
                    .collect()
            })
            .collect()
    };
    let outer = grid(0.0);
    let inner = grid(0.05);
    let outer_mat = |c: Vec3| {
        let in_window = c.y > BELT + 0.03
            && c.y < cabin_top(c.x) - 0.075
            && c.x > DOOR_X.0 + 0.05
            && c.x < DOOR_X.1 - 0.04 - (c.y - BELT) * 0.5;
        if in_window {
            "glass"
        } else if c.y > BELT - 0.01 && c.y < BELT + 0.03 {
            "trim"
        } else {
            "paint"
        }
    };
    // Face winding must point outward: outward is +z on the right (side > 0).
    let flip = side < 0.0;
    b.loft(&outer, false, &|_, _, c, _| Some(outer_mat(c)));
    b.loft(&inner, false, &|_, _, _, _| Some("interior"));
    if flip {
        for t in &mut b.tris {
            t.0.swap(1, 2);
        }
    }
    // Edges joining the outer and inner skins.
    let edges: [Vec<(usize, usize)>; 4] = [
        (0..=nv).map(|j| (0, j)).collect(),
        (0..=nv).map(|j| (nu, j)).collect(),
        (0..=nu).map(|i| (i, 0)).collect(),
        (0..=nu).map(|i| (i, nv)).collect(),
    ];
    for e in edges {
        for w in e.windows(2) {
            let (a, c) = (w[0], w[1]);
            b.quad(outer[a.0][a.1], outer[c.0][c.1], inner[c.0][c.1], inner[a.0][a.1], "trim");
        }
    }
    // Handle near the rear edge.
    let p = door_surface(DOOR_X.0 + 0.18, 0.86, side, -0.012);
    b.cube(Affine3A::from_scale_rotation_translation(Vec3::new(0.16, 0.03, 0.025), Quat::IDENTITY, p), "chrome");
    b
}

/// Centre of the steering wheel and the unit column axis (pointing from the wheel towards
/// the dashboard).
pub fn steering_pivot() -> (Vec3, Vec3) {
    (Vec3::new(0.42, 0.95, -0.37), Vec3::new(1.0, -0.6, 0.0).normalize())
}

fn steering_wheel() -> Builder {
    let mut b = Builder::default();
    let (c, axis) = steering_pivot();
    let frame = Affine3A::from_rotation_translation(Quat::from_rotation_arc(Vec3::Z, -axis), c);
    b.torus(frame, 0.185, 0.018, 64, 14, "trim");
    for k in 0..3 {
        let a = std::f32::consts::FRAC_PI_2 + k as f32 / 3.0 * std::f32::consts::TAU;
        let m = frame
            * Affine3A::from_rotation_z(a)
            * Affine3A::from_scale_rotation_translation(
                Vec3::new(0.17, 0.03, 0.015),
                Quat::IDENTITY,
                Vec3::new(0.09, 0.0, 0.0),
            );
        b.cube(m, if k == 0 { "chrome" } else { "interior" });
    }
    b.lathe(
        frame,
        &[(0.0, 0.02, "interior"), (0.05, 0.02, "interior"), (0.05, -0.02, "interior"), (0.0, -0.02, "interior")],
        24,
        &|_, _, r| r,
    );
    // Column towards the dashboard.
    b.lathe(frame, &[(0.02, -0.02, "interior"), (0.02, -0.3, "interior")], 16, &|_, _, r| r);
    b
}

/// Part names in load order (the embedded car's instance numbering).
pub const PART_NAMES: [&str; 8] =
    ["body", "wheel_fl", "wheel_fr", "wheel_rl", "wheel_rr", "door_l", "door_r", "steering_wheel"];

/// Pivot point and unit axis of every part, in [`PART_NAMES`] order (what `rig.json` records).
pub fn rig() -> [(Vec3, Vec3); 8] {
    let wheel = |x: f32, z: f32| (Vec3::new(x, WHEEL_R, z), Vec3::Z);
    let hinge = |side: f32| (Vec3::new(DOOR_X.1, 0.0, side * (body_side_z(DOOR_X.1, 0.7) + DOOR_GAP)), Vec3::Y * side);
    [
        (Vec3::ZERO, Vec3::Y),
        wheel(AXLE_X[0], -TRACK_Z),
        wheel(AXLE_X[0], TRACK_Z),
        wheel(AXLE_X[1], -TRACK_Z),
        wheel(AXLE_X[1], TRACK_Z),
        hinge(-1.0),
        hinge(1.0),
        steering_pivot(),
    ]
}

/// Wheel radius (m).
pub const WHEEL_RADIUS: f32 = WHEEL_R;
/// Distance between the axles (m).
pub const WHEELBASE: f32 = AXLE_X[0] - AXLE_X[1];

/// Builds every part of the car.
pub fn build() -> Vec<CarPart> {
    let rig = rig();
    let meshes = [
        body(),
        wheel(rig[1].0, -1.0),
        wheel(rig[2].0, 1.0),
        wheel(rig[3].0, -1.0),
        wheel(rig[4].0, 1.0),
        door(-1.0),
        door(1.0),
        steering_wheel(),
    ];
    let joints = [
        "chassis",
        "axle (spin); front wheels also steer about +Y",
        "axle (spin); front wheels also steer about +Y",
        "axle (spin)",
        "axle (spin)",
        "hinge (positive angles open)",
        "hinge (positive angles open)",
        "column",
    ];
    let mut parts = Vec::new();
    for (i, mesh) in meshes.into_iter().enumerate() {
        parts.push(CarPart { name: PART_NAMES[i], mesh, pivot: rig[i].0, axis: rig[i].1, joint: joints[i] });
    }
    parts
}

/// The car as an in-memory mesh (same geometry as the OBJ files, before their 0.1 mm
/// rounding), for callers built without OBJ support.
pub fn mesh() -> crate::mesh::Mesh {
    let parts = build();
    super::obj_writer::mesh_of(parts.iter().map(|p| (p.name, &p.mesh)), MATERIALS)
}

/// The generated files: (file name, contents), for `models/car/`.
pub fn files() -> Vec<(String, String)> {
    let parts = build();
    let mut out = Vec::new();
    let mut rig = String::from("{\n  \"units\": \"metres; +X forward, +Y up, +Z right; ground at y = 0\",\n");
    rig += &format!("  \"wheel_radius\": {WHEEL_R},\n  \"door_open_deg\": 70,\n  \"steer_max_deg\": 30,\n  \"steering_ratio\": 15,\n  \"parts\": [\n");
    for (i, p) in parts.iter().enumerate() {
        let used: Vec<MtlMaterial> =
            MATERIALS.iter().copied().filter(|m| p.mesh.tris.iter().any(|t| t.1 == m.name)).collect();
        out.push((
            format!("{}.obj", p.name),
            write_obj(
                &format!("voxray default car: part '{}' (generated by `voxray model car`)", p.name),
                p.name,
                &format!("{}.mtl", p.name),
                &p.mesh,
            ),
        ));
        out.push((
            format!("{}.mtl", p.name),
            write_mtl("voxray default car materials (generated by `voxray model car`)", &used),
        ));
        let parent = if p.name == "body" { "null".to_string() } else { "\"body\"".to_string() };
        rig += &format!(
            "    {{\"name\": \"{}\", \"obj\": \"{}.obj\", \"parent\": {parent}, \"joint\": \"{}\", \"pivot\": [{:.4}, {:.4}, {:.4}], \"axis\": [{:.4}, {:.4}, {:.4}]}}{}\n",
            p.name, p.name, p.joint, p.pivot.x, p.pivot.y, p.pivot.z, p.axis.x, p.axis.y, p.axis.z,
            if i + 1 < parts.len() { "," } else { "" }
        );
    }
    rig += "  ]\n}\n";
    out.push(("rig.json".into(), rig));
    out
}
