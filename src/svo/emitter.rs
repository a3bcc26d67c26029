//! Emissive triangles kept with a part's octree: the surfaces that light the scene directly
//! ([`crate::render::emitters`] samples points on them). Their emitted radiance also sits in
//! the voxels' attributes ([`super::Attr::emission`]), which is what a ray that hits an
//! emitter sees; the triangles give the exact area and orientation that sampling needs.

use crate::mesh::{Material, Part};
use glam::Vec3;

/// Most emissive triangles one part may keep (48 bytes each: 48 MiB).
pub const MAX_EMITTERS: usize = 1 << 20;

/// One emissive triangle of a part, in the part's object coordinates. It emits from its
/// front face only: the side its vertices wind counter-clockwise around, as the OBJ gives
/// them (the light sources of most path tracers are one-sided too).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Emitter {
    /// Corners, counter-clockwise seen from the lit side.
    pub vertices: [Vec3; 3],
    /// Emitted radiance (MTL `Ke`, linear RGB).
    pub emission: Vec3,
}

impl Emitter {
    /// Area (object units²).
    pub fn area(&self) -> f32 {
        let [a, b, c] = self.vertices;
        (b - a).cross(c - a).length() * 0.5
    }
}

/// The emissive triangles of `part`: those whose material has a positive `Ke` and a
/// non-zero area. `Err(n)` when there are more than [`MAX_EMITTERS`] (n of them).
pub fn emitters_of(part: &Part, materials: &[Material]) -> Result<Vec<Emitter>, usize> {
    let emission = |m: u32| materials.get(m as usize).map_or(Vec3::ZERO, |m| m.emission);
    let lit = |e: Vec3| e.is_finite() && e.max_element() > 0.0;
    let out: Vec<Emitter> = part
        .triangles
        .iter()
        .filter(|t| lit(emission(t.material)))
        .map(|t| Emitter { vertices: t.positions, emission: emission(t.material) })
        .filter(|e| e.area() > 0.0 && e.vertices.iter().all(|v| v.is_finite()))
        .collect();
    if out.len() > MAX_EMITTERS {
        return Err(out.len());
    }
    Ok(out)
}
