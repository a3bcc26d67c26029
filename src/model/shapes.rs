//! Small mesh-building helpers for generated models: lofts, lathes, tori and boxes, each
//! emitting triangles tagged with a material name.

use glam::{Affine3A, Vec3};

/// Triangles tagged with material names, collected while building one part.
#[derive(Clone, Debug, Default)]
pub struct Builder {
    /// (vertices, material) per triangle.
    pub tris: Vec<([Vec3; 3], &'static str)>,
}

impl Builder {
    /// Adds a triangle.
    pub fn tri(&mut self, a: Vec3, b: Vec3, c: Vec3, mat: &'static str) {
        self.tris.push(([a, b, c], mat));
    }
    /// Adds a quad (a, b, c, d in order around it) as two triangles.
    pub fn quad(&mut self, a: Vec3, b: Vec3, c: Vec3, d: Vec3, mat: &'static str) {
        self.tri(a, b, c, mat);
        self.tri(a, c, d, mat);
    }
    /// Connects consecutive rings of equal length with quads; `closed` joins each ring's
    /// last point to its first. `mat(i, j, centre, normal)` picks the material of the quad
    /// between rings i, i+1 and points j, j+1. `skip` drops quads (openings).
    pub fn loft(
        &mut self,
        rings: &[Vec<Vec3>],
        closed: bool,
        mat: &dyn Fn(usize, usize, Vec3, Vec3) -> Option<&'static str>,
    ) {
        for i in 0..rings.len().saturating_sub(1) {
            let (r0, r1) = (&rings[i], &rings[i + 1]);
            // Closed rings: orient normals away from the ring's centre (outward).
            let axis_c = (r0.iter().chain(r1.iter()).copied().sum::<Vec3>()) / (r0.len() + r1.len()) as f32;
            let m = r0.len();
            let segs = if closed { m } else { m - 1 };
            for j in 0..segs {
                let k = (j + 1) % m;
                let (a, b, c, d) = (r0[j], r0[k], r1[k], r1[j]);
                let centre = (a + b + c + d) * 0.25;
                let mut normal = (c - a).cross(d - b).normalize_or_zero();
                if closed && normal.dot(centre - axis_c) < 0.0 {
                    normal = -normal;
                }
                if let Some(name) = mat(i, j, centre, normal) {
                    self.quad(a, b, c, d, name);
                }
            }
        }
    }
    /// Closes a ring with a fan around its centroid.
    pub fn cap(&mut self, ring: &[Vec3], mat: &'static str) {
        let c = ring.iter().copied().sum::<Vec3>() / ring.len() as f32;
        for j in 0..ring.len() {
            self.tri(c, ring[(j + 1) % ring.len()], ring[j], mat);
        }
    }
    /// An axis-aligned box in the frame `m` (unit cube [-0.5, 0.5]³ mapped by `m`).
    pub fn cube(&mut self, m: Affine3A, mat: &'static str) {
        let p = |x: f32, y: f32, z: f32| m.transform_point3(Vec3::new(x, y, z) - 0.5);
        let v = [
            p(0., 0., 0.),
            p(1., 0., 0.),
            p(1., 1., 0.),
            p(0., 1., 0.),
            p(0., 0., 1.),
            p(1., 0., 1.),
            p(1., 1., 1.),
            p(0., 1., 1.),
        ];
        for f in [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [2, 3, 7, 6], [1, 2, 6, 5], [0, 4, 7, 3]] {
            self.quad(v[f[0]], v[f[1]], v[f[2]], v[f[3]], mat);
        }
    }
    /// Revolves a closed profile of (radius, axial offset, material) points around the
    /// frame's local z axis; `radius_at(angle, profile_index, r)` may modulate the radius.
    pub fn lathe(
        &mut self,
        frame: Affine3A,
        profile: &[(f32, f32, &'static str)],
        segments: usize,
        radius_at: &dyn Fn(f32, usize, f32) -> f32,
    ) {
        let ring = |s: usize| -> Vec<Vec3> {
            let a = s as f32 / segments as f32 * std::f32::consts::TAU;
            profile
                .iter()
                .enumerate()
                .map(|(k, &(r, z, _))| {
                    let r = radius_at(a, k, r);
                    frame.transform_point3(Vec3::new(r * a.cos(), r * a.sin(), z))
                })
                .collect()
        };
        let rings: Vec<Vec<Vec3>> = (0..=segments).map(ring).collect();
        for s in 0..segments {
            for k in 0..profile.len() - 1 {
                let (a, b, c, d) = (rings[s][k], rings[s][k + 1], rings[s + 1][k + 1], rings[s + 1][k]);
                self.quad(a, b, c, d, profile[k].2);
            }
        }
    }
    /// A torus around the frame's local z axis.
    pub fn torus(
        &mut self,
        frame: Affine3A,
        major: f32,
        minor: f32,
        seg_major: usize,
        seg_minor: usize,
        mat: &'static str,
    ) {
        let profile: Vec<(f32, f32, &'static str)> = (0..=seg_minor)
            .map(|k| {
                let b = k as f32 / seg_minor as f32 * std::f32::consts::TAU;
                (major + minor * b.cos(), minor * b.sin(), mat)
            })
            .collect();
        self.lathe(frame, &profile, seg_major, &|_, _, r| r);
    }
}

/// Hermite smoothstep of x between e0 and e1 (either order).
pub fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}
