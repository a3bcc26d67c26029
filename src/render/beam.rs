//! Beam optimization for primary rays (Laine & Karras 2010, §5.1 "beam optimization"): before
//! the rays of a screen tile are traced, the tile's whole pyramid of rays is traced once as a
//! cone through each instance's octree, giving a t before which none of its rays can hit that
//! instance. Each ray then starts there (`TraceOptions::t_min`), and a tile whose cone misses
//! an instance's voxels does not trace that instance at all.
//!
//! The bound is conservative, so rays find exactly the hits they find without it (tests
//! compare the images bit for bit): the cone contains every ray of the tile (primary rays
//! share the eye, and a linear map keeps a pyramid a pyramid), node cubes are grown by
//! [`GROW`] beyond anything f32 traversal could count as touching, and the start is the
//! distance to the nearest grown node the cone meets, divided by the longest object-space
//! length of a tile direction, less [`GROW`] again.

use super::instances::Prepared;
use crate::scene::camera::{Basis, Camera};
use crate::svo::Svo;
use glam::DVec3;

/// Tile side in pixels.
pub const TILE: u32 = 8;

/// Width in pixels of the run of tiles (a tile high) that shares one beam: a beam costs about
/// as much as tracing its tile's rays as a packet, and on the car a beam per four tiles
/// loses less in later starts than it saves (docs/benchmarks.md, step 12).
pub const BEAM_WIDTH: u32 = 4 * TILE;

/// Instances above this count get no beams (a per-tile start for every instance would cost
/// more than it saves; the BVH culls them instead). Measured on crowds of driving cars
/// (docs/benchmarks.md, step 36): beams save a third at 80 instances, break even near 150
/// and cost three times over at 800.
pub const MAX_INSTANCES: usize = 128;

/// Unit-cube distance by which node cubes are grown and start distances shrunk: far above the
/// f32 rounding of traversal (~2⁻²³) and its touching tolerance (2⁻²⁰), so a voxel that the
/// traversal could report for some ray of the tile always lies inside the grown cube the cone
/// meets, and each start lies before every such voxel's entry.
pub const GROW: f64 = 1e-5;

/// Stop descending where a node is at most this many times the cone's width at its
/// distance: below that, descending tightens the bound by less than it costs.
const STOP_RATIO: f64 = 1.0;

/// The rays of one tile: a pyramid from the eye, as the four unit directions of its corner
/// pixels.
#[derive(Clone, Copy, Debug)]
pub struct TileRays {
    /// Unit directions of the corner pixels' rays (camera-relative world space).
    pub corners: [DVec3; 4],
}

impl TileRays {
    /// The rays of pixels `x0..x1` × `y0..y1` (pixel centres, as [`Camera::ray_dir`]).
    pub fn new(camera: &Camera, basis: &Basis, x0: u32, y0: u32, x1: u32, y1: u32) -> Self {
        let (a, b) = (x1.max(x0 + 1) - 1, y1.max(y0 + 1) - 1);
        TileRays {
            corners: [
                camera.ray_dir(basis, x0, y0),
                camera.ray_dir(basis, a, y0),
                camera.ray_dir(basis, x0, b),
                camera.ray_dir(basis, a, b),
            ],
        }
    }
}

/// A circular cone from `apex` that holds a set of rays.
#[derive(Clone, Copy, Debug)]
struct Cone {
    apex: DVec3,
    axis: DVec3,
    cos: f64,
    sin: f64,
    tan: f64,
}

impl Cone {
    /// The smallest cone around the mean direction that holds four edge rays, and so (being
    /// convex) the pyramid they span; widened by a micro-radian against rounding.
    fn around(apex: DVec3, dirs: [DVec3; 4]) -> Option<Cone> {
        let units = dirs.map(|d| d.normalize_or_zero());
        let axis = (units[0] + units[1] + units[2] + units[3]).normalize_or_zero();
        if axis == DVec3::ZERO || units.contains(&DVec3::ZERO) {
            return None;
        }
        let min_cos = units.iter().map(|u| u.dot(axis)).fold(1.0f64, f64::min);
        let angle = min_cos.clamp(-1.0, 1.0).acos() + 1e-6;
        // Wider than a quarter turn is no longer a useful beam (and breaks the test below).
        if angle >= 1.5 {
            return None;
        }
        Some(Cone { apex, axis, cos: angle.cos(), sin: angle.sin(), tan: angle.tan() })
    }

    /// Whether the cone meets the ball (exact for the infinite single cone: the apex moved
    /// back so that the cone grows by the radius, then the region behind the apex). Compared
    /// squared, without roots: `a·d < |d| cos` with cos > 0 is `a·d < 0 or (a·d)² < |d|² cos²`.
    fn meets_ball(&self, centre: DVec3, radius: f64) -> bool {
        let back = self.apex - self.axis * (radius / self.sin);
        let d = centre - back;
        let ad = self.axis.dot(d);
        if ad < 0.0 || ad * ad < d.length_squared() * self.cos * self.cos {
            return false;
        }
        let e = centre - self.apex;
        let ae = -self.axis.dot(e);
        if ae >= 0.0 && ae * ae >= e.length_squared() * self.sin * self.sin {
            return e.length_squared() <= radius * radius;
        }
        true
    }
}

/// The cone that holds a tile's rays (from the camera-relative origin), for testing balls.
pub struct TileCone(Option<Cone>);

impl TileCone {
    /// The cone of `tile`'s rays.
    pub fn new(tile: &TileRays) -> TileCone {
        TileCone(Cone::around(DVec3::ZERO, tile.corners))
    }

    /// Whether some ray of the tile may meet the ball: false only when the cone passes wide
    /// of the ball grown by a millionth (far above the rounding of a ray's own sphere test).
    pub fn meets_ball(&self, centre: DVec3, radius: f64) -> bool {
        match &self.0 {
            Some(cone) => cone.meets_ball(centre, radius * (1.0 + 1e-6) + 1e-9 * centre.length()),
            None => true,
        }
    }
}

/// Squared Euclidean distance from `p` to the axis-aligned box `lo..hi` (0 inside).
fn box_distance2(p: DVec3, lo: DVec3, hi: DVec3) -> f64 {
    (lo - p).max(p - hi).max(DVec3::ZERO).length_squared()
}

/// Per instance, the t at which the tile's rays may start (`f32::INFINITY`: none of them
/// can hit the instance), written into `starts`. `max_level` is the traversal's level limit.
pub fn starts(
    parts: &[std::sync::Arc<Svo>],
    prepared: &[Prepared],
    tile: &TileRays,
    max_level: u32,
    starts: &mut Vec<f32>,
) {
    starts.clear();
    let world = Cone::around(DVec3::ZERO, tile.corners);
    for p in prepared {
        starts.push(match world {
            Some(cone) => instance_start(&parts[p.part], p, tile, &cone, max_level),
            // No usable cone: every ray starts at 0, as without beams.
            None => 0.0,
        });
    }
}

fn instance_start(svo: &Svo, p: &Prepared, tile: &TileRays, world: &Cone, max_level: u32) -> f32 {
    if !world.meets_ball(p.centre, p.radius) {
        return f32::INFINITY;
    }
    // The same pyramid in the instance's unit cube: the eye and the corner directions mapped
    // by the same affine map as the rays (t is unchanged by it).
    let apex = p.to_unit.point(DVec3::ZERO);
    let dirs = tile.corners.map(|d| p.to_unit.vector(d));
    let Some(cone) = Cone::around(apex, dirs) else { return 0.0 };
    // Longest unit-space length of a tile direction d: |M d| ≤ |M a| + ‖M‖·|d − a| with a the
    // world axis, |d − a| ≤ 2 sin(θ/2) ≤ tan θ for the world cone's angle θ, and ‖M‖ ≤ its Frobenius norm.
    let m = |v: DVec3| p.to_unit.vector(v);
    let frobenius = (m(DVec3::X).length_squared() + m(DVec3::Y).length_squared() + m(DVec3::Z).length_squared()).sqrt();
    let stretch = m(world.axis).length() + frobenius * world.tan;
    match nearest_node(svo, &cone, max_level.min(svo.depth)) {
        // A unit-space distance s along a direction of unit-space length ≤ stretch takes at
        // least t = s / stretch.
        Some(s) => (((s - GROW).max(0.0) / stretch) * (1.0 - 1e-6)) as f32,
        None => f32::INFINITY,
    }
}

/// The smallest distance from the cone's apex to a grown node that the cone meets, over the
/// nodes at `leaf_level` (voxels, or the level-of-detail limit) and the nodes small against
/// the cone where the descent stops; `None` when the cone meets no voxel. Distances are kept
/// squared until the end.
fn nearest_node(svo: &Svo, cone: &Cone, leaf_level: u32) -> Option<f64> {
    let grow = DVec3::splat(GROW);
    // A node is small against the cone when size ≤ STOP_RATIO · 2 tan · distance.
    let small = (STOP_RATIO * 2.0 * cone.tan).powi(2);
    // The squared distance to the grown cube at `lo` if the cone meets it and it could beat
    // `best`.
    let meets = |lo: DVec3, size: f64, best: f64| -> Option<f64> {
        let (glo, ghi) = (lo - grow, lo + DVec3::splat(size) + grow);
        let d2 = box_distance2(cone.apex, glo, ghi);
        if d2 >= best {
            return None;
        }
        let centre = (glo + ghi) * 0.5;
        cone.meets_ball(centre, (ghi - glo).length() * 0.5).then_some(d2)
    };
    let root = meets(DVec3::ZERO, 1.0, f64::INFINITY)?;
    if leaf_level == 0 {
        return Some(root.sqrt());
    }
    let mut best = f64::INFINITY;
    // Depth first, nearest child first; at most 8 entries per level are pending.
    let mut stack: Vec<(u32, u32, [u32; 3], f64)> = Vec::with_capacity(8 * svo.depth as usize + 1);
    stack.push((0, 0, [0; 3], root));
    while let Some((node, level, coord, dist2)) = stack.pop() {
        if dist2 >= best {
            continue;
        }
        let mask = svo.masks[node as usize];
        let child_level = level + 1;
        let size = 1.0 / (1u64 << child_level) as f64;
        let mut kids: [(f64, u32, [u32; 3]); 8] = [(0.0, 0, [0; 3]); 8];
        let mut n = 0;
        for oct in 0..8u32 {
            if mask & (1 << oct) == 0 {
                continue;
            }
            let c = [0, 1, 2].map(|i| 2 * coord[i] + ((oct >> i) & 1));
            let lo = DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * size;
            let Some(d2) = meets(lo, size, best) else { continue };
            // A voxel, or a node no wider than the cone there: its distance bounds every
            // voxel inside it.
            if child_level >= leaf_level || size * size <= small * d2 {
                best = d2;
                continue;
            }
            kids[n] = (d2, oct, c);
            n += 1;
        }
        // Farthest pushed first, so the nearest is taken next.
        kids[..n].sort_unstable_by(|a, b| b.0.total_cmp(&a.0));
        for &(d2, oct, c) in &kids[..n] {
            stack.push((svo.child_node(node as usize, oct) as u32, child_level, c, d2));
        }
    }
    best.is_finite().then(|| best.sqrt())
}
