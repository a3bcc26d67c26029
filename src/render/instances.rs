//! Per-frame instance data, all relative to the camera: the map from camera-relative world
//! space into each instance's SVO unit cube (the inverse transform, never renormalized, so t
//! is the same everywhere), the inverse transpose for normals, and the bounding sphere.
//!
//! Everything is formed in f64 from f64 world transforms and the f64 eye, so large world
//! coordinates cancel before any rounding to f32 (a car 10⁶ units away renders like one at the
//! origin).

use crate::scene::Scene;
use glam::{DAffine3, DMat3, DVec3};

/// Sphere radii are padded by this fraction of themselves and of the part cube's sphere, so
/// that hits computed in f32 never fall outside the sphere computed in f64 (culling,
/// early-out and the hit buffer rely on it).
pub const SPHERE_PAD: f64 = 1e-6;

/// How rays reach an instance's unit cube.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ToUnit {
    /// Identity world transform: only the cube's offset and scale (no ray transformation).
    Scale {
        /// Unit-cube position of the camera-relative origin.
        offset: DVec3,
        /// 1 / cube size.
        inv_size: f64,
    },
    /// General affine map (inverse world transform, then the cube mapping).
    Affine(DAffine3),
}

impl ToUnit {
    /// Maps a camera-relative point.
    #[inline]
    pub fn point(&self, p: DVec3) -> DVec3 {
        match self {
            ToUnit::Scale { offset, inv_size } => *offset + p * *inv_size,
            ToUnit::Affine(m) => m.transform_point3(p),
        }
    }
    /// Maps a direction (not renormalized).
    #[inline]
    pub fn vector(&self, d: DVec3) -> DVec3 {
        match self {
            ToUnit::Scale { inv_size, .. } => d * *inv_size,
            ToUnit::Affine(m) => m.transform_vector3(d),
        }
    }
}

/// One instance, ready for this frame's rays.
// In declaration order: what a ray's trace reads first (part, ray map) leads, so that
// prefetching it asks for the fewest cache lines.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct Prepared {
    /// The part it places.
    pub part: usize,
    /// Camera-relative world → SVO unit cube.
    pub to_unit: ToUnit,
    /// Bounding-sphere centre, camera-relative.
    pub centre: DVec3,
    /// Bounding-sphere radius of the occupied cells (padded by [`SPHERE_PAD`]).
    pub radius: f64,
    /// Largest stretch of the world transform (object → world length factor).
    pub max_stretch: f64,
}

impl Prepared {
    /// A slot before it is filled ([`fill_slot`] overwrites every field).
    pub(crate) const BLANK: Prepared = Prepared {
        part: 0,
        to_unit: ToUnit::Affine(DAffine3::IDENTITY),
        centre: DVec3::ZERO,
        radius: 0.0,
        max_stretch: 0.0,
    };

    /// A world vector along the normal of object-space normal `n` (not of unit length: the
    /// callers normalize). Normals map by the inverse transpose of the world transform's
    /// linear part; the ray map's linear part is that inverse times 1/size > 0, so its
    /// transpose gives the same direction without keeping another matrix per instance.
    #[inline]
    pub fn normal_to_world(&self, n: DVec3) -> DVec3 {
        match self.to_unit {
            ToUnit::Scale { .. } => n,
            ToUnit::Affine(m) => m.matrix3.transpose() * n,
        }
    }
}

/// Prepares every instance for a camera at `eye`, for rays traced down to the voxels.
/// `transform == false` (a frame plan that found only identity transforms) maps rays with the
/// cube offset and scale alone.
pub fn prepare(scene: &Scene, eye: DVec3, transform: bool) -> Vec<Prepared> {
    let mut out = Vec::new();
    prepare_into(scene, eye, transform, u32::MAX, &mut out);
    out
}

/// [`prepare`] for rays traced down to `max_level` (their level of detail: the spheres hold
/// what such rays can hit), into `out` (cleared first), keeping its memory: a renderer that
/// prepares tens of thousands of instances every frame reuses last frame's vector instead of
/// faulting in fresh pages.
pub fn prepare_into(scene: &Scene, eye: DVec3, transform: bool, max_level: u32, out: &mut Vec<Prepared>) {
    refill(scene, eye, transform, max_level, out, None, None);
}

/// What a list of prepared instances was made from: the scene (its number and update), the
/// eye, the ray map's kind, the level and the parts. [`prepare_changed`] refills from it only
/// the instances whose world transform or part changed since.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PreparedFor {
    scene: u64,
    epoch: u64,
    eye: [u64; 3],
    transform: bool,
    max_level: u32,
    parts: Vec<usize>,
    instances: usize,
}

impl PreparedFor {
    fn of(scene: &Scene, eye: DVec3, transform: bool, max_level: u32) -> PreparedFor {
        PreparedFor {
            scene: scene.id(),
            epoch: scene.epoch(),
            eye: eye.to_array().map(f64::to_bits),
            transform,
            max_level,
            // Parts are compared by address: the list is public and may be edited.
            parts: scene.parts.iter().map(|p| std::sync::Arc::as_ptr(p) as usize).collect(),
            instances: scene.instances().len(),
        }
    }
}

/// [`prepare_into`] for a list `out` that was prepared as `made` says: when only the scene's
/// updates differ (same scene, eye, ray map, level, parts and instances), refills only the
/// instances those updates changed (a still camera over a crowd whose cars are posed only
/// when seen); else all of them. `made` then describes `out`. `spheres` is kept as `out`'s
/// (centre, radius) pairs, in instance order, and refilled alongside: a crowd's frame reads
/// them without going through every prepared instance. Returns the instances refilled, in
/// ascending order, when only those were (the others are as they were); None when every
/// instance was.
pub fn prepare_changed(
    scene: &Scene,
    eye: DVec3,
    transform: bool,
    max_level: u32,
    out: &mut Vec<Prepared>,
    spheres: &mut Vec<(DVec3, f64)>,
    made: &mut PreparedFor,
) -> Option<Vec<u32>> {
    let now = PreparedFor::of(scene, eye, transform, max_level);
    let since = PreparedFor { epoch: made.epoch, ..now.clone() };
    let same =
        *made == since && out.len() == now.instances && spheres.len() == now.instances && scene.epoch() >= made.epoch;
    let refilled = refill(scene, eye, transform, max_level, out, Some(spheres), same.then_some(made.epoch));
    *made = now;
    refilled
}

/// Fills `out` (and `spheres`, when given) for every instance, or (with `since`) only for
/// those whose stamp is later; returns those (ascending) when `since` was given.
fn refill(
    scene: &Scene,
    eye: DVec3,
    transform: bool,
    max_level: u32,
    out: &mut Vec<Prepared>,
    spheres: Option<&mut Vec<(DVec3, f64)>>,
    since: Option<u64>,
) -> Option<Vec<u32>> {
    let boxes = part_boxes(scene, max_level);
    let fill = |i: usize, slot: &mut Prepared, sphere: Option<&mut (DVec3, f64)>| {
        fill_slot(scene, eye, transform, &boxes, i, slot);
        if let Some(sphere) = sphere {
            *sphere = (slot.centre, slot.radius);
        }
    };
    let n = scene.instances().len();
    // Last frame's slots, refilled in place.
    out.resize(n, Prepared::BLANK);
    // Without spheres to keep, an empty slice: each slot's sphere is then None.
    let spheres = match spheres {
        Some(s) => {
            s.resize(n, (DVec3::ZERO, 0.0));
            &mut s[..]
        }
        None => &mut [][..],
    };
    if let Some(since) = since {
        // The changed instances only: when one update has passed, the scene's own list of
        // them; else those whose stamp is later (a scan; counted in u32 by the renderer's
        // records).
        let changed: Vec<u32> = if since.checked_add(1) == Some(scene.epoch()) {
            scene.changed_by_last_update().to_vec()
        } else {
            (0..n).filter(|&i| scene.stamp(i) > since).map(|i| i as u32).collect()
        };
        refill_listed(&changed, scene, out, spheres, &fill);
        return Some(changed);
    }
    // Every slot in order: the hardware's prefetcher follows. Thousands of instances (a crowd
    // of cars) in parallel chunks: every one is independent.
    let fill_run = |first: usize, slots: &mut [Prepared], spheres: &mut [(DVec3, f64)]| {
        for (k, slot) in slots.iter_mut().enumerate() {
            fill(first + k, slot, spheres.get_mut(k));
        }
    };
    #[cfg(feature = "parallel")]
    if n >= 1024 {
        use rayon::prelude::*;
        const CHUNK: usize = 512;
        if spheres.is_empty() {
            out.par_chunks_mut(CHUNK).enumerate().for_each(|(c, slots)| fill_run(c * CHUNK, slots, &mut []));
        } else {
            out.par_chunks_mut(CHUNK)
                .zip(spheres.par_chunks_mut(CHUNK))
                .enumerate()
                .for_each(|(c, (slots, spheres))| fill_run(c * CHUNK, slots, spheres));
        }
        return None;
    }
    fill_run(0, out, spheres);
    None
}

/// Fills instance `i`'s slot for a camera at `eye` ([`prepare_into`]'s work for one
/// instance), field by field: built whole and assigned, each 152-byte instance went through a
/// memcpy (3.5 % of a 10 000-car frame). `boxes`: [`part_boxes`] at the frame's level.
#[inline]
pub(crate) fn fill_slot(scene: &Scene, eye: DVec3, transform: bool, boxes: &[PartBox], i: usize, slot: &mut Prepared) {
    let inst = &scene.instances()[i];
    let cube = scene.parts[inst.part].bounds;
    let (min, size) = (cube.min.as_dvec3(), cube.size as f64);
    let w = scene.world(i);
    // One inverse serves the ray map and the normals (the inverse transpose of the
    // linear part is the transpose of the inverse's).
    let inverse = w.inverse();
    let to_unit = if transform {
        // (scale 1/size) · (translate −min) · inverse · (translate eye), multiplied out.
        let k = 1.0 / size;
        let m = inverse.matrix3;
        ToUnit::Affine(DAffine3 { matrix3: m * k, translation: (m * eye + inverse.translation - min) * k })
    } else {
        ToUnit::Scale { offset: (eye - min) / size, inv_size: 1.0 / size }
    };
    // The sphere holds the occupied cells at the traced level, not the whole cube (a
    // car's body fills a third of its cube's height): about the transformed centre of
    // their box, through its farthest corner or its farthest cell.
    let (c0, c1, c2) = (w.matrix3.x_axis, w.matrix3.y_axis, w.matrix3.z_axis);
    let PartBox { centre: centre_obj, half: e, reach } = boxes[inst.part];
    let max_stretch = c0.length_squared().max(c1.length_squared()).max(c2.length_squared()).sqrt();
    // The box's farthest corner, or the farthest cell's reach stretched as far as the
    // transform stretches anything (both hold every cell; a turned wheel's box corners lie
    // far outside the wheel). Rounding in f32 traversal scales with the cube, not with the
    // box: the padding is also a fraction of a bound on the cube's sphere
    // (|M·(±h, ±h, h)| ≤ 3h·max stretch).
    let held = farthest_corner(&w.matrix3, e).min(reach * stretch_bound(&w.matrix3) * (1.0 + 1e-12));
    let radius = held * (1.0 + SPHERE_PAD) + 1.5 * size * max_stretch * SPHERE_PAD;
    slot.part = inst.part;
    slot.to_unit = to_unit;
    slot.centre = w.transform_point3(centre_obj) - eye;
    slot.radius = radius + f64::MIN_POSITIVE;
    slot.max_stretch = max_stretch;
}

/// Fills the slots (and spheres, when there are any) of the instances `ids` (ascending) with
/// `fill` (which reads each one's world transform and record in `scene`), each while the
/// memory of one a few places on is asked for (a crowd's moved cars lie scattered over
/// megabytes of slots); in parallel chunks of ids, each owning the stretch of slots up to its
/// last one.
fn refill_listed<F: Fn(usize, &mut Prepared, Option<&mut (DVec3, f64)>) + Sync>(
    ids: &[u32],
    scene: &Scene,
    out: &mut [Prepared],
    spheres: &mut [(DVec3, f64)],
    fill: &F,
) {
    const AHEAD: usize = 4;
    let (worlds, instances) = (scene.worlds(), scene.instances());
    let run = |ids: &[u32], first: usize, slots: &mut [Prepared], spheres: &mut [(DVec3, f64)]| {
        for (j, &i) in ids.iter().enumerate() {
            if let Some(&next) = ids.get(j + AHEAD) {
                if let Some(world) = worlds.get(next as usize) {
                    crate::prefetch::prefetch_bytes(world, std::mem::size_of::<DAffine3>());
                }
                // The part index is the fill's first read (a quarter of its time stalled there).
                if let Some(inst) = instances.get(next as usize) {
                    crate::prefetch::prefetch(&inst.part);
                }
                if let Some(slot) = slots.get(next as usize - first) {
                    crate::prefetch::prefetch_bytes(slot, std::mem::size_of::<Prepared>());
                }
                if let Some(sphere) = spheres.get(next as usize - first) {
                    crate::prefetch::prefetch(sphere);
                }
            }
            let k = i as usize - first;
            if let Some(slot) = slots.get_mut(k) {
                fill(i as usize, slot, spheres.get_mut(k));
            }
        }
    };
    #[cfg(feature = "parallel")]
    if ids.len() >= 1024 {
        const CHUNK: usize = 512;
        // (The spheres are as many as the slots, or none: their stretches start where the
        // slots' do, or are all empty.)
        let pieces: Vec<_> = stretches(ids, CHUNK, out).into_iter().zip(stretches(ids, CHUNK, spheres)).collect();
        crate::pool::map_owned(pieces, |((chunk, first, a), (_, _, c))| run(chunk, first, a, c));
        return;
    }
    run(ids, 0, out, spheres);
}

/// `items` (one per instance) split among the chunks of `ids` (ascending instances, `chunk`
/// at a time) so that each owns the stretch from the end of the one before up to its own
/// last instance (clamped to `items`): each chunk with its first slot's instance and its
/// stretch. Parallel chunks can then write their instances' items.
pub(super) fn stretches<'a, T>(
    ids: &'a [u32],
    chunk: usize,
    items: &'a mut [T],
) -> Vec<(&'a [u32], usize, &'a mut [T])> {
    let mut pieces = Vec::with_capacity(ids.len().div_ceil(chunk.max(1)));
    let (mut rest, mut offset) = (items, 0usize);
    for ids in ids.chunks(chunk.max(1)) {
        let end = ids.last().map_or(offset, |&l| l as usize + 1).clamp(offset, offset + rest.len());
        let (mine, tail) = std::mem::take(&mut rest).split_at_mut(end - offset);
        pieces.push((ids, offset, mine));
        (rest, offset) = (tail, end);
    }
    pieces
}

/// A part's occupied box at a level, about whose centre an instance's sphere is drawn.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PartBox {
    /// The box's centre (object space).
    pub centre: DVec3,
    /// Its half extents.
    pub half: DVec3,
    /// The largest distance from the centre to a point of an occupied cell
    /// ([`crate::svo::Svo::occupied_reach`]).
    pub reach: f64,
}

/// Per part (a handful, shared by thousands of instances): its [`PartBox`] at `max_level`.
pub(crate) fn part_boxes(scene: &Scene, max_level: u32) -> Vec<PartBox> {
    scene
        .parts
        .iter()
        .map(|svo| {
            let (lo, hi) = svo.occupied_box(max_level);
            PartBox { centre: (lo + hi) * 0.5, half: (hi - lo) * 0.5, reach: svo.occupied_reach(max_level) }
        })
        .collect()
}

/// Per instance, a camera-relative axis-aligned box holding its occupied cells at
/// `max_level` (the world box of its part's [`crate::svo::Svo::occupied_box`], grown as
/// the sphere of [`Prepared`] is, by [`SPHERE_PAD`] of itself and of the part's cube): a
/// ray that misses it cannot hit the instance at that level. Flat and long instances (a
/// ground) fill their box far more than their sphere.
pub fn occupied_world_boxes(scene: &Scene, eye: DVec3, max_level: u32) -> Vec<(DVec3, DVec3)> {
    let boxes = part_boxes(scene, max_level);
    scene
        .instances()
        .iter()
        .enumerate()
        .map(|(i, inst)| {
            let w = scene.world(i);
            let PartBox { centre, half, .. } = boxes[inst.part];
            let m = &w.matrix3;
            // |M|·half: the box's corners mapped by M lie within it of the mapped centre.
            let (a, b, c) = (m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs());
            let reach = a * half.x + b * half.y + c * half.z;
            let stretch = a.length().max(b.length()).max(c.length());
            let size = scene.parts[inst.part].bounds.size as f64;
            let grow = reach * (1.0 + SPHERE_PAD) + DVec3::splat(1.5 * size * stretch * SPHERE_PAD);
            let mid = w.transform_point3(centre) - eye;
            (mid - grow, mid + grow)
        })
        .collect()
}

/// A bound on how far `m` stretches any vector (its largest singular value): the largest
/// row sum of |MᵀM| (Gershgorin), the largest column length when the columns are
/// orthogonal (a rotation with any scale along the part's axes), more under shear.
pub fn stretch_bound(m: &DMat3) -> f64 {
    let (a, b, c) = (m.x_axis, m.y_axis, m.z_axis);
    let (ab, ac, bc) = (a.dot(b).abs(), a.dot(c).abs(), b.dot(c).abs());
    (a.length_squared() + ab + ac).max(b.length_squared() + ab + bc).max(c.length_squared() + ac + bc).sqrt()
}

/// How far a box's farthest corner lies from its centre once mapped by `m`, for half
/// extents `e`: its corners e·(±x, ±y, z) (the other four are their negatives) mapped by the
/// columns c, |±ex·c0 ± ey·c1 + ez·c2|.
pub fn farthest_corner(m: &DMat3, e: DVec3) -> f64 {
    let (a, b, z) = (m.x_axis * e.x + m.y_axis * e.y, m.x_axis * e.x - m.y_axis * e.y, m.z_axis * e.z);
    (z + a)
        .length_squared()
        .max((z - a).length_squared())
        .max((z + b).length_squared())
        .max((z - b).length_squared())
        .sqrt()
}

/// Whether the eye (the camera-relative origin `prepared` was made for) lies inside a voxel
/// of some instance: every ray from there hits at t = 0 and the image is one colour. For
/// callers without the frame's pixels (a GPU frame kept on the GPU);
/// [`super::Frame::eye_inside_fraction`] measures the same from the pixels. Only instances
/// whose bounding sphere holds the eye are looked up.
pub fn eye_inside(parts: &[std::sync::Arc<crate::svo::Svo>], prepared: &[Prepared]) -> bool {
    prepared.iter().any(|p| p.centre.length() <= p.radius && holds_eye(parts, p))
}

/// [`eye_inside`] with the instances' spheres listed apart (as [`prepare_changed`] keeps
/// them): a crowd's 80 000 spheres are read, not its 12 MB of prepared instances.
pub fn eye_inside_listed(
    parts: &[std::sync::Arc<crate::svo::Svo>],
    prepared: &[Prepared],
    spheres: &[(DVec3, f64)],
) -> bool {
    spheres.iter().zip(prepared).any(|(&(c, r), p)| c.length() <= r && holds_eye(parts, p))
}

/// Whether a voxel of `p`'s part holds the eye.
fn holds_eye(parts: &[std::sync::Arc<crate::svo::Svo>], p: &Prepared) -> bool {
    parts.get(p.part).is_some_and(|svo| svo.contains(p.to_unit.point(DVec3::ZERO)))
}

/// The interval of t over which the ray `o + t·d` (d unit length) is inside the sphere, or
/// None when it misses it or the sphere lies behind the origin.
#[inline]
pub fn sphere_interval(centre: DVec3, radius: f64, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
    let oc = centre - o;
    let b = oc.dot(d);
    let c = oc.length_squared() - radius * radius;
    let disc = b * b - c;
    if !(disc >= 0.0) {
        return None;
    }
    let s = disc.sqrt();
    let (t0, t1) = (b - s, b + s);
    (t1 >= 0.0).then_some((t0, t1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::visibility::{nearest, FrameInstances, Search};
    use crate::scene::{Instance, Transform};
    use crate::svo::Cube;
    use crate::traverse::TraceOptions;
    use glam::{DQuat, Vec3};
    use std::sync::Arc;

    /// `stretch_bound` holds how far random matrices (turns, anisotropic scales, shears)
    /// stretch many directions, and is the largest scale of a turned anisotropic scale.
    #[test]
    fn stretch_bound_holds_every_direction() {
        let mut rng = crate::rng::Rng::new(3);
        let (mut sheared_past_columns, mut exact) = (0, 0);
        for round in 0..2000 {
            let turn = DQuat::from_rotation_y(rng.f64() * 6.3) * DQuat::from_rotation_x(rng.f64() * 6.3);
            let scale = DVec3::new(rng.f64() * 3.0 + 0.01, rng.f64() * 3.0 + 0.01, rng.f64() * 3.0 + 0.01);
            let mut m = DMat3::from_quat(turn) * DMat3::from_diagonal(scale);
            if round % 2 == 1 {
                // A shear (a parent's anisotropic scale over a turned child's).
                m = DMat3::from_diagonal(DVec3::new(rng.f64() * 4.0 + 0.1, 1.0, rng.f64() * 0.5 + 0.1)) * m;
            }
            let bound = stretch_bound(&m);
            let columns = m.x_axis.length().max(m.y_axis.length()).max(m.z_axis.length());
            let mut most = 0.0f64;
            for _ in 0..200 {
                most = most.max((m * rng.unit_vector().as_dvec3().normalize()).length());
            }
            assert!(most <= bound * (1.0 + 1e-12), "round {round}: {most} past the bound {bound}");
            sheared_past_columns += (most > columns * (1.0 + 1e-9)) as u32;
            if round % 2 == 0 {
                assert!((bound - scale.max_element()).abs() <= 1e-12 * bound, "round {round}: {bound} for {scale}");
                exact += 1;
            }
        }
        // Shears that stretch some direction more than any column: the reason for the bound.
        assert!(sheared_past_columns > 50 && exact == 1000, "{sheared_past_columns} sheared past their columns");
    }

    /// World normals stay perpendicular to the world images of the surface's tangents and on
    /// the side the object normal points to, under rotations, anisotropic scales and
    /// mirrors, and with the identity's offset-and-scale map.
    #[test]
    fn normals_stay_perpendicular_to_transformed_surfaces() {
        let grid =
            crate::voxelize::VoxelGrid::from_coords(2, Cube { min: Vec3::ZERO, size: 3.0 }, [[1, 2, 0]], Vec3::ONE);
        let mut rng = crate::rng::Rng::new(11);
        for k in 0..40 {
            let mut scene = Scene::new(vec![Arc::new(crate::svo::build(&grid).unwrap())]);
            let scale = DVec3::new(rng.range(-3.0, 3.0) as f64, 0.2 + rng.f64() * 4.0, 0.05 + rng.f64());
            let local = match k {
                0 => Transform::IDENTITY,
                _ => Transform::new(
                    DVec3::new(rng.f64(), -2.0, 5.0),
                    DQuat::from_axis_angle(rng.unit_vector().as_dvec3(), rng.f64() * 6.0),
                    if scale.x.abs() < 0.1 { DVec3::new(0.5, scale.y, scale.z) } else { scale },
                )
                .unwrap(),
            };
            scene.add(Instance { part: 0, parent: None, local }).unwrap();
            scene.update().unwrap();
            let w = scene.world(0).matrix3;
            let p = prepare(&scene, DVec3::new(1.0, 2.0, 3.0), k != 0)[0];
            assert_eq!(matches!(p.to_unit, ToUnit::Scale { .. }), k == 0);
            for _ in 0..20 {
                let n = rng.unit_vector().as_dvec3().normalize();
                let t1 = n.any_orthonormal_vector();
                let t2 = n.cross(t1);
                let nw = p.normal_to_world(n).normalize();
                for t in [t1, t2] {
                    let tw = (w * t).normalize();
                    assert!(nw.dot(tw).abs() < 1e-9, "{k}: {}", nw.dot(tw));
                }
                assert!(nw.dot(w * n) > 0.0, "{k}: the normal flipped");
            }
        }
    }

    /// One voxel near a corner of a depth-6 cube: at coarse levels the node holding it
    /// reaches far beyond the voxel. Rays aimed anywhere into each level's occupied box hit
    /// the same with the sphere culling as without it, so each level's sphere holds what
    /// that level can hit; the spheres shrink level by level, the voxel's own to a small
    /// fraction of the cube's, and `prepare` gives the voxels' sphere.
    #[test]
    fn spheres_hold_what_each_level_can_hit() {
        let grid =
            crate::voxelize::VoxelGrid::from_coords(6, Cube { min: Vec3::ZERO, size: 2.0 }, [[1, 2, 1]], Vec3::ONE);
        let svo = Arc::new(crate::svo::build(&grid).unwrap());
        let mut scene = Scene::new(vec![svo.clone()]);
        let local = Transform::new(
            DVec3::new(3.0, -1.0, 0.5),
            DQuat::from_axis_angle(DVec3::new(1.0, 2.0, -0.5).normalize(), 0.7),
            DVec3::new(0.5, 2.0, 1.25),
        )
        .unwrap();
        scene.add(Instance { part: 0, parent: None, local }).unwrap();
        scene.update().unwrap();
        let eye = DVec3::new(-4.0, 6.0, 9.0);
        let w = scene.world(0);
        let mut rng = crate::rng::Rng::new(3);
        let mut radii = Vec::new();
        for level in 0..=6u32 {
            let mut prepared = Vec::new();
            prepare_into(&scene, eye, true, level, &mut prepared);
            radii.push(prepared[0].radius);
            let fi = FrameInstances { parts: &scene.parts, prepared: &prepared, bvh: None, starts: None };
            let opts = TraceOptions { max_level: level, ..TraceOptions::default() };
            let (lo, hi) = svo.occupied_box(level);
            let mut hits = 0;
            for _ in 0..400 {
                let target = lo + (hi - lo) * DVec3::new(rng.f64(), rng.f64(), rng.f64());
                let d = (w.transform_point3(target) - eye).normalize();
                let plain = nearest(&fi, DVec3::ZERO, d, Search::Plain, &opts);
                assert_eq!(nearest(&fi, DVec3::ZERO, d, Search::Cull, &opts), plain, "level {level}");
                hits += plain.is_some() as u32;
            }
            assert!(hits > 300, "level {level}: {hits} hits");
            // Rays that only clip the box's farthest corner pass just inside the sphere, the
            // closest calls a sphere makes.
            let corner = (0..8)
                .map(|k| DVec3::new([lo.x, hi.x][k & 1], [lo.y, hi.y][(k >> 1) & 1], [lo.z, hi.z][k >> 2]))
                .map(|c| w.transform_point3(c))
                .max_by(|a, b| {
                    (*a - w.transform_point3((lo + hi) * 0.5))
                        .length()
                        .total_cmp(&(*b - w.transform_point3((lo + hi) * 0.5)).length())
                })
                .unwrap();
            let centre = w.transform_point3((lo + hi) * 0.5);
            let r = corner - centre;
            let mut clipped = 0;
            for _ in 0..200 {
                let d = r.cross(rng.unit_vector().as_dvec3()).normalize();
                let through = centre + r * (1.0 - 1e-5);
                let o = through - d * 10.0 - eye;
                let plain = nearest(&fi, o, d, Search::Plain, &opts);
                assert_eq!(nearest(&fi, o, d, Search::Cull, &opts), plain, "level {level}, corner");
                clipped += plain.is_some() as u32;
            }
            assert!(clipped > 20, "level {level}: {clipped} corner hits");
        }
        assert!(radii.windows(2).all(|r| r[1] <= r[0]), "{radii:?}");
        assert!(radii[6] * 10.0 < radii[0], "{radii:?}");
        assert_eq!(prepare(&scene, eye, true)[0].radius.to_bits(), radii[6].to_bits());
    }

    /// Prepared instances kept from frame to frame and refilled where the scene changed equal
    /// instances prepared afresh, bit for bit, through moved instances (some of them parents
    /// of others), a part swapped, an added instance, a moved eye, another level, a part list
    /// edited in place, a refused update, a clone of the scene edited apart from it, no update
    /// and two updates between two frames.
    #[test]
    fn prepared_instances_refilled_where_changed_equal_fresh_ones() {
        let grid = |k: u32| {
            crate::voxelize::VoxelGrid::from_coords(
                4,
                Cube { min: Vec3::ZERO, size: 2.0 },
                [[k, 2, 1], [3, k, 5]],
                Vec3::ONE,
            )
        };
        let parts: Vec<Arc<crate::svo::Svo>> = (1..4).map(|k| Arc::new(crate::svo::build(&grid(k)).unwrap())).collect();
        let mut scene = Scene::new(parts.clone());
        let mut rng = crate::rng::Rng::new(4);
        let random_local = |rng: &mut crate::rng::Rng| {
            Transform::new(
                DVec3::new(rng.range(-5.0, 5.0) as f64, rng.range(-5.0, 5.0) as f64, rng.range(-5.0, 5.0) as f64),
                DQuat::from_axis_angle(rng.unit_vector().as_dvec3().normalize(), rng.f64() * 6.0),
                DVec3::new(0.5 + rng.f64(), 0.5 + rng.f64(), 0.5 + rng.f64()),
            )
            .unwrap()
        };
        // Enough that the changed instances of one update fill several parallel chunks.
        let n = 8000;
        for i in 0..n {
            let parent = (i % 4 != 0).then_some(i - i % 4);
            let local = random_local(&mut rng);
            scene.add(Instance { part: i % 3, parent, local }).unwrap();
        }
        scene.update().unwrap();
        let (mut kept, mut spheres, mut made) = (Vec::new(), Vec::new(), PreparedFor::default());
        let mut eye = DVec3::new(1.0, 2.0, 3.0);
        let mut level = u32::MAX;
        let mut check = |scene: &Scene, eye: DVec3, level: u32, what: &str| {
            // Spheres that lost their tail (kept by someone else): all are refilled.
            if what == "step 10" {
                spheres.truncate(spheres.len() / 2);
            }
            prepare_changed(scene, eye, true, level, &mut kept, &mut spheres, &mut made);
            let mut fresh = Vec::new();
            prepare_into(scene, eye, true, level, &mut fresh);
            assert_eq!(kept.len(), fresh.len(), "{what}");
            assert_eq!(spheres.len(), fresh.len(), "{what}");
            for (i, (a, b)) in kept.iter().zip(&fresh).enumerate() {
                assert_eq!(a, b, "{what}: instance {i}");
                assert_eq!(spheres[i], (b.centre, b.radius), "{what}: sphere {i}");
            }
        };
        check(&scene, eye, level, "first");
        for step in 0..12 {
            if step == 2 {
                // No update since the last check: nothing is refilled.
                check(&scene, eye, level, "no update");
            }
            // Some instances move: every 7th of a random offset, parents carrying children.
            let offset = step % 7;
            let edits: Vec<(usize, Transform)> = (offset..n).step_by(7).map(|i| (i, random_local(&mut rng))).collect();
            scene.set_locals(&edits).unwrap();
            match step {
                3 => scene.set_part(10, 2).unwrap(),
                4 => eye += DVec3::new(0.5, 0.0, 0.0),
                5 => level = 2,
                6 => {
                    scene.add(Instance { part: 1, parent: Some(8), local: random_local(&mut rng) }).unwrap();
                }
                7 => scene.parts[1] = Arc::new(crate::svo::build(&grid(3)).unwrap()),
                8 => {
                    // Each scale alone is acceptable, their product (a parent and its child)
                    // is refused, after the other moved instances were composed: nothing
                    // changes, and the prepared instances stay as they were.
                    let tiny = Transform { scale: DVec3::splat(2e-6), ..Transform::IDENTITY };
                    scene.set_locals(&[(n - 4, tiny), (n - 3, tiny)]).unwrap();
                    assert!(scene.update().is_err());
                    check(&scene, eye, level, "refused");
                    scene.set_locals(&[(n - 4, Transform::IDENTITY), (n - 3, Transform::IDENTITY)]).unwrap();
                }
                9 => {
                    // A clone edited apart from the scene: prepared for the clone, then for the
                    // scene again.
                    let mut other = scene.clone();
                    other.set_locals(&[(1, random_local(&mut rng))]).unwrap();
                    other.update().unwrap();
                    check(&other, eye, level, "the clone");
                }
                11 => {
                    // Two updates since the last check: the stamps are scanned.
                    scene.update().unwrap();
                    scene.set_locals(&[(5, random_local(&mut rng)), (n - 1, random_local(&mut rng))]).unwrap();
                }
                _ => {}
            }
            scene.update().unwrap();
            check(&scene, eye, level, &format!("step {step}"));
        }
    }
}
