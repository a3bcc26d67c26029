//! Writes generated parts as OBJ + MTL text, with shared vertices and rounded coordinates
//! so the committed files stay small and diff cleanly.

use super::shapes::Builder;
use glam::Vec3;
use std::collections::HashMap;
use std::fmt::Write;

/// A material to write into an MTL file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MtlMaterial {
    /// Name used by `usemtl`.
    pub name: &'static str,
    /// Diffuse albedo (`Kd`).
    pub kd: Vec3,
    /// Emission (`Ke`); zero for none.
    pub ke: Vec3,
    /// Grey specular reflectance (`Ks`); zero for a diffuse-only material.
    pub ks: f32,
    /// Phong exponent (`Ns`).
    pub ns: f32,
}

impl MtlMaterial {
    /// A diffuse material.
    pub const fn diffuse(name: &'static str, kd: Vec3) -> Self {
        MtlMaterial { name, kd, ke: Vec3::ZERO, ks: 0.0, ns: 1.0 }
    }
    /// A diffuse material with a Phong lobe.
    pub const fn glossy(name: &'static str, kd: Vec3, ks: f32, ns: f32) -> Self {
        MtlMaterial { name, kd, ke: Vec3::ZERO, ks, ns }
    }
    /// An emitter.
    pub const fn emitter(name: &'static str, kd: Vec3, ke: Vec3) -> Self {
        MtlMaterial { name, kd, ke, ks: 0.0, ns: 1.0 }
    }
}

/// OBJ text of one part (object `name`, referencing `mtl_file`), vertices rounded to 0.1 mm;
/// `header` becomes the first line's comment.
pub fn write_obj(header: &str, name: &str, mtl_file: &str, part: &Builder) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "# {header}");
    let _ = writeln!(out, "mtllib {mtl_file}\no {name}");
    let mut index: HashMap<[i32; 3], usize> = HashMap::new();
    let mut verts = String::new();
    let mut faces: Vec<(&'static str, [usize; 3])> = Vec::new();
    for (tri, mat) in &part.tris {
        let mut f = [0usize; 3];
        for (k, p) in tri.iter().enumerate() {
            let key = [(p.x * 1e4).round() as i32, (p.y * 1e4).round() as i32, (p.z * 1e4).round() as i32];
            let next = index.len() + 1;
            f[k] = *index.entry(key).or_insert_with(|| {
                let _ = writeln!(verts, "v {} {} {}", fmt4(key[0]), fmt4(key[1]), fmt4(key[2]));
                next
            });
        }
        if f[0] != f[1] && f[1] != f[2] && f[0] != f[2] {
            faces.push((mat, f));
        }
    }
    out += &verts;
    // Group faces by material, keeping first-use order.
    let mut order: Vec<&'static str> = Vec::new();
    for (m, _) in &faces {
        if !order.contains(m) {
            order.push(m);
        }
    }
    for m in order {
        let _ = writeln!(out, "usemtl {m}");
        for (_, f) in faces.iter().filter(|(fm, _)| *fm == m) {
            let _ = writeln!(out, "f {} {} {}", f[0], f[1], f[2]);
        }
    }
    out
}

fn fmt4(v: i32) -> String {
    let s = if v < 0 { "-" } else { "" };
    let a = v.unsigned_abs();
    let frac = format!("{:04}", a % 10_000);
    let frac = frac.trim_end_matches('0');
    if frac.is_empty() {
        format!("{s}{}", a / 10_000)
    } else {
        format!("{s}{}.{frac}", a / 10_000)
    }
}

/// An in-memory mesh of generated parts (same geometry as their OBJ files, before the 0.1 mm
/// rounding), degenerate triangles dropped; triangles name their material in `materials`.
pub fn mesh_of<'a>(
    parts: impl IntoIterator<Item = (&'a str, &'a Builder)>,
    materials: &[MtlMaterial],
) -> crate::mesh::Mesh {
    use crate::mesh::{Material, Mesh, Part, Triangle};
    let index = |name: &str| materials.iter().position(|m| m.name == name).unwrap_or(0) as u32;
    let parts = parts
        .into_iter()
        .map(|(name, b)| Part {
            name: name.to_string(),
            triangles: b
                .tris
                .iter()
                .filter(|(t, _)| !crate::mesh::is_degenerate(t))
                .map(|(t, m)| Triangle { positions: *t, uvs: None, material: index(m) })
                .collect(),
        })
        .collect();
    let materials = materials
        .iter()
        .map(|m| Material { emission: m.ke, specular: m.ks, shininess: m.ns, ..Material::new(m.name, m.kd) })
        .collect();
    Mesh { parts, materials, ..Default::default() }
}

/// MTL text for the given materials; `header` becomes the first line's comment.
pub fn write_mtl(header: &str, materials: &[MtlMaterial]) -> String {
    let mut out = format!("# {header}\n");
    for m in materials {
        let _ = writeln!(out, "\nnewmtl {}\nKd {} {} {}", m.name, m.kd.x, m.kd.y, m.kd.z);
        if m.ke != Vec3::ZERO {
            let _ = writeln!(out, "Ke {} {} {}", m.ke.x, m.ke.y, m.ke.z);
        }
        if m.ks > 0.0 {
            let _ = writeln!(out, "Ks {} {} {}\nNs {}", m.ks, m.ks, m.ks, m.ns);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn fixed_point_formatting() {
        assert_eq!(super::fmt4(12345), "1.2345");
        assert_eq!(super::fmt4(-500), "-0.05");
        assert_eq!(super::fmt4(20000), "2");
        assert_eq!(super::fmt4(0), "0");
    }
}
