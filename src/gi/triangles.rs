//! The source triangles as the path-traced reference's geometry: every instance's triangles
//! placed in the world (camera-relative, as the renderer's hit points are), a bounding volume
//! hierarchy over them, and hits with the same surface record the voxels give — material
//! packed the same way, so only the geometry differs. A reference traced through them counts
//! the voxelization's own error in the error it reports.

use crate::mesh::{Material, Mesh};
use crate::render::hitbuffer::HitRecord;
use crate::scene::Scene;
use crate::svo::Attr;
use glam::{DVec3, Vec2, Vec3};

/// Triangles per leaf, at most.
const LEAF: usize = 4;

/// Why the triangles cannot stand in for a scene.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum TriangleSceneError {
    /// An instance's part has no triangles in the mesh (a generated part such as the ground).
    #[error("part {part} of the scene has no source triangles (the mesh has {parts} parts); the triangle reference needs every part's triangles")]
    MissingPart {
        /// The scene's part index.
        part: usize,
        /// Parts in the mesh.
        parts: usize,
    },
}

/// One placed triangle.
#[derive(Clone, Copy, Debug)]
struct Placed {
    /// Camera-relative corners.
    p: [DVec3; 3],
    /// Texture coordinates, if any.
    uv: Option<[Vec2; 3]>,
    /// Material index in the mesh.
    material: u32,
    /// The instance it belongs to.
    instance: i32,
}

/// A node of the hierarchy: a box and either two children (`count == 0`: `first` is the left
/// child, the right one follows it) or `count` triangles from `first`.
#[derive(Clone, Copy, Debug)]
struct Node {
    lo: DVec3,
    hi: DVec3,
    first: u32,
    count: u32,
}

/// The scene's instances as triangles, with a hierarchy for nearest-hit and shadow queries.
pub struct TriangleScene {
    tris: Vec<Placed>,
    nodes: Vec<Node>,
    materials: Vec<Material>,
    /// How far a ray leaving a surface starts off it (world units): 10⁻⁶ of the scene's size.
    offset: f32,
}

impl TriangleScene {
    /// Places `mesh`'s part `i` at every instance of the scene's part `i` (the order
    /// [`crate::pipeline::build_parts`] keeps), camera-relative to `eye`.
    pub fn new(mesh: &Mesh, scene: &Scene, eye: DVec3) -> Result<Self, TriangleSceneError> {
        let mut tris = Vec::new();
        for (i, inst) in scene.instances().iter().enumerate() {
            let part = mesh
                .parts
                .get(inst.part)
                .ok_or(TriangleSceneError::MissingPart { part: inst.part, parts: mesh.parts.len() })?;
            let world = scene.world(i);
            for t in &part.triangles {
                let p = t.positions.map(|v| world.transform_point3(v.as_dvec3()) - eye);
                tris.push(Placed { p, uv: t.uvs, material: t.material, instance: i as i32 });
            }
        }
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for t in &tris {
            for p in t.p {
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        let size = if tris.is_empty() { 1.0 } else { (hi - lo).max_element().max(1e-30) };
        let mut s = TriangleScene { tris, nodes: Vec::new(), materials: mesh.materials.clone(), offset: 0.0 };
        s.offset = (size * 1e-6) as f32;
        let n = s.tris.len();
        s.nodes.push(Node { lo, hi, first: 0, count: n as u32 });
        if n > LEAF {
            s.split(0);
        }
        Ok(s)
    }

    /// Triangles placed.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// Splits node `k` at the median of its triangles' centres along its box's longest
    /// axis, recursively (an explicit stack: deep meshes do not overflow the call stack).
    fn split(&mut self, root: usize) {
        let mut todo = vec![root];
        while let Some(k) = todo.pop() {
            let Node { first, count, .. } = self.nodes[k];
            let (first, count) = (first as usize, count as usize);
            let tris = &mut self.tris[first..first + count];
            let centre = |t: &Placed| (t.p[0] + t.p[1] + t.p[2]) / 3.0;
            let (mut clo, mut chi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
            for t in tris.iter() {
                clo = clo.min(centre(t));
                chi = chi.max(centre(t));
            }
            let axis = (chi - clo).max_position();
            let half = count / 2;
            tris.select_nth_unstable_by(half, |a, b| centre(a)[axis].total_cmp(&centre(b)[axis]));
            let left = self.nodes.len();
            for (f, c) in [(first, half), (first + half, count - half)] {
                let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
                for t in &self.tris[f..f + c] {
                    for p in t.p {
                        lo = lo.min(p);
                        hi = hi.max(p);
                    }
                }
                self.nodes.push(Node { lo, hi, first: f as u32, count: c as u32 });
            }
            self.nodes[k] = Node { first: left as u32, count: 0, ..self.nodes[k] };
            for child in [left, left + 1] {
                if self.nodes[child].count as usize > LEAF {
                    todo.push(child);
                }
            }
        }
    }

    /// Where the ray o + t·d (d unit) first meets triangle `t` in (0, t_max): t and the
    /// barycentric coordinates of the second and third corners (Möller–Trumbore, f64).
    fn intersect(t: &Placed, o: DVec3, d: DVec3, t_max: f64) -> Option<(f64, f64, f64)> {
        let (e1, e2) = (t.p[1] - t.p[0], t.p[2] - t.p[0]);
        let pv = d.cross(e2);
        let det = e1.dot(pv);
        if det.abs() < 1e-300 {
            return None;
        }
        let inv = 1.0 / det;
        let s = o - t.p[0];
        let u = s.dot(pv) * inv;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let q = s.cross(e1);
        let v = d.dot(q) * inv;
        if v < 0.0 || u + v > 1.0 {
            return None;
        }
        let dist = e2.dot(q) * inv;
        (dist > 0.0 && dist < t_max).then_some((dist, u, v))
    }

    /// The slab test of a node's box against the ray (inverse direction `inv`): the entry
    /// distance when the box is met before `t_max`.
    fn enter(n: &Node, o: DVec3, inv: DVec3, t_max: f64) -> Option<f64> {
        let (a, b) = ((n.lo - o) * inv, (n.hi - o) * inv);
        let (near, far) = (a.min(b).max_element().max(0.0), a.max(b).min_element().min(t_max));
        // NaN (0 · ∞ on a slab the ray lies in) compares false: the box is entered.
        (near.is_nan() || far.is_nan() || near <= far).then_some(near)
    }

    /// Walks the hierarchy; `hit` is called per triangle met and returns whether to stop.
    fn walk(&self, o: DVec3, d: DVec3, mut t_max: f64, mut hit: impl FnMut(usize, f64, f64, f64) -> bool) {
        if self.tris.is_empty() {
            return;
        }
        let inv = d.recip();
        let mut stack = vec![0usize];
        while let Some(k) = stack.pop() {
            let n = &self.nodes[k];
            if Self::enter(n, o, inv, t_max).is_none() {
                continue;
            }
            if n.count > 0 {
                for i in n.first as usize..(n.first + n.count) as usize {
                    if let Some((t, u, v)) = Self::intersect(&self.tris[i], o, d, t_max) {
                        if hit(i, t, u, v) {
                            return;
                        }
                        t_max = t;
                    }
                }
                continue;
            }
            // The nearer child last, so it is walked first.
            let (l, r) = (n.first as usize, n.first as usize + 1);
            let (el, er) = (
                Self::enter(&self.nodes[l], o, inv, t_max).unwrap_or(f64::INFINITY),
                Self::enter(&self.nodes[r], o, inv, t_max).unwrap_or(f64::INFINITY),
            );
            if el <= er {
                stack.extend([r, l]);
            } else {
                stack.extend([l, r]);
            }
        }
    }

    /// The nearest hit of the ray from camera-relative `o` along unit `d`, as the renderer's
    /// record (normal facing the ray, material packed as the voxels pack it).
    pub fn nearest(&self, o: DVec3, d: DVec3) -> Option<HitRecord> {
        let mut best: Option<(usize, f64, f64, f64)> = None;
        self.walk(o, d, f64::INFINITY, |i, t, u, v| {
            best = Some((i, t, u, v));
            false
        });
        let (i, t, u, v) = best?;
        let tri = &self.tris[i];
        let mut n = (tri.p[1] - tri.p[0]).cross(tri.p[2] - tri.p[0]).normalize_or_zero().as_vec3();
        if n.dot(d.as_vec3()) > 0.0 {
            n = -n;
        }
        let uv = tri.uv.map(|w| w[0] * (1.0 - u - v) as f32 + w[1] * u as f32 + w[2] * v as f32);
        // A triangle naming no material is grey (0.7) and matte, as the voxelizer makes it.
        let attr = match self.materials.get(tri.material as usize) {
            Some(m) => Attr::pack_glossy(m.albedo_at(uv), n, m.emission, m.specular, m.gloss()),
            None => Attr::pack(Vec3::splat(0.7), n, Vec3::ZERO),
        };
        Some(HitRecord { t: t as f32, instance: tri.instance, normal: n, face_normal: n, attr, voxel: self.offset })
    }

    /// Whether anything lies on the ray from `o` along unit `d` before `t_max`.
    pub fn occluded(&self, o: DVec3, d: DVec3, t_max: f64) -> bool {
        let mut any = false;
        self.walk(o, d, t_max, |_, _, _, _| {
            any = true;
            true
        });
        any
    }

    /// The nearest hit by testing every triangle (the hierarchy's oracle in the tests).
    #[cfg(test)]
    fn nearest_brute(&self, o: DVec3, d: DVec3) -> Option<(usize, f64)> {
        let mut best: Option<(usize, f64)> = None;
        for (i, t) in self.tris.iter().enumerate() {
            if let Some((dist, _, _)) = Self::intersect(t, o, d, best.map_or(f64::INFINITY, |b| b.1)) {
                best = Some((i, dist));
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{Part, Triangle};
    use crate::rng::Rng;

    /// The hierarchy finds what testing every triangle finds, nearest hit and shadow query,
    /// on a soup of random triangles.
    #[test]
    fn the_hierarchy_agrees_with_brute_force() {
        let mut rng = Rng::new(7);
        let mut r = || rng.f64() as f32;
        let triangles: Vec<Triangle> = (0..500)
            .map(|_| {
                let c = Vec3::new(r(), r(), r()) * 10.0;
                let mut q = || c + Vec3::new(r() - 0.5, r() - 0.5, r() - 0.5);
                Triangle { positions: [q(), q(), q()], uvs: None, material: 0 }
            })
            .collect();
        let mesh = Mesh {
            parts: vec![Part { name: "soup".into(), triangles }],
            materials: vec![Material::new("grey", Vec3::splat(0.5))],
            ..Default::default()
        };
        let mut scene = Scene::new(crate::pipeline::build_parts(&mesh, crate::voxelize::Resolution::Depth(3)).unwrap());
        scene.add(crate::scene::Instance { part: 0, parent: None, local: crate::scene::Transform::IDENTITY }).unwrap();
        scene.update().unwrap();
        let eye = DVec3::new(-3.0, 4.0, -5.0);
        let ts = TriangleScene::new(&mesh, &scene, eye).unwrap();
        assert_eq!(ts.len(), 500);
        let mut rng = Rng::new(9);
        let (mut hits, mut misses) = (0, 0);
        for _ in 0..2000 {
            let target = DVec3::new(rng.f64(), rng.f64(), rng.f64()) * 12.0 - DVec3::ONE - eye;
            let d = target.normalize();
            let got = ts.nearest(DVec3::ZERO, d).map(|h| h.t as f64);
            let want = ts.nearest_brute(DVec3::ZERO, d).map(|b| b.1);
            match (got, want) {
                (Some(a), Some(b)) => {
                    assert!((a - b).abs() <= 1e-5 * b, "{a} vs {b}");
                    assert!(ts.occluded(DVec3::ZERO, d, b * 1.001) && !ts.occluded(DVec3::ZERO, d, b * 0.999));
                    hits += 1;
                }
                (None, None) => {
                    assert!(!ts.occluded(DVec3::ZERO, d, f64::INFINITY));
                    misses += 1;
                }
                other => panic!("hierarchy {other:?}"),
            }
        }
        assert!(hits > 300 && misses > 100, "{hits} hits, {misses} misses");
    }
}
