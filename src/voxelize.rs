//! Triangle → voxel conversion: exact conservative triangle/box overlap (separating axis
//! test, Akenine-Möller 2001) over the part's bounding cube, found by descending an implicit
//! octree per triangle so only the surface is ever touched (sparse: depth 11 and deeper fit
//! in memory). Each voxel's albedo and normal are weighted by the exact area of the
//! triangle inside it (the triangle clipped to the voxel box). Optional solid fill.

use crate::mesh::{Material, Part};
use crate::svo::format::{morton_decode, morton_encode};
use crate::svo::{Cube, MAX_DEPTH};
use glam::{DVec2, DVec3, Vec3};

/// Deepest grid for which solid fill is offered: it floods a dense bit grid of 2^(3·depth)
/// cells (512³ = 16 MiB) and may create tens of millions of interior voxels.
pub const SOLID_MAX_DEPTH: u32 = 9;

/// Largest number of voxels one part may produce: building costs about 200 bytes per voxel
/// at peak (entries, levels, the node and attribute arrays), so this keeps a build under
/// ~12 GiB on a 24 GiB machine instead of letting the system kill it.
pub const MAX_VOXELS: u64 = 60_000_000;

/// How fine to voxelize.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Resolution {
    /// 2^depth voxels along the longest side of the part.
    Depth(u32),
    /// Voxels of this edge length (object units); the depth follows.
    VoxelSize(f32),
}

/// Voxelizer settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VoxelizeOptions {
    /// Grid resolution.
    pub resolution: Resolution,
    /// Fill the inside of closed surfaces too.
    pub solid: bool,
}

impl Default for VoxelizeOptions {
    fn default() -> Self {
        VoxelizeOptions { resolution: Resolution::Depth(9), solid: false }
    }
}

/// One occupied voxel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Voxel {
    /// Morton code of the voxel's integer coordinates (x in bit 0).
    pub code: u64,
    /// Area-weighted mean linear albedo.
    pub albedo: Vec3,
    /// Area-weighted mean normal (not necessarily unit length).
    pub normal: Vec3,
    /// Area-weighted mean emitted radiance (MTL `Ke`).
    pub emission: Vec3,
    /// Area-weighted mean specular reflectance ([`crate::mesh::Material::specular`]).
    pub specular: f32,
    /// Area-weighted mean glossiness ([`crate::mesh::Material::gloss`]).
    pub gloss: f32,
    /// Surface area inside the voxel, in voxel faces (area ÷ one face's area, so independent
    /// of the model's scale); tiny for voxels only touched.
    pub weight: f32,
}

/// A sparse voxel grid: the voxels of one part, sorted by Morton code.
#[derive(Clone, Debug, PartialEq)]
pub struct VoxelGrid {
    /// Levels: the grid is 2^depth per axis.
    pub depth: u32,
    /// The cube the grid covers.
    pub bounds: Cube,
    /// Occupied voxels, strictly increasing codes.
    pub voxels: Vec<Voxel>,
    /// The part's emissive triangles (object coordinates), kept for direct lighting.
    pub emitters: Vec<crate::svo::Emitter>,
}

impl VoxelGrid {
    /// A grid from integer coordinates (duplicates removed), with a uniform albedo and zero
    /// normals; used by tests and the stability suite.
    pub fn from_coords(depth: u32, bounds: Cube, coords: impl IntoIterator<Item = [u32; 3]>, albedo: Vec3) -> Self {
        let mut codes: Vec<u64> = coords.into_iter().map(|[x, y, z]| morton_encode(x, y, z)).collect();
        codes.sort_unstable();
        codes.dedup();
        let voxels = codes
            .into_iter()
            .map(|code| Voxel {
                code,
                albedo,
                normal: Vec3::ZERO,
                emission: Vec3::ZERO,
                specular: 0.0,
                gloss: 0.0,
                weight: 1.0,
            })
            .collect();
        VoxelGrid { depth, bounds, voxels, emitters: Vec::new() }
    }
    /// Integer coordinates of every voxel.
    pub fn coords(&self) -> impl Iterator<Item = [u32; 3]> + '_ {
        self.voxels.iter().map(|v| morton_decode(v.code))
    }
}

/// Why a part could not be voxelized.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum VoxelizeError {
    /// No triangle, or all degenerate.
    #[error("part '{0}' has no non-degenerate triangle")]
    EmptyPart(String),
    /// More emissive triangles than a part keeps for direct lighting.
    #[error(
        "part '{part}' has {count} emissive triangles; a part keeps at most {} (merge or simplify the emitters)",
        crate::svo::emitter::MAX_EMITTERS
    )]
    TooManyEmitters {
        /// The part.
        part: String,
        /// Its emissive triangles.
        count: usize,
    },
    /// Resolution out of range.
    #[error("invalid resolution: {0}")]
    Resolution(String),
    /// Solid fill asked for a grid finer than [`SOLID_MAX_DEPTH`].
    #[error("solid fill supports depth ≤ {SOLID_MAX_DEPTH}, asked for {0} (use a surface voxelization or a coarser voxel size)")]
    SolidTooDeep(u32),
    /// The part would produce more than [`MAX_VOXELS`] voxels.
    #[error("part '{part}' at depth {depth} would have about {estimate} million voxels (the limit is {} million); use a smaller depth or a larger voxel size", MAX_VOXELS / 1_000_000)]
    TooManyVoxels {
        /// Part name.
        part: String,
        /// Grid depth asked for.
        depth: u32,
        /// Estimated voxels, in millions.
        estimate: u64,
    },
    /// Counted exactly, the part's triangles overlap more than [`MAX_VOXELS`] voxels (the
    /// count stops at the limit).
    #[error("part '{part}' at depth {depth}: its triangles overlap more than {} million voxels, the limit (counted triangle by triangle); use a smaller depth or a larger voxel size", MAX_VOXELS / 1_000_000)]
    TooManyVoxelsCounted {
        /// Part name.
        part: String,
        /// Grid depth asked for.
        depth: u32,
    },
    /// Non-finite vertex coordinates.
    #[error("part '{0}' has non-finite vertex coordinates")]
    NonFinite(String),
    /// The memory budget refused the voxels.
    #[error(transparent)]
    Memory(#[from] crate::memory::MemoryError),
}

/// The cube and depth a part is voxelized into: the part's bounding box grown to a cube
/// about its centre (with a relative margin of 2⁻¹⁶ so no vertex sits on the cube's faces
/// after rounding).
pub fn bounding_cube(part: &Part, resolution: Resolution) -> Result<(Cube, u32), VoxelizeError> {
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for t in &part.triangles {
        for p in t.positions {
            if !p.is_finite() {
                return Err(VoxelizeError::NonFinite(part.name.clone()));
            }
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    if part.triangles.is_empty() {
        return Err(VoxelizeError::EmptyPart(part.name.clone()));
    }
    let extent = (hi - lo).max_element() as f64;
    if !(extent > 0.0) {
        return Err(VoxelizeError::EmptyPart(part.name.clone()));
    }
    let centre = (lo.as_dvec3() + hi.as_dvec3()) * 0.5;
    let padded = extent * (1.0 + 1.0 / 65536.0);
    let (size, depth) = match resolution {
        Resolution::Depth(d) => {
            if d == 0 || d > MAX_DEPTH {
                return Err(VoxelizeError::Resolution(format!("depth {d} outside 1..={MAX_DEPTH}")));
            }
            (padded, d)
        }
        Resolution::VoxelSize(v) => {
            if !(v.is_finite() && v > 0.0) {
                return Err(VoxelizeError::Resolution(format!("voxel size {v} must be finite and positive")));
            }
            let d = (padded / v as f64).log2().ceil().max(1.0);
            if d > MAX_DEPTH as f64 {
                return Err(VoxelizeError::Resolution(format!(
                    "voxel size {v} needs depth {d} for a part of extent {extent:.4}; the maximum is {MAX_DEPTH}"
                )));
            }
            (v as f64 * 2f64.powi(d as i32), d as u32)
        }
    };
    let min = centre - DVec3::splat(size * 0.5);
    Ok((Cube { min: min.as_vec3(), size: size as f32 }, depth))
}

/// Voxelizes one part. `progress(done, total)` is called now and then with triangle counts.
pub fn voxelize(
    part: &Part,
    materials: &[Material],
    opts: &VoxelizeOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<VoxelGrid, VoxelizeError> {
    let (bounds, depth) = bounding_cube(part, opts.resolution)?;
    voxelize_in(part, materials, bounds, depth, opts.solid, progress)
}

/// Voxelizes one part into a given cube at a given depth (a fixed grid shared with other
/// data, e.g. a world volume); triangles outside the cube contribute nothing. An empty
/// result is an [`VoxelizeError::EmptyPart`] error.
pub fn voxelize_in(
    part: &Part,
    materials: &[Material],
    bounds: Cube,
    depth: u32,
    solid: bool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<VoxelGrid, VoxelizeError> {
    if depth == 0 || depth > MAX_DEPTH {
        return Err(VoxelizeError::Resolution(format!("depth {depth} outside 1..={MAX_DEPTH}")));
    }
    if !(bounds.min.is_finite() && bounds.size.is_finite() && bounds.size > 0.0) {
        return Err(VoxelizeError::Resolution(format!("cube {bounds:?} must be finite with a positive size")));
    }
    if solid && depth > SOLID_MAX_DEPTH {
        return Err(VoxelizeError::SolidTooDeep(depth));
    }
    let total = part.triangles.len();
    let scale = (1u64 << depth) as f64 / bounds.size as f64;
    // A surface of area A covers about A / voxel² voxels, and a triangle at least as many as
    // its longest extent along an axis spans (a needle has no area but a line of voxels);
    // refuse before allocating.
    let covered: f64 = part
        .triangles
        .iter()
        .map(|t| {
            let p = t.positions.map(|v| v.as_dvec3());
            let area = (p[1] - p[0]).cross(p[2] - p[0]).length() * 0.5;
            let extent = p[0].max(p[1]).max(p[2]) - p[0].min(p[1]).min(p[2]);
            (area * scale * scale).max(extent.max_element() * scale)
        })
        .sum();
    let estimate = covered + total as f64;
    if estimate > MAX_VOXELS as f64 {
        return Err(VoxelizeError::TooManyVoxels {
            part: part.name.clone(),
            depth,
            estimate: (estimate / 1e6).round() as u64,
        });
    }
    // The memory budget may allow fewer voxels than the fixed limit.
    let per_voxel = crate::memory::VOXELIZE_BYTES_PER_VOXEL;
    let limit = MAX_VOXELS.min(crate::memory::budget() / per_voxel);
    let what = |voxels: f64| {
        format!("voxelizing part '{}' at depth {depth} (about {:.1} million voxels)", part.name, voxels / 1e6)
    };
    const ADVICE: &str = "use a smaller depth or a larger voxel size, or raise the memory budget";
    crate::memory::check(&what(estimate), estimate as u64 * per_voxel, ADVICE)?;
    let origin = bounds.min.as_dvec3();
    let ctx = Ctx { depth, scale, origin, materials };
    // The area misses what a surface really touches: oblique surfaces cross up to √3 times
    // as many voxels, surfaces on voxel boundaries touch both sides, needles cover voxels
    // along their length with no area. Near the limit, count exactly (no memory) first.
    if estimate > (limit / 4) as f64 {
        let counted = count_entries(&ctx, &part.triangles, MAX_VOXELS);
        if counted > MAX_VOXELS {
            return Err(VoxelizeError::TooManyVoxelsCounted { part: part.name.clone(), depth });
        }
        crate::memory::check(&what(counted as f64), counted * per_voxel, ADVICE)?;
    }

    const CHUNK: usize = 2048;
    let done = std::sync::atomic::AtomicUsize::new(0);
    let run_chunk = |chunk: &[crate::mesh::Triangle]| {
        let mut out = Vec::new();
        for tri in chunk {
            ctx.rasterize(tri, &mut out);
        }
        let d = done.fetch_add(chunk.len(), std::sync::atomic::Ordering::Relaxed) + chunk.len();
        progress(d, total);
        out
    };
    #[cfg(feature = "parallel")]
    let mut entries: Vec<Entry> = {
        use rayon::prelude::*;
        part.triangles.par_chunks(CHUNK).flat_map_iter(run_chunk).collect()
    };
    #[cfg(not(feature = "parallel"))]
    let mut entries: Vec<Entry> = part.triangles.chunks(CHUNK).flat_map(run_chunk).collect();

    // Stable sort keeps the triangle order within a voxel, so results are deterministic.
    #[cfg(feature = "parallel")]
    {
        use rayon::slice::ParallelSliceMut;
        entries.par_sort_by_key(|e| e.code);
    }
    #[cfg(not(feature = "parallel"))]
    entries.sort_by_key(|e| e.code);

    let mut voxels: Vec<Voxel> = Vec::new();
    let mut acc: Option<Entry> = None;
    for e in entries {
        match acc.as_mut() {
            Some(a) if a.code == e.code => {
                a.weight += e.weight;
                a.albedo_w += e.albedo_w;
                a.emission_w += e.emission_w;
                a.specular_w += e.specular_w;
                a.gloss_w += e.gloss_w;
                // Align orientations so the two faces of a thin wall do not cancel.
                a.normal_w += if a.normal_w.dot(e.normal_w) < 0.0 { -e.normal_w } else { e.normal_w };
            }
            _ => {
                if let Some(a) = acc.take() {
                    voxels.push(a.finish());
                }
                acc = Some(e);
            }
        }
    }
    if let Some(a) = acc {
        voxels.push(a.finish());
    }
    if voxels.is_empty() {
        return Err(VoxelizeError::EmptyPart(part.name.clone()));
    }
    if solid {
        fill_solid(depth, &mut voxels, limit).map_err(|filled| {
            // Within the fixed limit, it is the budget that refused.
            match crate::memory::check(&what(filled as f64), filled * per_voxel, ADVICE) {
                Err(e) if filled <= MAX_VOXELS => e.into(),
                _ => VoxelizeError::TooManyVoxels {
                    part: part.name.clone(),
                    depth,
                    estimate: filled.div_ceil(1_000_000),
                },
            }
        })?;
    }
    let emitters = crate::svo::emitter::emitters_of(part, materials)
        .map_err(|count| VoxelizeError::TooManyEmitters { part: part.name.clone(), count })?;
    Ok(VoxelGrid { depth, bounds, voxels, emitters })
}

/// Voxels the triangles overlap, each counted once per triangle (the entries voxelizing
/// them writes), counting stopped soon after `limit`.
fn count_entries(ctx: &Ctx, triangles: &[crate::mesh::Triangle], limit: u64) -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    let total = AtomicU64::new(0);
    let run = |chunk: &[crate::mesh::Triangle]| {
        for tri in chunk {
            let so_far = total.load(Ordering::Relaxed);
            if so_far > limit {
                return;
            }
            total.fetch_add(ctx.count(tri, limit - so_far), Ordering::Relaxed);
        }
    };
    #[cfg(feature = "parallel")]
    {
        use rayon::prelude::*;
        triangles.par_chunks(256).for_each(run);
    }
    #[cfg(not(feature = "parallel"))]
    triangles.chunks(256).for_each(run);
    total.into_inner()
}

/// One triangle's contribution to one voxel (48 bytes: there are tens of millions of these
/// in a deep build).
#[derive(Clone, Copy)]
struct Entry {
    code: u64,
    weight: f32,
    albedo_w: Vec3,
    normal_w: Vec3,
    emission_w: Vec3,
    specular_w: f32,
    gloss_w: f32,
}

impl Entry {
    fn finish(self) -> Voxel {
        let w = self.weight.max(f32::MIN_POSITIVE);
        Voxel {
            code: self.code,
            albedo: self.albedo_w / w,
            normal: self.normal_w / w,
            emission: self.emission_w / w,
            specular: self.specular_w / w,
            gloss: self.gloss_w / w,
            weight: self.weight,
        }
    }
}

struct Ctx<'a> {
    depth: u32,
    scale: f64,
    origin: DVec3,
    materials: &'a [Material],
}

impl Ctx<'_> {
    /// Emits an entry for every voxel the triangle overlaps, descending from the root and
    /// testing each node box so only the triangle's own voxels are visited.
    fn rasterize(&self, tri: &crate::mesh::Triangle, out: &mut Vec<Entry>) {
        let v = tri.positions.map(|p| (p.as_dvec3() - self.origin) * self.scale);
        let n = (v[1] - v[0]).cross(v[2] - v[0]);
        if !(n.length_squared() > 0.0) {
            return;
        }
        let normal = n.normalize();
        let mat = self.materials.get(tri.material as usize);
        self.overlapped(&v, |c, bmin, bmax| {
            let (area, centroid) = clip_area(&v, bmin, bmax);
            // The weight is the clipped area in voxel faces (the grid's unit), so it does not
            // depend on the model's scale: in object units² a model of 10⁻⁸ units weighs
            // ~10⁻²² and one of 10³⁸ overflows f32, and both lost their normals. Only touching
            // (zero clipped area): keep the voxel, with a tiny weight.
            let area_w = area.max(1e-9);
            let albedo = mat.map_or(DVec3::splat(0.7), |m| {
                let uv = tri.uvs.map(|uv| {
                    let b = barycentric(&v, if area > 0.0 { centroid } else { (bmin + bmax) * 0.5 });
                    uv[0].as_dvec2() * b.x + uv[1].as_dvec2() * b.y + uv[2].as_dvec2() * b.z
                });
                m.albedo_at(uv.map(|p: DVec2| p.as_vec2())).as_dvec3()
            });
            let w = area_w as f32;
            out.push(Entry {
                code: morton_encode(c[0] as u32, c[1] as u32, c[2] as u32),
                weight: w,
                albedo_w: albedo.as_vec3() * w,
                normal_w: normal.as_vec3() * w,
                emission_w: mat.map_or(Vec3::ZERO, |m| m.emission) * w,
                specular_w: mat.map_or(0.0, |m| m.specular) * w,
                gloss_w: mat.map_or(0.0, |m| m.gloss()) * w,
            });
            true
        });
    }

    /// How many voxels the triangle overlaps, counting stopped once past `limit`.
    fn count(&self, tri: &crate::mesh::Triangle, limit: u64) -> u64 {
        let v = tri.positions.map(|p| (p.as_dvec3() - self.origin) * self.scale);
        if !((v[1] - v[0]).cross(v[2] - v[0]).length_squared() > 0.0) {
            return 0;
        }
        let mut n = 0u64;
        self.overlapped(&v, |_, _, _| {
            n += 1;
            n <= limit
        });
        n
    }

    /// Calls `leaf(coords, min, max)` for every voxel the grid-space triangle `v` overlaps,
    /// descending from the root and testing each node box so only the triangle's own voxels
    /// are visited; stops when `leaf` returns false.
    fn overlapped(&self, v: &[DVec3; 3], mut leaf: impl FnMut([u64; 3], DVec3, DVec3) -> bool) {
        let n_cells = 1u64 << self.depth;
        let lo = v[0].min(v[1]).min(v[2]);
        let hi = v[0].max(v[1]).max(v[2]);
        // (level, x, y, z) of nodes still to test.
        let mut stack: Vec<(u32, [u64; 3])> = vec![(0, [0, 0, 0])];
        while let Some((level, c)) = stack.pop() {
            let size = (n_cells >> level) as f64;
            let bmin = DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * size;
            let bmax = bmin + DVec3::splat(size);
            if bmax.cmplt(lo).any() || bmin.cmpgt(hi).any() {
                continue;
            }
            let half = DVec3::splat(size * 0.5);
            if !tri_box_overlap(bmin + half, half, v) {
                continue;
            }
            if level == self.depth {
                if !leaf(c, bmin, bmax) {
                    return;
                }
                continue;
            }
            for oct in 0..8u64 {
                stack.push((level + 1, [2 * c[0] + (oct & 1), 2 * c[1] + ((oct >> 1) & 1), 2 * c[2] + (oct >> 2)]));
            }
        }
    }
}

/// Exact triangle/box overlap by the separating axis theorem (Akenine-Möller 2001): the
/// three box normals, the triangle normal and the nine edge cross products. Boxes are
/// closed: a triangle touching a face, edge or corner overlaps.
pub fn tri_box_overlap(centre: DVec3, half: DVec3, tri: &[DVec3; 3]) -> bool {
    let v = [tri[0] - centre, tri[1] - centre, tri[2] - centre];
    let e = [v[1] - v[0], v[2] - v[1], v[0] - v[2]];
    for axis_i in 0..3 {
        let mut a = DVec3::ZERO;
        a[axis_i] = 1.0;
        for edge in &e {
            let axis = a.cross(*edge);
            if separated(axis, &v, half) {
                return false;
            }
        }
    }
    for i in 0..3 {
        let (mn, mx) = (v[0][i].min(v[1][i]).min(v[2][i]), v[0][i].max(v[1][i]).max(v[2][i]));
        if mn > half[i] || mx < -half[i] {
            return false;
        }
    }
    let n = e[0].cross(e[1]);
    !separated(n, &v, half)
}

fn separated(axis: DVec3, v: &[DVec3; 3], half: DVec3) -> bool {
    let p = [axis.dot(v[0]), axis.dot(v[1]), axis.dot(v[2])];
    let r = half.x * axis.x.abs() + half.y * axis.y.abs() + half.z * axis.z.abs();
    let (mn, mx) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
    mn > r || mx < -r
}

/// Area and centroid of the part of a triangle inside a box (Sutherland–Hodgman clipping).
pub fn clip_area(tri: &[DVec3; 3], bmin: DVec3, bmax: DVec3) -> (f64, DVec3) {
    let mut poly: Vec<DVec3> = tri.to_vec();
    let mut next = Vec::with_capacity(9);
    for axis in 0..3 {
        for (bound, keep_above) in [(bmin[axis], true), (bmax[axis], false)] {
            next.clear();
            let inside = |p: &DVec3| {
                if keep_above {
                    p[axis] >= bound
                } else {
                    p[axis] <= bound
                }
            };
            for i in 0..poly.len() {
                let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
                let (ia, ib) = (inside(&a), inside(&b));
                if ia {
                    next.push(a);
                }
                if ia != ib {
                    let t = (bound - a[axis]) / (b[axis] - a[axis]);
                    let mut p = a + (b - a) * t;
                    p[axis] = bound;
                    next.push(p);
                }
            }
            std::mem::swap(&mut poly, &mut next);
            if poly.len() < 3 {
                return (0.0, DVec3::ZERO);
            }
        }
    }
    let (mut area, mut centroid) = (0.0, DVec3::ZERO);
    for i in 1..poly.len() - 1 {
        let a = (poly[i] - poly[0]).cross(poly[i + 1] - poly[0]).length() * 0.5;
        area += a;
        centroid += (poly[0] + poly[i] + poly[i + 1]) * (a / 3.0);
    }
    if area > 0.0 {
        (area, centroid / area)
    } else {
        (0.0, DVec3::ZERO)
    }
}

/// Barycentric coordinates of `p` (projected onto the triangle's plane), clamped inside.
fn barycentric(v: &[DVec3; 3], p: DVec3) -> DVec3 {
    let (e0, e1, ep) = (v[1] - v[0], v[2] - v[0], p - v[0]);
    let (d00, d01, d11) = (e0.dot(e0), e0.dot(e1), e1.dot(e1));
    let (d20, d21) = (ep.dot(e0), ep.dot(e1));
    let den = d00 * d11 - d01 * d01;
    if !(den.abs() > 0.0) {
        return DVec3::new(1.0, 0.0, 0.0);
    }
    let b1 = ((d11 * d20 - d01 * d21) / den).clamp(0.0, 1.0);
    let b2 = ((d00 * d21 - d01 * d20) / den).clamp(0.0, 1.0 - b1);
    DVec3::new(1.0 - b1 - b2, b1, b2)
}

/// Fills the inside of closed surfaces: floods the outside from the grid boundary (6-connected)
/// and adds every cell that is neither outside nor surface. Interior voxels take the attributes
/// of the surface voxel below them in their z column, with a tiny weight so coarse levels keep
/// the surface colour.
fn fill_solid(depth: u32, voxels: &mut Vec<Voxel>, limit: u64) -> Result<(), u64> {
    let n = 1usize << depth;
    let idx = |x: usize, y: usize, z: usize| (z * n + y) * n + x;
    let mut surface = vec![false; n * n * n];
    for v in voxels.iter() {
        let [x, y, z] = morton_decode(v.code);
        surface[idx(x as usize, y as usize, z as usize)] = true;
    }
    let mut outside = vec![false; n * n * n];
    let mut stack: Vec<u32> = Vec::new();
    let seed = |x: usize, y: usize, z: usize, outside: &mut Vec<bool>, stack: &mut Vec<u32>| {
        let i = idx(x, y, z);
        if !surface[i] && !outside[i] {
            outside[i] = true;
            stack.push(i as u32);
        }
    };
    for a in 0..n {
        for b in 0..n {
            for (x, y, z) in [(0, a, b), (n - 1, a, b), (a, 0, b), (a, n - 1, b), (a, b, 0), (a, b, n - 1)] {
                seed(x, y, z, &mut outside, &mut stack);
            }
        }
    }
    while let Some(i) = stack.pop() {
        let i = i as usize;
        let (x, y, z) = (i % n, (i / n) % n, i / (n * n));
        if x > 0 {
            seed(x - 1, y, z, &mut outside, &mut stack)
        }
        if x + 1 < n {
            seed(x + 1, y, z, &mut outside, &mut stack)
        }
        if y > 0 {
            seed(x, y - 1, z, &mut outside, &mut stack)
        }
        if y + 1 < n {
            seed(x, y + 1, z, &mut outside, &mut stack)
        }
        if z > 0 {
            seed(x, y, z - 1, &mut outside, &mut stack)
        }
        if z + 1 < n {
            seed(x, y, z + 1, &mut outside, &mut stack)
        }
    }
    // Refuse before writing the interior: a closed cube at depth 9 is 134 million voxels.
    let inside = surface.iter().zip(&outside).filter(|(s, o)| !**s && !**o).count() as u64;
    let filled = voxels.len() as u64 + inside;
    if filled > limit {
        return Err(filled);
    }
    let lookup = |code: u64, voxels: &[Voxel]| voxels.binary_search_by_key(&code, |v| v.code).ok().map(|i| voxels[i]);
    let mut interior = Vec::new();
    for y in 0..n {
        for x in 0..n {
            let mut last: Option<Voxel> = None;
            for z in 0..n {
                let i = idx(x, y, z);
                let code = morton_encode(x as u32, y as u32, z as u32);
                if surface[i] {
                    last = lookup(code, voxels);
                } else if !outside[i] {
                    if let Some(s) = last {
                        interior.push(Voxel { code, weight: s.weight * 1e-6, ..s });
                    }
                }
            }
        }
    }
    voxels.extend(interior);
    voxels.sort_by_key(|v| v.code);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The exact count is what voxelizing writes, and it sees what the area misses: three
    /// axis planes through the cube's centre lie on voxel boundaries and touch both sides
    /// (twice the area estimate), a needle covers voxels along its length with no area.
    #[test]
    fn the_entry_count_is_exact_where_the_area_estimate_is_not() {
        use crate::mesh::Triangle;
        let tri = |a: [f32; 3], b: [f32; 3], c: [f32; 3]| Triangle {
            positions: [Vec3::from(a), Vec3::from(b), Vec3::from(c)],
            uvs: None,
            material: 0,
        };
        let mut planes = Vec::new();
        for axis in 0..3 {
            let p = |u: f32, v: f32| {
                let mut q = [0.0f32; 3];
                q[(axis + 1) % 3] = u;
                q[(axis + 2) % 3] = v;
                q
            };
            planes.push(tri(p(-1.0, -1.0), p(1.0, -1.0), p(1.0, 1.0)));
            planes.push(tri(p(-1.0, -1.0), p(1.0, 1.0), p(-1.0, 1.0)));
        }
        let needle = vec![tri([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [1.0, 1.0 + 1e-6, 1.0])];
        let bounds = Cube { min: Vec3::splat(-1.0), size: 2.0 };
        let depth = 6;
        let scale = (1u64 << depth) as f64 / 2.0;
        let ctx = Ctx { depth, scale, origin: bounds.min.as_dvec3(), materials: &[] };
        for (name, tris, area) in [("planes", &planes, 12.0), ("needle", &needle, 0.0)] {
            let mut entries = Vec::new();
            for t in tris.iter() {
                ctx.rasterize(t, &mut entries);
            }
            let counted = count_entries(&ctx, tris, u64::MAX);
            assert_eq!(counted, entries.len() as u64, "{name}");
            let estimate = area * scale * scale;
            assert!(counted as f64 > 1.9 * estimate && counted > 60, "{name}: {counted} against {estimate}");
        }
        // Counting stops soon past the limit.
        assert!(count_entries(&ctx, &planes, 100) < 200);
    }

    #[test]
    fn clip_area_of_a_triangle_inside_is_its_area() {
        let t = [DVec3::new(0.1, 0.1, 0.5), DVec3::new(0.9, 0.1, 0.5), DVec3::new(0.1, 0.9, 0.5)];
        let (a, c) = clip_area(&t, DVec3::ZERO, DVec3::ONE);
        assert!((a - 0.32).abs() < 1e-12);
        assert!((c - (t[0] + t[1] + t[2]) / 3.0).length() < 1e-12);
        // Half of a right triangle cut by x = 0.5.
        let t = [DVec3::new(0.0, 0.0, 0.5), DVec3::new(1.0, 0.0, 0.5), DVec3::new(0.0, 1.0, 0.5)];
        let (a, _) = clip_area(&t, DVec3::ZERO, DVec3::new(0.5, 1.0, 1.0));
        assert!((a - 0.375).abs() < 1e-12, "{a}");
    }

    #[test]
    fn sat_touching_counts_and_separated_does_not() {
        let t = [DVec3::new(1.0, 0.0, 0.0), DVec3::new(1.0, 1.0, 0.0), DVec3::new(1.0, 0.0, 1.0)];
        assert!(tri_box_overlap(DVec3::splat(0.5), DVec3::splat(0.5), &t));
        let t2 = t.map(|p| p + DVec3::X * 1e-9);
        assert!(!tri_box_overlap(DVec3::splat(0.5), DVec3::splat(0.5), &t2));
        // A triangle whose AABB overlaps the box but which passes beside it (edge-axis case).
        let t3 = [DVec3::new(1.4, -0.5, 0.5), DVec3::new(-0.5, 1.4, 0.5), DVec3::new(2.0, 2.0, 0.5)];
        assert!(!tri_box_overlap(DVec3::splat(0.2), DVec3::splat(0.2), &t3));
    }
}
