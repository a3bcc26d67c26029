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
use crate::svo::{Svo, MAX_DEPTH};
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

/// Below this many pixels per instance on average (the rectangles bounding their spheres'
/// projections), a frame that traces every pixel does better with per-pixel sphere lists
/// than with beams, however few the instances: each 8×8 tile's packet then meets several
/// instances a few pixels wide. One car of the instance sweep covers ~480 (beams faster,
/// 0.53 against 0.63 ms), two ~170 (lists faster, 0.34 against 0.46 ms), a ground plane or a
/// few large parts thousands (docs/benchmarks.md, step 81).
pub const MIN_MEAN_AREA: f64 = 400.0;

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

    /// [`TileRays::new`] from the camera's [`Camera::screen_slopes`] (`columns`, `rows`): the
    /// same rays without the divisions, for a frame that forms many tiles' rays (a mostly
    /// kept frame's tests of its tiles: docs/benchmarks.md, step 149).
    ///
    /// # Panics
    /// When the tile reaches past `columns` or `rows`.
    pub fn from_slopes(basis: &Basis, columns: &[f64], rows: &[f64], x0: u32, y0: u32, x1: u32, y1: u32) -> Self {
        let (a, b) = (x1.max(x0 + 1) as usize - 1, y1.max(y0 + 1) as usize - 1);
        let (x0, y0) = (x0 as usize, y0 as usize);
        TileRays {
            corners: [
                basis.dir(columns[x0], rows[y0]),
                basis.dir(columns[a], rows[y0]),
                basis.dir(columns[x0], rows[b]),
                basis.dir(columns[a], rows[b]),
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
        self.meets_ball_with(centre, radius, radius / self.sin)
    }

    /// [`Self::meets_ball`] with `radius / sin` formed by the caller (once for many balls of
    /// one radius).
    #[inline]
    fn meets_ball_with(&self, centre: DVec3, radius: f64, radius_over_sin: f64) -> bool {
        let back = self.apex - self.axis * radius_over_sin;
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

/// The pyramid of a tile's rays from the camera-relative origin as four planes through it
/// (inward normals), with the tile's cone for the instances' spheres: what settles a crowd's
/// empty tiles through the instance BVH ([`meets_any`]).
pub struct TilePyramid {
    normals: [DVec3; 4],
    cone: TileCone,
}

/// Relative slack of the pyramid's box test: a box is outside only when its nearest corner
/// lies this fraction of its distance beyond a side plane, far above the rounding of the
/// pixels' own directions (2⁻⁵² relative) and of the planes.
const PYRAMID_SLACK: f64 = 1e-7;

/// The most BVH nodes [`meets_any`] visits for one tile before it stops and lets the tile's
/// rays search as usual (a tile deep inside a crowd meets a leaf within a few nodes, a tile
/// beside it misses at the root).
const PYRAMID_NODES: usize = 48;

impl TilePyramid {
    /// The pyramid of `tile`'s rays; None when its corners do not span one (a degenerate
    /// camera), and then nothing is settled.
    pub fn new(tile: &TileRays) -> Option<TilePyramid> {
        // Around the rectangle: (x0, y0) → (x1, y0) → (x1, y1) → (x0, y1).
        let [a, b, c, d] = tile.corners;
        let ring = [a, b, d, c];
        let inside = a + b + c + d;
        let mut normals = [DVec3::ZERO; 4];
        for k in 0..4 {
            let n = ring[k].cross(ring[(k + 1) % 4]);
            let n = if n.dot(inside) < 0.0 { -n } else { n };
            let n = n.normalize_or_zero();
            // Every corner ray must lie on the plane's inner side (a convex, pointed pyramid).
            if n == DVec3::ZERO || !n.is_finite() || ring.iter().any(|r| n.dot(*r) < -1e-9) {
                return None;
            }
            normals[k] = n;
        }
        Some(TilePyramid { normals, cone: TileCone::new(tile) })
    }

    /// Whether some ray of the tile may enter the box: false only when the box lies wholly
    /// beyond one side plane, by more than [`PYRAMID_SLACK`] of its distance.
    fn may_meet_box(&self, lo: DVec3, hi: DVec3) -> bool {
        let far = lo.abs().max(hi.abs()).max_element();
        self.normals.iter().all(|n| {
            // The corner farthest along the normal.
            let p = DVec3::select(n.cmpge(DVec3::ZERO), hi, lo);
            n.dot(p) >= -PYRAMID_SLACK * 3.0 * far
        })
    }
}

/// Whether some ray of the tile may cross some instance's sphere, found by walking the
/// instance BVH with the tile's pyramid (its boxes) and cone (the spheres): false only when
/// none can, so every ray of the tile misses every instance. Gives up (true) after
/// `PYRAMID_NODES` nodes.
pub fn meets_any(pyramid: &TilePyramid, bvh: &super::bvh::Bvh, prepared: &[Prepared]) -> bool {
    if bvh.nodes.is_empty() {
        return !prepared.is_empty();
    }
    bvh.any_item(
        PYRAMID_NODES,
        |lo, hi| pyramid.may_meet_box(lo, hi),
        |i| prepared.get(i as usize).is_none_or(|p| pyramid.cone.meets_ball(p.centre, p.radius)),
    )
    .unwrap_or(true)
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
    // The ball around a grown cube of side `size`: its half-diagonal, rounded up far beyond
    // f64's rounding of the cube's corners (a larger ball only lets the cone meet more, so the
    // start stays conservative); with `radius / sin` for the cone test, formed once per size.
    let ball = |size: f64| {
        let r = (size + 2.0 * GROW) * (0.5 * 3f64.sqrt()) * (1.0 + 1e-9);
        (r, r / cone.sin)
    };
    // The squared distance to the grown cube at `lo` if the cone meets it and it could beat
    // `best`.
    let meets = |lo: DVec3, size: f64, (r, r_sin): (f64, f64), best: f64| -> Option<f64> {
        let (glo, ghi) = (lo - grow, lo + DVec3::splat(size) + grow);
        let d2 = box_distance2(cone.apex, glo, ghi);
        if d2 >= best {
            return None;
        }
        let centre = (glo + ghi) * 0.5;
        cone.meets_ball_with(centre, r, r_sin).then_some(d2)
    };
    let root = meets(DVec3::ZERO, 1.0, ball(1.0), f64::INFINITY)?;
    if leaf_level == 0 {
        return Some(root.sqrt());
    }
    let mut best = f64::INFINITY;
    // Depth first, nearest child first; at most 8 entries per level are pending. On the stack
    // of this call, not the heap: one beam's descent is about a microsecond, and an
    // allocation per beam and instance was a measurable part of it.
    let mut stack =
        crate::uninit_stack::UninitStack::<(u32, u32, [u32; 3], f64), { 8 * MAX_DEPTH as usize + 1 }>::new();
    stack.push((0, 0, [0; 3], root));
    while let Some((node, level, coord, dist2)) = stack.pop() {
        if dist2 >= best {
            continue;
        }
        let mask = svo.masks[node as usize];
        let child_level = level + 1;
        let size = 1.0 / (1u64 << child_level) as f64;
        let child_ball = ball(size);
        let mut kids: [(f64, u32, [u32; 3]); 8] = [(0.0, 0, [0; 3]); 8];
        let mut n = 0;
        for oct in 0..8u32 {
            if mask & (1 << oct) == 0 {
                continue;
            }
            let c = [0, 1, 2].map(|i| 2 * coord[i] + ((oct >> i) & 1));
            let lo = DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * size;
            let Some(d2) = meets(lo, size, child_ball, best) else { continue };
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::bvh::{box_entry, Bvh};
    use crate::render::instances::{sphere_interval, ToUnit};
    use crate::rng::Rng;

    fn camera() -> Camera {
        Camera {
            eye: DVec3::new(0.5, 2.0, 9.0),
            target: DVec3::new(0.0, -0.5, 0.0),
            up: DVec3::Y,
            vfov_deg: 50.0,
            width: 70,
            height: 52,
        }
    }

    /// A tile's corner rays from the screen slopes are `TileRays::new`'s, bit for bit, for
    /// tiles of every size and place (clipped by the image's edges) and cameras of every
    /// field of view and aspect.
    #[test]
    fn tile_rays_from_slopes_are_the_cameras() {
        let mut rng = Rng::new(17);
        for round in 0..400 {
            let cam = Camera {
                vfov_deg: rng.range(5.0, 150.0) as f64,
                width: 1 + rng.below(300) as u32,
                height: 1 + rng.below(300) as u32,
                up: if round % 2 == 0 { DVec3::Y } else { DVec3::new(0.3, 1.0, -0.2) },
                ..camera()
            };
            let basis = cam.basis();
            let (columns, rows) = cam.screen_slopes(&basis);
            let (x0, y0) = (rng.below(cam.width as u64) as u32, rng.below(cam.height as u64) as u32);
            let x1 = (x0 + rng.below(12) as u32).min(cam.width);
            let y1 = (y0 + rng.below(12) as u32).min(cam.height);
            let want = TileRays::new(&cam, &basis, x0, y0, x1, y1).corners;
            let got = TileRays::from_slopes(&basis, &columns, &rows, x0, y0, x1, y1).corners;
            let bits = |c: [DVec3; 4]| c.map(|d| d.to_array().map(f64::to_bits));
            assert_eq!(bits(got), bits(want), "round {round}: {x0}..{x1} x {y0}..{y1}");
        }
    }

    /// Pixels x0..x1 × y0..y1 of every tile (edge tiles cut short).
    fn tiles(cam: &Camera) -> Vec<[u32; 4]> {
        let mut out = Vec::new();
        for y0 in (0..cam.height).step_by(TILE as usize) {
            for x0 in (0..cam.width).step_by(TILE as usize) {
                out.push([x0, y0, (x0 + TILE).min(cam.width), (y0 + TILE).min(cam.height)]);
            }
        }
        out
    }

    /// Spheres scattered in front of, around and behind the eye (camera-relative, as prepared
    /// instances are), some of them tiny, some grazing the screen's edges.
    fn spheres(cam: &Camera, n: usize, seed: u64) -> Vec<Prepared> {
        let mut rng = Rng::new(seed);
        (0..n)
            .map(|_| {
                let world =
                    DVec3::new(rng.range(-9.0, 9.0) as f64, rng.range(-1.5, 1.5) as f64, rng.range(-12.0, 12.0) as f64);
                let radius = if rng.below(4) == 0 { 1e-3 } else { rng.range(0.02, 0.4) as f64 };
                Prepared {
                    part: 0,
                    to_unit: ToUnit::Scale { offset: DVec3::ZERO, inv_size: 1.0 },
                    centre: world - cam.eye,
                    radius,
                    max_stretch: 1.0,
                }
            })
            .collect()
    }

    /// A tile the walk settles has no pixel ray that crosses any sphere (each ray tested
    /// against every sphere, as the renderer's own sphere test does), over scenes from a few
    /// spheres to many; and the walk does settle tiles (it is not always "may meet").
    #[test]
    fn settled_tiles_have_no_ray_that_crosses_a_sphere() {
        let cam = camera();
        let basis = cam.basis();
        let mut settled = 0;
        let mut total = 0;
        for (n, seed) in [(3, 1), (40, 2), (300, 3), (2000, 4)] {
            let prepared = spheres(&cam, n, seed);
            let bvh = Bvh::build(&prepared.iter().map(|p| (p.centre, p.radius)).collect::<Vec<_>>());
            for [x0, y0, x1, y1] in tiles(&cam) {
                let tile = TileRays::new(&cam, &basis, x0, y0, x1, y1);
                let Some(pyramid) = TilePyramid::new(&tile) else { continue };
                total += 1;
                if meets_any(&pyramid, &bvh, &prepared) {
                    continue;
                }
                settled += 1;
                for y in y0..y1 {
                    for x in x0..x1 {
                        let d = cam.ray_dir(&basis, x, y);
                        for (i, p) in prepared.iter().enumerate() {
                            let crosses =
                                sphere_interval(p.centre, p.radius, DVec3::ZERO, d).is_some_and(|(_, t1)| t1 >= 0.0);
                            assert!(
                                !crosses,
                                "{n} spheres: tile {x0},{y0} settled, but pixel {x},{y} crosses sphere {i}"
                            );
                        }
                    }
                }
            }
        }
        assert!(settled > total / 10, "only {settled} of {total} tiles settled");
    }

    /// The pyramid's box test never says "outside" for a box some pixel ray of the tile
    /// enters, boxes of every size and distance, flat ones and ones behind the eye included.
    #[test]
    fn the_pyramid_rules_out_no_box_a_ray_enters() {
        let cam = camera();
        let basis = cam.basis();
        let mut rng = Rng::new(7);
        let mut ruled_out = 0;
        for _ in 0..3000 {
            let centre =
                DVec3::new(rng.range(-6.0, 6.0) as f64, rng.range(-4.0, 4.0) as f64, rng.range(-14.0, 4.0) as f64);
            let half = DVec3::new(rng.range(0.0, 1.5) as f64, rng.range(0.0, 0.2) as f64, rng.range(0.0, 1.5) as f64);
            let (lo, hi) = (centre - half, centre + half);
            let [x0, y0, x1, y1] = tiles(&cam)[rng.below(tiles(&cam).len() as u64) as usize];
            let Some(pyramid) = TilePyramid::new(&TileRays::new(&cam, &basis, x0, y0, x1, y1)) else { continue };
            if pyramid.may_meet_box(lo, hi) {
                continue;
            }
            ruled_out += 1;
            for y in y0..y1 {
                for x in x0..x1 {
                    let d = cam.ray_dir(&basis, x, y);
                    let entry = box_entry(lo, hi, DVec3::ZERO, d.recip(), f64::INFINITY);
                    assert!(entry.is_none(), "box {lo}..{hi} ruled out for tile {x0},{y0}, entered by pixel {x},{y}");
                }
            }
        }
        assert!(ruled_out > 1000, "only {ruled_out} boxes ruled out");
    }
}
