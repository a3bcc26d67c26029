//! The numerical stability suite: stiff and adversarial rays traced through SVOs and checked
//! ray by ray against the brute-force DDA oracle ([`crate::oracle`]). `voxray stability`
//! prints its table; `tests/stability.rs` asserts it.
//!
//! A traversal answer counts as correct when it names the oracle's voxel at the oracle's t
//! (relative error ≤ [`T_TOLERANCE`] of max(|t|, one cube width in t)). Where a ray passes
//! exactly through an edge or corner, several voxels are touched at the same t and which one
//! a walk reports first depends on rounding; such an answer is a *tie*, accepted only if the
//! voxel reported is occupied and its closed box is touched at that t.

use crate::oracle::{dda, voxel_interval, voxel_interval_grown, Contact, OracleHit, VoxelSet};
use crate::ray::UnitRay;
use crate::rng::Rng;
use crate::svo::{self, Cube, Svo};
use crate::traverse::{step_bound, trace_unit, Hit, TraceOptions};
use crate::voxelize::VoxelGrid;
use glam::{DQuat, DVec3, Vec3};
use std::sync::Arc;

/// Largest accepted relative t error against the oracle.
pub const T_TOLERANCE: f64 = 1e-5;

/// One ray of a case, in the unit cube of the case's SVO.
#[derive(Clone, Copy, Debug)]
pub struct CaseRay {
    /// Origin (unit-cube coordinates).
    pub origin: Vec3,
    /// Direction (any length).
    pub dir: Vec3,
    /// Interval start.
    pub t_min: f32,
    /// Interval end.
    pub t_max: f32,
}

/// A ray in the unit cube of an SVO, in f64, with its interval.
#[derive(Clone, Copy, Debug)]
pub struct Ray64 {
    /// Origin.
    pub origin: DVec3,
    /// Direction.
    pub dir: DVec3,
    /// Interval start.
    pub t_min: f64,
    /// Interval end.
    pub t_max: f64,
}

impl From<&CaseRay> for Ray64 {
    fn from(r: &CaseRay) -> Self {
        Ray64 { origin: r.origin.as_dvec3(), dir: r.dir.as_dvec3(), t_min: r.t_min as f64, t_max: r.t_max as f64 }
    }
}

/// A scene plus a family of rays.
pub struct Case {
    /// Short name (table row).
    pub name: String,
    /// The voxels.
    pub set: VoxelSet,
    /// The SVO built from them (unit-cube bounds).
    pub svo: Svo,
    /// Rays to trace.
    pub rays: Vec<CaseRay>,
    /// Level-of-detail limit, if the case tests LOD.
    pub max_level: Option<u32>,
}

/// How one ray compared with the oracle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Same voxel (or both missed) and t within tolerance.
    Match,
    /// A different voxel touched at the same t (edge/corner/face contact), or a zero-length
    /// touch one side reported and the other skipped.
    Tie,
    /// Anything else.
    Mismatch,
}

/// One row of the stability table.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CaseReport {
    /// Case name.
    pub name: String,
    /// Tree depth.
    pub depth: u32,
    /// Rays traced.
    pub rays: u64,
    /// Rays the oracle says hit.
    pub hits: u64,
    /// Results with a NaN or infinite t or normal.
    pub nan: u64,
    /// Disagreements with the oracle (wrong voxel, wrong t, hit vs miss).
    pub mismatches: u64,
    /// Accepted ties (see [`Verdict::Tie`]).
    pub ties: u64,
    /// Largest relative |Δt| among rays where both hit.
    pub max_rel_dt: f64,
    /// Largest loop count of one traversal.
    pub max_steps: u32,
    /// The proven bound on the loop count for this depth.
    pub step_bound: u32,
    /// Traversals stopped by the step bound.
    pub aborted: u64,
    /// Description of the first mismatch, for debugging.
    pub first_mismatch: Option<String>,
}

/// How close (relative to max(|t|, one cube width in t)) in t two contacts must be to count
/// as simultaneous.
pub const TOUCH_TOLERANCE: f64 = 1e-6;

/// How close (in unit-cube units) a ray must pass to a voxel to count as touching it: the
/// traversal decides contacts in f32, whose origin coordinates carry about 2⁻²⁴ of error, so a
/// contact is only resolvable to a few times that as a *distance* — in t it is larger by the
/// inverse of the direction component, which is why this is not a t tolerance.
pub const TOUCH_DISTANCE: f64 = 1.0 / (1u64 << 20) as f64;

/// Compares a traversal result with the oracle for one ray. `strict` is the oracle under
/// closed-box contact, `lenient` the oracle counting only voxels the ray stays inside for
/// longer than [`TOUCH_TOLERANCE`]. The hit must name an occupied voxel the ray passes within
/// [`TOUCH_DISTANCE`] of, at its t. Returns the verdict and the relative error of the hit's t
/// against the exact (f64) entry of the voxel it names.
pub fn compare(
    set: &VoxelSet,
    ray: &Ray64,
    got: Option<&Hit>,
    strict: Option<&OracleHit>,
    lenient: Option<&OracleHit>,
) -> (Verdict, f64) {
    compare_with(set, ray, got, strict, lenient, T_TOLERANCE)
}

/// [`compare`] with another bound on the relative t error (the GPU reports t in f32).
pub fn compare_with(
    set: &VoxelSet,
    ray: &Ray64,
    got: Option<&Hit>,
    strict: Option<&OracleHit>,
    lenient: Option<&OracleHit>,
    t_tolerance: f64,
) -> (Verdict, f64) {
    let (o, d) = (ray.origin, ray.dir);
    let t_unit = 1.0 / d.abs().max_element().max(1e-300);
    let scale = |t: f64| t.abs().max(t_unit);
    let Some(h) = got else {
        // Missing is right when nothing is robustly entered (at most touched).
        return (
            if strict.is_none() {
                Verdict::Match
            } else if lenient.is_none() {
                Verdict::Tie
            } else {
                Verdict::Mismatch
            },
            0.0,
        );
    };
    let (enter, _) = voxel_interval(set.depth, h.coord, o, d);
    let t = h.t as f64;
    let exact_t = enter.max(ray.t_min);
    let dt = (t - exact_t).abs() / scale(exact_t);
    let touch = TOUCH_TOLERANCE * scale(t);
    let (g_enter, g_exit) = voxel_interval_grown(set.depth, h.coord, o, d, TOUCH_DISTANCE);
    let contact = set.contains(h.coord) && g_enter <= t + touch && g_exit >= t - touch;
    if !contact || dt > t_tolerance || t > ray.t_max + touch {
        return (Verdict::Mismatch, dt);
    }
    match (strict, lenient) {
        (Some(s), _) if s.coord == h.coord => (Verdict::Match, dt),
        // Another voxel touched first or at the same time (an edge/corner/face contact), but no
        // voxel is robustly entered before this one.
        (_, Some(l)) if t <= l.t + t_tolerance * scale(l.t) => (Verdict::Tie, dt),
        (_, None) => (Verdict::Tie, dt),
        _ => (Verdict::Mismatch, dt),
    }
}

/// Checks one traversal result against the oracle (strict, then lenient) and makes a
/// one-ray report.
/// Checks one result against the oracle; see [`compare`].
pub fn check(set: &VoxelSet, r: &Ray64, hit: Option<Hit>, steps: u32, aborted: bool) -> CaseReport {
    check_with(set, r, hit, steps, aborted, T_TOLERANCE)
}

/// [`check`] with another t tolerance.
pub fn check_with(
    set: &VoxelSet,
    r: &Ray64,
    hit: Option<Hit>,
    steps: u32,
    aborted: bool,
    t_tolerance: f64,
) -> CaseReport {
    let want = dda(set, r.origin, r.dir, r.t_min, r.t_max, Contact::Closed);
    let (verdict, dt) = match compare_with(set, r, hit.as_ref(), want.as_ref(), want.as_ref(), t_tolerance) {
        (Verdict::Mismatch, _) => {
            let min_overlap = TOUCH_TOLERANCE * r.t_min.abs().max(1.0 / r.dir.abs().max_element());
            let lenient = dda(set, r.origin, r.dir, r.t_min, r.t_max, Contact::MinOverlap(min_overlap));
            compare_with(set, r, hit.as_ref(), want.as_ref(), lenient.as_ref(), t_tolerance)
        }
        ok => ok,
    };
    let nan = hit.is_some_and(|h| !h.t.is_finite() || !h.normal().is_finite() || !h.face_normal.is_finite());
    CaseReport {
        rays: 1,
        hits: want.is_some() as u64,
        nan: nan as u64,
        mismatches: (verdict == Verdict::Mismatch) as u64,
        ties: (verdict == Verdict::Tie) as u64,
        max_rel_dt: dt,
        max_steps: steps,
        aborted: aborted as u64,
        first_mismatch: (verdict == Verdict::Mismatch)
            .then(|| format!("ray {r:?}: traversal {:?}, oracle {want:?}", hit.map(|h| (h.t, h.coord)))),
        ..Default::default()
    }
}

/// Adds up two reports.
pub fn merge(mut a: CaseReport, b: CaseReport) -> CaseReport {
    a.rays += b.rays;
    a.hits += b.hits;
    a.nan += b.nan;
    a.mismatches += b.mismatches;
    a.ties += b.ties;
    a.max_rel_dt = a.max_rel_dt.max(b.max_rel_dt);
    a.max_steps = a.max_steps.max(b.max_steps);
    a.aborted += b.aborted;
    a.first_mismatch = a.first_mismatch.or(b.first_mismatch);
    a
}

/// Runs one case.
pub fn run_case(case: &Case) -> CaseReport {
    let oracle_set = match case.max_level {
        Some(l) if l < case.set.depth => case.set.coarsen(l),
        _ => case.set.clone(),
    };
    let opts_of =
        |r: &CaseRay| TraceOptions { t_min: r.t_min, t_max: r.t_max, max_level: case.max_level.unwrap_or(u32::MAX) };
    let one = |r: &CaseRay| -> CaseReport {
        let traced =
            UnitRay::from_unit(r.origin.as_dvec3(), r.dir.as_dvec3()).map(|u| trace_unit(&case.svo, &u, &opts_of(r)));
        let (hit, steps, aborted) = traced.map_or((None, 0, false), |t| (t.hit, t.steps, t.aborted));
        check(&oracle_set, &Ray64::from(r), hit, steps, aborted)
    };
    #[cfg(feature = "parallel")]
    let mut report = {
        use rayon::prelude::*;
        case.rays.par_iter().map(one).reduce(CaseReport::default, merge)
    };
    #[cfg(not(feature = "parallel"))]
    let mut report = case.rays.iter().map(one).fold(CaseReport::default(), merge);
    report.name = case.name.clone();
    report.depth = case.svo.depth;
    report.step_bound = step_bound(case.svo.depth);
    report
}

/// Builds a case from voxel coordinates (unit-cube bounds).
pub fn make_case(name: &str, depth: u32, coords: Vec<[u32; 3]>, rays: Vec<CaseRay>, max_level: Option<u32>) -> Case {
    let unit = Cube { min: Vec3::ZERO, size: 1.0 };
    let grid = VoxelGrid::from_coords(depth, unit, coords.iter().copied(), Vec3::splat(0.8));
    let svo = svo::build(&grid).expect("non-empty case scene");
    Case { name: name.into(), set: VoxelSet::new(depth, coords), svo, rays, max_level }
}

/// Scattered blobs and single voxels in a 2^depth grid.
pub fn scene_blobs(depth: u32, seed: u64) -> Vec<[u32; 3]> {
    let n = 1u32 << depth;
    let mut rng = Rng::new(seed);
    let mut out = Vec::new();
    for _ in 0..12 {
        let c = Vec3::new(rng.range(0.1, 0.9), rng.range(0.1, 0.9), rng.range(0.1, 0.9)) * n as f32;
        let r = rng.range(0.03, 0.12) * n as f32;
        let (lo, hi) = ((c - r).max(Vec3::ZERO), (c + r).min(Vec3::splat(n as f32 - 1.0)));
        for z in lo.z as u32..=hi.z as u32 {
            for y in lo.y as u32..=hi.y as u32 {
                for x in lo.x as u32..=hi.x as u32 {
                    let p = Vec3::new(x as f32, y as f32, z as f32) + 0.5;
                    if (p - c).length() <= r {
                        out.push([x, y, z]);
                    }
                }
            }
        }
    }
    for _ in 0..(n * n / 8) {
        out.push([rng.below(n as u64) as u32, rng.below(n as u64) as u32, rng.below(n as u64) as u32]);
    }
    out
}

/// A one-voxel-thick spherical shell (like a voxelized surface) around a solid cube.
pub fn scene_shell(depth: u32) -> Vec<[u32; 3]> {
    let n = 1u32 << depth;
    let c = n as f32 / 2.0;
    let r = 0.4 * n as f32;
    let mut out = Vec::new();
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let p = Vec3::new(x as f32, y as f32, z as f32) + 0.5 - c;
                let l = p.length();
                if (l - r).abs() <= 0.87 || p.abs().max_element() < 0.1 * n as f32 {
                    out.push([x, y, z]);
                }
            }
        }
    }
    out
}

/// The default car's body voxelized at `depth` (a real surface: thin walls, curved panels).
pub fn scene_car_body(depth: u32) -> Vec<[u32; 3]> {
    let mesh = crate::model::car::mesh();
    let opts = crate::voxelize::VoxelizeOptions { resolution: crate::voxelize::Resolution::Depth(depth), solid: false };
    crate::voxelize::voxelize(&mesh.parts[0], &mesh.materials, &opts, &|_, _| {})
        .map(|g| g.coords().collect())
        .unwrap_or_default()
}

/// A compact random blob 2^16 deep: a 64³ window placed far from the origin of the grid.
pub fn scene_deep(depth: u32, seed: u64) -> Vec<[u32; 3]> {
    let mut rng = Rng::new(seed);
    let base = [(1u32 << depth) / 3 + 17, (1u32 << depth) / 2 - 5, (1u32 << depth) * 2 / 3 + 3];
    let mut out = Vec::new();
    for _ in 0..6000 {
        out.push([0, 1, 2].map(|i| base[i] + rng.below(64) as u32));
    }
    out
}

fn random_point(rng: &mut Rng, lo: f32, hi: f32) -> Vec3 {
    Vec3::new(rng.range(lo, hi), rng.range(lo, hi), rng.range(lo, hi))
}

fn voxel_point(c: [u32; 3], depth: u32, local: Vec3) -> Vec3 {
    (Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32) + local) / (1u64 << depth) as f32
}

fn ray(origin: Vec3, dir: Vec3) -> CaseRay {
    CaseRay { origin, dir, t_min: 0.0, t_max: f32::INFINITY }
}

/// Every standard case. `random_rays` sets the size of the random families (the test uses
/// 10⁶ in all); the adversarial families have fixed sizes.
pub fn standard_cases(random_rays: usize) -> Vec<Case> {
    let mut cases = Vec::new();
    let blobs = scene_blobs(6, 1);
    let shell = scene_shell(7);
    let mut rng = Rng::new(42);

    // Uniformly random rays: origins around and inside the cube, random directions; half of
    // them aimed at an occupied voxel so that most hit something.
    let random = |rng: &mut Rng, coords: &[[u32; 3]], depth: u32, n: usize| {
        (0..n)
            .map(|i| {
                let o = random_point(rng, -0.5, 1.5);
                let dir = if i % 2 == 0 {
                    rng.unit_vector()
                } else {
                    let c = coords[rng.below(coords.len() as u64) as usize];
                    (voxel_point(c, depth, random_point(rng, 0.0, 1.0)) - o).normalize_or(Vec3::X)
                };
                ray(o, dir)
            })
            .collect::<Vec<_>>()
    };
    let r = random(&mut rng, &blobs, 6, random_rays * 2 / 5);
    cases.push(make_case("random rays, blobs d6", 6, blobs.clone(), r, None));
    let r = random(&mut rng, &shell, 7, random_rays * 2 / 5);
    cases.push(make_case("random rays, shell d7", 7, shell.clone(), r, None));
    let car = scene_car_body(8);
    let r = random(&mut rng, &car, 8, random_rays - 2 * (random_rays * 2 / 5));
    cases.push(make_case("random rays, car body d8", 8, car, r, None));

    // Random [t_min, t_max] intervals, including origins inside the cube.
    let mut r = random(&mut rng, &blobs, 6, 20_000);
    for x in &mut r {
        x.t_min = rng.range(-0.5, 1.5);
        x.t_max = x.t_min + rng.range(0.0, 1.0);
    }
    cases.push(make_case("random t intervals", 6, blobs.clone(), r, None));

    // Axis-parallel rays from grid points (centres, faces, edges, corners), with the other
    // components +0.0 or −0.0.
    let n6 = 64u32;
    let mut r = Vec::new();
    for k in 0..20_000 {
        let c = [0, 1, 2].map(|_| rng.below(n6 as u64) as u32);
        let local = [0.5f32, 0.0, 1.0, 0.25][k % 4];
        let mut local3 = Vec3::splat(0.5);
        for i in 0..3 {
            if rng.below(2) == 0 {
                local3[i] = local;
            }
        }
        let mut o = voxel_point(c, 6, local3);
        let axis = rng.below(3) as usize;
        o[axis] = if rng.below(2) == 0 { -0.25 } else { 1.25 };
        let mut d = Vec3::new(
            if rng.below(2) == 0 { 0.0 } else { -0.0 },
            if rng.below(2) == 0 { 0.0 } else { -0.0 },
            if rng.below(2) == 0 { 0.0 } else { -0.0 },
        );
        d[axis] = if o[axis] < 0.0 { 1.0 } else { -1.0 };
        r.push(ray(o, d));
    }
    cases.push(make_case("axis-parallel, ±0.0 others", 6, blobs.clone(), r, None));

    // ±0.0, denormal and minimum-normal components in otherwise random directions.
    let specials = [0.0f32, -0.0, 1e-40, -1e-40, f32::MIN_POSITIVE, -f32::MIN_POSITIVE, 1e-45, -1e-45];
    let mut r = random(&mut rng, &blobs, 6, 20_000);
    for x in &mut r {
        let k = 1 + rng.below(2) as usize;
        for _ in 0..k {
            x.dir[rng.below(3) as usize] = specials[rng.below(specials.len() as u64) as usize];
        }
        if x.dir.abs().max_element() == 0.0 {
            x.dir.x = 1.0;
        }
    }
    cases.push(make_case("±0.0 / denormal components", 6, blobs.clone(), r, None));

    // Along voxel faces: one coordinate exactly on a grid plane, no motion along it.
    let mut r = random(&mut rng, &blobs, 6, 20_000);
    for x in &mut r {
        let axis = rng.below(3) as usize;
        x.origin[axis] = rng.below(n6 as u64 + 1) as f32 / n6 as f32;
        x.dir[axis] = if rng.below(2) == 0 { 0.0 } else { -0.0 };
        if x.dir.abs().max_element() == 0.0 {
            x.dir[(axis + 1) % 3] = 1.0;
        }
    }
    cases.push(make_case("along voxel faces", 6, blobs.clone(), r, None));

    // Along voxel edges: two coordinates on grid planes, moving along the third axis.
    let mut r = Vec::new();
    for _ in 0..20_000 {
        let axis = rng.below(3) as usize;
        let mut o = Vec3::ZERO;
        for i in 0..3 {
            o[i] = rng.below(n6 as u64 + 1) as f32 / n6 as f32;
        }
        o[axis] = if rng.below(2) == 0 { -0.5 } else { 1.5 };
        let mut d = Vec3::ZERO;
        d[axis] = if o[axis] < 0.0 { 1.0 } else { -1.0 };
        r.push(ray(o, d));
    }
    cases.push(make_case("along voxel edges", 6, blobs.clone(), r, None));

    // Through voxel corners: diagonal directions from a point on a diagonal through a grid
    // corner; every coordinate is dyadic, so the ray meets corners exactly.
    let mut r = Vec::new();
    for _ in 0..20_000 {
        let corner = Vec3::new(rng.below(65) as f32, rng.below(65) as f32, rng.below(65) as f32) / 64.0;
        let sign = Vec3::new(
            if rng.below(2) == 0 { 1.0 } else { -1.0 },
            if rng.below(2) == 0 { 1.0 } else { -1.0 },
            if rng.below(2) == 0 { 1.0 } else { -1.0 },
        );
        let back = rng.below(96) as f32 / 64.0;
        r.push(ray(corner - sign * back, sign));
    }
    cases.push(make_case("through voxel corners", 6, blobs.clone(), r, None));

    // Origins on faces of occupied voxels, and inside occupied voxels.
    let (mut on_face, mut inside) = (Vec::new(), Vec::new());
    for _ in 0..20_000 {
        let c = blobs[rng.below(blobs.len() as u64) as usize];
        let mut local = random_point(&mut rng, 0.0, 1.0);
        local[rng.below(3) as usize] = rng.below(2) as f32;
        on_face.push(ray(voxel_point(c, 6, local), rng.unit_vector()));
        let c = blobs[rng.below(blobs.len() as u64) as usize];
        inside.push(ray(voxel_point(c, 6, random_point(&mut rng, 0.01, 0.99)), rng.unit_vector()));
    }
    cases.push(make_case("origins on voxel faces", 6, blobs.clone(), on_face, None));
    cases.push(make_case("origins inside voxels", 6, blobs.clone(), inside, None));

    // Grazing angles: one component 10⁻³ … 10⁻⁹ of the others.
    let mut r = random(&mut rng, &shell, 7, 20_000);
    for x in &mut r {
        let axis = rng.below(3) as usize;
        x.dir[axis] *= 10f32.powf(-rng.range(3.0, 9.0));
    }
    cases.push(make_case("grazing angles", 7, shell.clone(), r, None));

    // Level of detail: stop two levels above the leaves; the oracle walks the coarsened set.
    let r = random(&mut rng, &shell, 7, 20_000);
    cases.push(make_case("LOD max_level = depth-2", 7, shell.clone(), r, Some(5)));

    // Depth 16: a blob deep inside a 65536³ grid, rays aimed at it, some axis-parallel.
    let deep = scene_deep(16, 7);
    let mut r = random(&mut rng, &deep, 16, 20_000);
    for (i, x) in r.iter_mut().enumerate() {
        if i % 4 == 0 {
            let axis = rng.below(3) as usize;
            let target = x.origin + x.dir;
            x.dir = Vec3::ZERO;
            x.dir[axis] = 1.0;
            x.origin = target;
            x.origin[axis] = -0.1;
        }
    }
    cases.push(make_case("depth-16 tree", 16, deep, r, None));
    cases
}

/// One placement: parent transform, optional child transform (the traced instance is the
/// child when there is one), and world rays (origin, unit direction).
pub type TransformBatch = (crate::scene::Transform, Option<crate::scene::Transform>, Vec<(DVec3, DVec3)>);

/// An SVO placed by a transform (or a parent and a child transform), traced the way the
/// renderer traces instances: camera-relative f64 maps, the search of `render::visibility`.
pub struct TransformCase {
    /// Short name (table row).
    pub name: String,
    /// The voxels.
    pub set: VoxelSet,
    /// Their SVO (unit-cube bounds).
    pub part: Arc<Svo>,
    /// Placements and their rays.
    pub batches: Vec<TransformBatch>,
}

/// Runs a transform case: each ray through the renderer's instance path, each compared with
/// the DDA on the ray mapped into the unit cube in f64.
pub fn run_transform_case(case: &TransformCase) -> CaseReport {
    use crate::render::instances::prepare_into;
    use crate::render::visibility::{nearest, FrameInstances, Search};
    use crate::scene::{Instance, Scene};
    let mut report = CaseReport::default();
    for (parent, child, rays) in &case.batches {
        let mut scene = Scene::new(vec![case.part.clone()]);
        let Ok(p) = scene.add(Instance { part: 0, parent: None, local: *parent }) else { continue };
        let leaf = match child {
            Some(c) => match scene.add(Instance { part: 0, parent: Some(p), local: *c }) {
                Ok(i) => i,
                Err(_) => continue,
            },
            None => p,
        };
        if scene.update().is_err() {
            continue;
        }
        let world = scene.world(leaf);
        let to_unit = world.inverse();
        // Every ray also at a coarser level of detail, against the coarsened voxels: the
        // instance's sphere (which culls here) must hold what each level can hit.
        let coarse_level = case.part.depth.saturating_sub(2);
        let coarse_set = case.set.coarsen(coarse_level);
        let one = |&(o, d): &(DVec3, DVec3)| {
            let r = Ray64 {
                origin: to_unit.transform_point3(o),
                dir: to_unit.transform_vector3(d),
                t_min: 0.0,
                t_max: f64::INFINITY,
            };
            let mut report = CaseReport::default();
            for (max_level, set) in [(u32::MAX, &case.set), (coarse_level, &coarse_set)] {
                let mut prepared = Vec::new();
                prepare_into(&scene, o, true, max_level, &mut prepared);
                // Only the instance under test (the parent of a hierarchy is a helper).
                let fi = FrameInstances {
                    parts: &scene.parts,
                    prepared: &prepared[leaf..leaf + 1],
                    bvh: None,
                    starts: None,
                };
                let opts = TraceOptions { max_level, ..TraceOptions::default() };
                let got = nearest(&fi, DVec3::ZERO, d, Search::Cull, &opts).map(|h| h.hit);
                report = merge(report, check(set, &r, got, 0, false));
            }
            report
        };
        #[cfg(feature = "parallel")]
        let part = {
            use rayon::prelude::*;
            rays.par_iter().map(one).reduce(CaseReport::default, merge)
        };
        #[cfg(not(feature = "parallel"))]
        let part = rays.iter().map(one).fold(CaseReport::default(), merge);
        report = merge(report, part);
    }
    report.name = case.name.clone();
    report.depth = case.part.depth;
    report.step_bound = step_bound(case.part.depth);
    report
}

/// The transform families: extreme and anisotropic scales, large translations, rotations at
/// and near 90°, mirroring, and a parent–child pair whose product shears. `rays_per_case`
/// rays each, aimed at occupied voxels from outside the instance.
pub fn transform_cases(rays_per_case: usize) -> Vec<TransformCase> {
    use crate::scene::Transform;
    let coords = scene_blobs(6, 5);
    let unit = Cube { min: Vec3::ZERO, size: 1.0 };
    let part =
        Arc::new(svo::build(&VoxelGrid::from_coords(6, unit, coords.iter().copied(), Vec3::ONE)).expect("scene"));
    let set = VoxelSet::new(6, coords.iter().copied());
    let mut rng = Rng::new(99);
    let random_scale = |rng: &mut Rng| {
        DVec3::new(
            10f64.powf(rng.f64() * 6.0 - 3.0),
            10f64.powf(rng.f64() * 6.0 - 3.0),
            10f64.powf(rng.f64() * 6.0 - 3.0),
        )
    };
    let random_rot =
        |rng: &mut Rng| DQuat::from_axis_angle(rng.unit_vector().as_dvec3(), rng.f64() * std::f64::consts::TAU);
    type Family = (&'static str, Box<dyn Fn(&mut Rng, usize) -> (Transform, Option<Transform>)>);
    let families: Vec<Family> = vec![
        (
            "instance: anisotropic scale 1e-3…1e3",
            Box::new(move |rng, _| {
                (Transform { translation: DVec3::ZERO, rotation: random_rot(rng), scale: random_scale(rng) }, None)
            }),
        ),
        (
            "instance: translation 1e6 and 1e9",
            Box::new(move |rng, k| {
                let far = if k % 2 == 0 { 1e6 } else { 1e9 };
                let t = rng.unit_vector().as_dvec3() * far;
                (Transform { translation: t, rotation: random_rot(rng), scale: DVec3::splat(0.5 + rng.f64()) }, None)
            }),
        ),
        (
            "instance: rotation at and near 90°",
            Box::new(move |rng, k| {
                let axis = [DVec3::X, DVec3::Y, DVec3::Z, rng.unit_vector().as_dvec3()][k % 4];
                let eps = [0.0, 1e-9, 1e-6, 1e-3][(k / 4) % 4];
                let angle = std::f64::consts::FRAC_PI_2 * (1 + k % 3) as f64 + eps;
                (
                    Transform {
                        translation: DVec3::ZERO,
                        rotation: DQuat::from_axis_angle(axis, angle),
                        scale: DVec3::ONE,
                    },
                    None,
                )
            }),
        ),
        (
            "instance: mirrored (negative scale)",
            Box::new(move |rng, _| {
                let s = DVec3::new(
                    if rng.below(2) == 0 { -1.0 } else { 1.0 },
                    if rng.below(2) == 0 { -1.0 } else { 1.0 },
                    -1.0,
                ) * (0.5 + rng.f64());
                (Transform { translation: DVec3::ZERO, rotation: random_rot(rng), scale: s }, None)
            }),
        ),
        (
            "instance: sheared parent × child",
            Box::new(move |rng, _| {
                let parent = Transform {
                    translation: DVec3::splat(3.0),
                    rotation: random_rot(rng),
                    scale: DVec3::new(4.0, 0.25, 1.0),
                };
                let child =
                    Transform { translation: DVec3::ZERO, rotation: random_rot(rng), scale: DVec3::new(0.3, 2.0, 1.5) };
                (parent, Some(child))
            }),
        ),
    ];
    let batches = 24;
    families
        .into_iter()
        .map(|(name, make)| {
            let batches = (0..batches)
                .map(|k| {
                    let (parent, child) = make(&mut rng, k);
                    let world = parent.to_affine() * child.map_or(glam::DAffine3::IDENTITY, |c| c.to_affine());
                    let radius = (0..3).map(|i| world.matrix3.col(i).length()).fold(0.0, f64::max) * 2.0;
                    let rays = (0..rays_per_case / batches)
                        .map(|i| {
                            let c = coords[rng.below(coords.len() as u64) as usize];
                            let local =
                                DVec3::new(c[0] as f64 + rng.f64(), c[1] as f64 + rng.f64(), c[2] as f64 + rng.f64())
                                    / 64.0;
                            let target = world.transform_point3(local);
                            let o = target + rng.unit_vector().as_dvec3() * radius * (1.5 + 3.0 * rng.f64());
                            // A quarter of the rays go anywhere: mostly misses, some grazing.
                            let d = if i % 4 == 0 { rng.unit_vector().as_dvec3() } else { (target - o).normalize() };
                            (o, d)
                        })
                        .collect();
                    (parent, child, rays)
                })
                .collect();
            TransformCase { name: name.into(), set: set.clone(), part: part.clone(), batches }
        })
        .collect()
}

/// Formats reports as a Markdown table.
pub fn table(reports: &[CaseReport]) -> String {
    let mut s = String::from(
        "| case | depth | rays | oracle hits | NaN | misses vs oracle | accepted ties | max rel. \\|Δt\\| | max loop count | loop bound |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in reports {
        s += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {:.2e} | {} | {} |\n",
            r.name, r.depth, r.rays, r.hits, r.nan, r.mismatches, r.ties, r.max_rel_dt, r.max_steps, r.step_bound
        );
    }
    s
}
