//! What a frame's rays can reach: whether any primary ray of a camera, or any sun's shadow
//! ray from a point those rays can see, can meet a given sphere ([`Sight::reaches`]), or a
//! placed box, the boxes of its parts and a sphere ([`Sight::reaches_boxes`]). A crowd poses
//! only the cars whose bounds some ray can reach ([`super::car::SeenCars::pose`]); a car no
//! ray reaches in its old pose nor in its new one looks the same in the picture whether it is
//! posed or not.
//!
//! The test is conservative: it may say a bound is reached when no ray meets it (the car is
//! then posed for nothing), never the other way round. Spheres and boxes are padded by a
//! fraction of their size and of their distance, far beyond the rounding of the renderer's
//! f32 and f64 rays.

use super::camera::{PixelGrid, PixelRect};
use super::{Camera, Lights};
use crate::render::instances::{farthest_corner, stretch_bound};
use glam::{DAffine3, DVec3};

/// Relative padding of a tested sphere's radius.
const RADIUS_PAD: f64 = 1e-3;
/// Padding of a tested sphere's radius per unit of its distance from the eye (a ray's
/// direction is good to about 10⁻⁷ in f32).
const DISTANCE_PAD: f64 = 1e-6;
/// A sphere whose screen rectangle holds more pixels than this counts as reached without
/// testing them one by one (it is close to the eye; such spheres are few).
const MAX_TESTED_PIXELS: u64 = 64;

/// The rays of one frame, for [`Sight::reaches`].
#[derive(Clone, Debug, PartialEq)]
pub struct Sight {
    camera: Camera,
    basis: super::camera::Basis,
    /// Unit directions towards each sun whose shadow rays are cast.
    suns: Vec<DVec3>,
    /// Where every surface a primary ray can see lies (world).
    surfaces: (DVec3, DVec3),
    /// [`Camera::screen_x`] of each pixel column and [`Camera::screen_y`] of each row.
    columns: Vec<f64>,
    rows: Vec<f64>,
    /// Where spheres project among the pixels.
    grid: PixelGrid,
}

/// Why a frame's rays cannot be bounded by a [`Sight`] (every instance must then be posed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Unbounded {
    /// GI voxelizes every instance into its volume.
    Gi,
    /// Point or spot lights, or sampled emitters, cast shadow rays that are not followed.
    LocalLights,
    /// The renderer draws voxels as splats, not rays.
    Splats,
    /// The camera is not valid.
    Camera,
    /// The box of visible surfaces is not finite.
    Surfaces,
}

/// What a frame casts, as [`Sight::new`] needs to know it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameRays {
    /// Shadow rays are traced (the plan's shadow switch).
    pub shadows: bool,
    /// GI runs.
    pub gi: bool,
    /// The frame is ray traced (not splatted).
    pub traced: bool,
    /// Some part has emissive triangles.
    pub emitters: bool,
}

impl FrameRays {
    /// What a frame of `scene` with these switches casts: shadow rays when they are on,
    /// GI when `gi`, rays unless `opts` asks for splats.
    pub fn of(
        scene: &super::Scene,
        features: &crate::render::Features,
        gi: bool,
        opts: &crate::render::RenderOptions,
    ) -> FrameRays {
        FrameRays {
            shadows: features.shadows,
            gi,
            traced: opts.renderer == crate::render::Renderer::Trace,
            emitters: scene.parts.iter().any(|p| !p.emitters.is_empty()),
        }
    }
}

impl Sight {
    /// The rays of a frame of `camera` under `lights`, when the frame casts only primary
    /// rays and (with `rays.shadows`) the suns' shadow rays; `surfaces` is a box holding
    /// every surface those primary rays can see. Otherwise why not.
    pub fn new(
        camera: &Camera,
        lights: &Lights,
        rays: FrameRays,
        surfaces: (DVec3, DVec3),
    ) -> Result<Sight, Unbounded> {
        if rays.gi {
            return Err(Unbounded::Gi);
        }
        if !rays.traced {
            return Err(Unbounded::Splats);
        }
        camera.validate().map_err(|_| Unbounded::Camera)?;
        if !(surfaces.0.is_finite() && surfaces.1.is_finite()) {
            return Err(Unbounded::Surfaces);
        }
        let mut suns = Vec::new();
        if rays.shadows {
            let local = lights.points.iter().any(|p| p.intensity.max_element() > 0.0)
                || lights.spots.iter().any(|s| s.intensity.max_element() > 0.0)
                || (lights.emitter_sampling() > 0 && rays.emitters);
            if local {
                return Err(Unbounded::LocalLights);
            }
            for s in lights.sun.iter().chain(&lights.suns) {
                let d = s.to_sun.as_dvec3();
                if s.irradiance.max_element() > 0.0 && d.length() > 0.0 {
                    suns.push(d.normalize());
                }
            }
        }
        let basis = camera.basis();
        let (columns, rows) = camera.screen_slopes(&basis);
        let grid = PixelGrid::new(camera, &basis);
        Ok(Sight { camera: *camera, basis, suns, surfaces, columns, rows, grid })
    }

    /// Whether some ray of the frame may meet the sphere (world `centre`, `radius`): a
    /// primary ray, or a sun's shadow ray from a point inside the visible surfaces' box.
    pub fn reaches(&self, centre: DVec3, radius: f64) -> bool {
        let eye = self.camera.eye;
        let c = centre - eye;
        let r = radius + padding(radius, c);
        if !(c.is_finite() && r.is_finite()) {
            return true;
        }
        self.primary_meets_capsule(c, c, r) || self.sun_reaches(c, r)
    }

    /// Whether some ray of the frame may meet what lies in the box `outline` (`(lo, hi)`)
    /// placed by `world` (an invertible affine map; a car body's world transform), in one of
    /// the boxes `parts` too when there are any (the car's parts; each taken within the
    /// outline), and within `radius` of `world`'s origin: a primary ray, tested against the
    /// boxes themselves (grown by the padding [`Sight::reaches`] gives the outline's radius),
    /// or a sun's shadow ray, tested against the sphere (as [`Sight::reaches`]). The boxes
    /// are the tighter outline on screen; the sphere, swept towards the sun, the simpler
    /// shadow.
    pub fn reaches_boxes(
        &self,
        world: &DAffine3,
        outline: (DVec3, DVec3),
        parts: &[(DVec3, DVec3)],
        radius: f64,
    ) -> bool {
        let Some((c, corner, pad)) = self.box_sphere(world, outline) else { return true };
        if self.primary_meets_boxes(world, outline, parts, c, corner + pad, pad) {
            return true;
        }
        let o = world.translation - self.camera.eye;
        let r = radius + padding(radius, o);
        !(o.is_finite() && r.is_finite()) || self.sun_reaches(o, r)
    }

    /// [`Sight::reaches_boxes`], with room: None when some ray of the frame may meet what
    /// lies in the outline and (with `parts`) in a part; else a world distance s ≤ `cap` such
    /// that with each of its points moved by less than s it is still met by no pixel's
    /// primary ray (a crowd's car keeps clear of the rays for as long as its motion takes to
    /// cover s). Suns' shadow rays give no room: what no ray reaches then has s = 0.
    pub fn boxes_slack(
        &self,
        world: &DAffine3,
        outline: (DVec3, DVec3),
        parts: &[(DVec3, DVec3)],
        radius: f64,
        cap: f64,
    ) -> Option<f64> {
        if !self.suns.is_empty() {
            return (!self.reaches_boxes(world, outline, parts, radius)).then_some(0.0);
        }
        let cap = if cap.is_finite() { cap.max(0.0) } else { 0.0 };
        let (c, corner, pad) = self.box_sphere(world, outline)?;
        // Pixels outside this rectangle: their rays pass farther than the padding and `cap`
        // from every point of the outline.
        let rect = self.grid.near(&[c], corner + pad + cap);
        let (x0, y0, x1, y1) = match rect {
            PixelRect::Empty => return Some(cap),
            PixelRect::Pixels { x0, y0, x1, y1 } if rect.area(&self.camera) <= MAX_TESTED_PIXELS => (x0, y0, x1, y1),
            // Close to the eye: the boxes themselves, without room.
            _ => return (!self.primary_meets_boxes(world, outline, parts, c, corner + pad, pad)).then_some(0.0),
        };
        let f = self.box_frame(world)?;
        let grown = f.grown(outline, outline, pad);
        // Growth that gives the whole cap as room below (rounding aside): a ray that needs
        // more than this gives none less, so its parts are not looked at.
        let mut need = (cap + pad) * f.spectral / 0.99;
        for py in y0..=y1 {
            let sy = self.rows[py as usize];
            for px in x0..=x1 {
                let ray = f.ray(self.columns[px as usize], sy);
                let mut g = growth_to_meet(f.eye, ray, grown.0, grown.1);
                // A part inside the outline must grow at least as far as the outline: only a
                // ray nearer the outline than the nearest so far can bring a part nearer.
                if !parts.is_empty() && !(g >= need) {
                    g = parts.iter().fold(f64::INFINITY, |m, &b| {
                        let (lo, hi) = f.grown(b, outline, pad);
                        m.min(growth_to_meet(f.eye, ray, lo, hi))
                    });
                }
                if !(g > 0.0) {
                    return None;
                }
                need = need.min(g);
            }
        }
        // A world distance s is at most s·‖inverse‖ in the box's frame; a hundredth and the
        // padding again are left for the rounding of it all and of the moved box's padding.
        let room = need / f.spectral * 0.99 - pad;
        Some(if room.is_finite() { room.clamp(0.0, cap) } else { 0.0 })
    }

    /// Whether a sun's shadow ray from a point inside the visible surfaces' box may meet the
    /// sphere about `c` (camera-relative) of radius `r` (padded).
    fn sun_reaches(&self, c: DVec3, r: f64) -> bool {
        // A shadow ray from p towards the sun meets the sphere when p lies in the sphere swept
        // away from the sun; only the stretch of that sweep whose centre lies inside the
        // surfaces' box grown by r can hold a visible p.
        let eye = self.camera.eye;
        let (lo, hi) = (self.surfaces.0 - eye - DVec3::splat(r), self.surfaces.1 - eye + DVec3::splat(r));
        self.suns.iter().any(|&to_sun| match sweep_span(c, -to_sun, lo, hi) {
            Some((s0, s1)) => self.primary_meets_capsule(c - to_sun * s0, c - to_sun * s1, r),
            None => false,
        })
    }

    /// Whether a pixel's primary ray meets the box `outline` placed by `world` and (with
    /// `parts`) one of `parts` within it, all grown by the world length `pad`: the pixels
    /// inside the rectangle of the outline's bounding sphere (about `c`, camera-relative,
    /// radius `r`, padded), each ray taken into the boxes' frame and tested against their
    /// slabs.
    fn primary_meets_boxes(
        &self,
        world: &DAffine3,
        outline: (DVec3, DVec3),
        parts: &[(DVec3, DVec3)],
        c: DVec3,
        r: f64,
        pad: f64,
    ) -> bool {
        let rect = self.grid.near(&[c], r);
        let PixelRect::Pixels { x0, y0, x1, y1 } = rect else {
            return rect == PixelRect::Unbounded;
        };
        if rect.area(&self.camera) > MAX_TESTED_PIXELS {
            return true;
        }
        // Inverted only here: most of a crowd's outlines hold no pixel centre.
        let Some(f) = self.box_frame(world) else { return true };
        let (lo, hi) = f.grown(outline, outline, pad);
        (y0..=y1).any(|py| {
            let sy = self.rows[py as usize];
            (x0..=x1).any(|px| {
                let ray = f.ray(self.columns[px as usize], sy);
                ray_meets_box(f.eye, ray, lo, hi)
                    && (parts.is_empty()
                        || parts.iter().any(|&b| {
                            let (lo, hi) = f.grown(b, outline, pad);
                            ray_meets_box(f.eye, ray, lo, hi)
                        }))
            })
        })
    }

    /// The box's own bounding sphere, as the renderer bounds an instance's box (its
    /// rectangle holds the pixels whose rays may meet the box): the camera-relative centre,
    /// the radius to the farthest corner and the padding for it. None when not finite.
    fn box_sphere(&self, world: &DAffine3, (lo, hi): (DVec3, DVec3)) -> Option<(DVec3, f64, f64)> {
        let corner = farthest_corner(&world.matrix3, (hi - lo).abs() * 0.5);
        let c = world.transform_point3((lo + hi) * 0.5) - self.camera.eye;
        let pad = padding(corner, c);
        (c.is_finite() && pad.is_finite()).then_some((c, corner, pad))
    }

    /// The frame of boxes placed by `world`, for pixel rays ([`BoxFrame`]). None when
    /// `world`'s inverse is not finite.
    fn box_frame(&self, world: &DAffine3) -> Option<BoxFrame> {
        let inverse = world.inverse();
        if !inverse.is_finite() {
            return None;
        }
        let (im, b) = (inverse.matrix3, &self.basis);
        Some(BoxFrame {
            eye: inverse.transform_point3(self.camera.eye),
            right: im * b.right,
            up: im * b.up,
            forward: im * b.forward,
            stretch: (im.x_axis.length_squared() + im.y_axis.length_squared() + im.z_axis.length_squared()).sqrt(),
            spectral: stretch_bound(&im),
        })
    }

    /// Whether a pixel's primary ray (from the eye, camera-relative) meets the capsule of
    /// radius `r` around the segment a–b.
    fn primary_meets_capsule(&self, a: DVec3, b: DVec3, r: f64) -> bool {
        let (cam, bs) = (&self.camera, &self.basis);
        let ends = if a == b { 1 } else { 2 };
        let rect = self.grid.near(&[a, b][..ends], r);
        let PixelRect::Pixels { x0, y0, x1, y1 } = rect else {
            return rect == PixelRect::Unbounded;
        };
        if rect.area(cam) > MAX_TESTED_PIXELS {
            return true;
        }
        // In the camera's frame a pixel's ray runs along D = (screen_x, screen_y, 1); it
        // meets the sphere about p (in front of the eye) when p's distance from the line is at
        // most r: |p|²|D|² − (p·D)² ≤ r²|D|².
        let p = DVec3::new(a.dot(bs.right), a.dot(bs.up), a.dot(bs.forward));
        let reach = p.length_squared() - r * r;
        (y0..=y1).any(|py| {
            let sy = self.rows[py as usize];
            (x0..=x1).any(|px| {
                if a == b {
                    let d = DVec3::new(self.columns[px as usize], sy, 1.0);
                    let along = p.dot(d);
                    reach * d.length_squared() <= along * along
                } else {
                    ray_segment_distance(cam.ray_dir(bs, px, py), a, b) <= r
                }
            })
        })
    }
}

/// The frame of boxes placed by an affine map (a car body's), where pixel rays are tested
/// against them: the map's inverse applied to the eye and to the camera's axes once.
#[derive(Clone, Copy, Debug)]
struct BoxFrame {
    /// The eye.
    eye: DVec3,
    /// The camera's right, up and forward axes.
    right: DVec3,
    up: DVec3,
    forward: DVec3,
    /// A bound on how much the inverse stretches a length (its columns' Frobenius norm): a
    /// box grown by a world length l grows by at most l times this.
    stretch: f64,
    /// [`stretch_bound`] of the inverse (tighter than `stretch`).
    spectral: f64,
}

impl BoxFrame {
    /// The box `b` taken within `outline` and grown by the world length `pad`.
    fn grown(&self, b: (DVec3, DVec3), outline: (DVec3, DVec3), pad: f64) -> (DVec3, DVec3) {
        let grow = DVec3::splat(pad * self.stretch);
        (b.0.max(outline.0) - grow, b.1.min(outline.1) + grow)
    }

    /// A pixel's primary ray, given its screen slopes (x, y): unnormalized, as whether a ray
    /// meets a box and how far the box must grow to meet it do not depend on its length.
    fn ray(&self, x: f64, y: f64) -> DVec3 {
        self.forward + self.up * y + self.right * x
    }
}

/// How much a bound of size `size` (a radius) at camera-relative `c` is grown: a fraction of
/// its size and of its distance, far beyond the rounding of the renderer's rays.
fn padding(size: f64, c: DVec3) -> f64 {
    size * RADIUS_PAD + c.length() * DISTANCE_PAD + 1e-9
}

/// Whether the ray `o + t·d`, t ≥ 0, meets the box `lo..hi` (slabs; a zero component tests
/// the position). Anything not finite counts as a meeting.
fn ray_meets_box(o: DVec3, d: DVec3, lo: DVec3, hi: DVec3) -> bool {
    // (An unbounded box would give an unbounded span, which `sweep_span` reports as none.)
    !(o.is_finite() && d.is_finite() && lo.is_finite() && hi.is_finite()) || sweep_span(o, d, lo, hi).is_some()
}

/// How far the box `lo..hi` must grow on every side (each face moved out by g) before the
/// ray `o + t·d`, t ≥ 0, meets it: at most 0 when the ray meets it already. Grown by g, slab
/// k holds the ray over [near_k − g/|d_k|, far_k + g/|d_k|], and the ray meets the box when
/// every slab's entry precedes every slab's exit and no exit is behind the origin; each
/// such pair of bounds gives the g it needs. Anything not finite counts as a meeting.
fn growth_to_meet(o: DVec3, d: DVec3, lo: DVec3, hi: DVec3) -> f64 {
    // (`f64::max` would pass over a NaN from a position that is not finite.)
    if !(o.is_finite() && d.is_finite() && lo.is_finite() && hi.is_finite()) {
        return 0.0;
    }
    let mut need = f64::NEG_INFINITY;
    let mut slabs = [(0.0, 0.0, 0.0); 3];
    let mut moving = 0;
    for k in 0..3 {
        if d[k] == 0.0 {
            // The ray stays at o[k]: the slab must grow to hold it.
            need = need.max(lo[k] - o[k]).max(o[k] - hi[k]);
            continue;
        }
        // One division per slab and one per pair of slabs (a crowd tests thousands of cars a
        // frame, each against a few pixels): the products round within a few units in the
        // last place of the quotients, far inside the hundredth the caller leaves.
        let per = 1.0 / d[k];
        let (a, b) = ((lo[k] - o[k]) * per, (hi[k] - o[k]) * per);
        let (near, far, per) = (a.min(b), a.max(b), per.abs());
        if !(near.is_finite() && far.is_finite() && per.is_finite()) {
            return 0.0;
        }
        // The exit must not be behind the origin: far + g·per ≥ 0.
        need = need.max(-far * d[k].abs());
        slabs[moving] = (near, far, per);
        moving += 1;
    }
    for i in 0..moving {
        for j in i + 1..moving {
            let ((ni, fi, pi), (nj, fj, pj)) = (slabs[i], slabs[j]);
            let inv = 1.0 / (pi + pj);
            need = need.max((ni - fj) * inv).max((nj - fi) * inv);
        }
    }
    if need.is_finite() {
        need
    } else {
        0.0
    }
}

/// The stretch [s0, s1] (s ≥ 0) of the ray `c + s·dir` inside the box [lo, hi]; None when
/// the ray misses it. (The sphere's centre itself may lie outside: an occluder above the
/// visible surfaces still shadows them.)
fn sweep_span(c: DVec3, dir: DVec3, lo: DVec3, hi: DVec3) -> Option<(f64, f64)> {
    let (mut s0, mut s1) = (0.0f64, f64::INFINITY);
    for k in 0..3 {
        if dir[k] == 0.0 {
            if c[k] < lo[k] || c[k] > hi[k] {
                return None;
            }
            continue;
        }
        let (a, b) = ((lo[k] - c[k]) / dir[k], (hi[k] - c[k]) / dir[k]);
        s0 = s0.max(a.min(b));
        s1 = s1.min(a.max(b));
    }
    (s0 <= s1 && s1.is_finite()).then_some((s0, s1))
}

/// The distance between the ray from the origin along unit `d` (t ≥ 0) and the segment a–b.
fn ray_segment_distance(d: DVec3, a: DVec3, b: DVec3) -> f64 {
    // Minimize |t d − (a + u (b − a))| over t ≥ 0, u ∈ [0, 1]: the distance is convex in
    // (t, u), so the minimum is the unconstrained one or lies on an edge of the domain.
    let e = b - a;
    let point_ray = |p: DVec3| (p - d * p.dot(d).max(0.0)).length();
    let ee = e.dot(e);
    // Edge t = 0: the origin against the segment.
    let u0 = if ee > 0.0 { (-a.dot(e) / ee).clamp(0.0, 1.0) } else { 0.0 };
    let mut best = (a + e * u0).length().min(point_ray(a)).min(point_ray(b));
    let de = d.dot(e);
    let den = ee - de * de;
    if den > ee * 1e-12 {
        // Interior: the lines' closest points.
        let (da, ea) = (d.dot(a), e.dot(a));
        let u = (de * da - ea) / den;
        let t = da + u * de;
        if (0.0..=1.0).contains(&u) && t >= 0.0 {
            best = best.min((d * t - (a + e * u)).length());
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::instances::sphere_interval;
    use crate::rng::Rng;
    use crate::scene::instances::box_corners;
    use crate::scene::Sun;
    use glam::Vec3;

    fn camera(eye: DVec3, width: u32, height: u32) -> Camera {
        Camera { eye, target: DVec3::new(0.0, 0.0, 0.0), up: DVec3::Y, vfov_deg: 40.0, width, height }
    }

    fn sun_lights(to_sun: Vec3) -> Lights {
        Lights { sun: Some(Sun { to_sun, irradiance: Vec3::ONE }), ..Lights::default() }
    }

    const PRIMARY: FrameRays = FrameRays { shadows: false, gi: false, traced: true, emitters: false };

    /// Every sphere some pixel ray meets (brute force over all pixels) is reached, for
    /// spheres from sub-pixel to screen-filling, in front of the eye, beside and behind it.
    #[test]
    fn every_sphere_a_pixel_ray_meets_is_reached() {
        let mut rng = Rng::new(5);
        let (w, h) = (40, 24);
        let cam = camera(DVec3::new(3.0, 4.0, -20.0), w, h);
        let box_ = (DVec3::splat(-30.0), DVec3::splat(30.0));
        let sight = Sight::new(&cam, &Lights::default(), PRIMARY, box_).unwrap();
        let b = cam.basis();
        let (mut met, mut spared) = (0, 0);
        for k in 0..4000 {
            let c =
                DVec3::new(rng.range(-25.0, 25.0) as f64, rng.range(-25.0, 25.0) as f64, rng.range(-40.0, 30.0) as f64);
            let r = if k % 2 == 0 { 0.02 + rng.f64() * 0.3 } else { rng.f64() * 4.0 };
            let meets = (0..h)
                .any(|y| (0..w).any(|x| sphere_interval(c - cam.eye, r, DVec3::ZERO, cam.ray_dir(&b, x, y)).is_some()));
            let reached = sight.reaches(c, r);
            assert!(reached || !meets, "sphere {c} r {r}: a pixel ray meets it but it is not reached");
            met += meets as u32;
            spared += (!reached) as u32;
        }
        // Both kinds occur, and most spheres no ray meets are spared.
        assert!(met > 400 && spared > 1500, "met {met}, spared {spared}");
    }

    /// The box tests' 40×24 view and its primary rays' sight.
    fn box_view() -> (Camera, Sight) {
        let cam = camera(DVec3::new(3.0, 4.0, -20.0), 40, 24);
        let sight = Sight::new(&cam, &Lights::default(), PRIMARY, (DVec3::splat(-30.0), DVec3::splat(30.0))).unwrap();
        (cam, sight)
    }

    /// Brute force: whether some pixel's primary ray meets the box `lo..hi` placed by `world`.
    fn met_by_a_pixel_ray(cam: &Camera, world: &DAffine3, lo: DVec3, hi: DVec3) -> bool {
        let (b, inverse) = (cam.basis(), world.inverse());
        let o = inverse.transform_point3(cam.eye);
        (0..cam.height)
            .any(|y| (0..cam.width).any(|x| ray_meets_box(o, inverse.transform_vector3(cam.ray_dir(&b, x, y)), lo, hi)))
    }

    /// Every box (turned, stretched, placed anywhere about the view) that some pixel's ray
    /// meets is reached, the box tested exactly by the ray's slabs; most that none meets are
    /// spared, also where their bounding sphere's rectangle holds pixels.
    #[test]
    fn every_box_a_pixel_ray_meets_is_reached() {
        let mut rng = Rng::new(21);
        let (cam, sight) = box_view();
        let (mut met, mut spared, mut by_box) = (0, 0, 0);
        for k in 0..3000 {
            let q = glam::DQuat::from_euler(glam::EulerRot::XYZ, rng.f64() * 6.3, rng.f64() * 6.3, rng.f64() * 6.3);
            let scale = DVec3::new(0.5 + rng.f64(), 0.5 + rng.f64(), 0.5 + rng.f64());
            let at = DVec3::new(rng.f64() * 50.0 - 25.0, rng.f64() * 50.0 - 25.0, rng.f64() * 70.0 - 40.0);
            let world = DAffine3::from_scale_rotation_translation(scale, q, at);
            let size = if k % 2 == 0 { 0.05 + rng.f64() * 0.3 } else { rng.f64() * 3.0 };
            let (lo, hi) = (-DVec3::new(size, 0.2 * size, 0.5 * size), DVec3::new(size, 0.3 * size, 0.4 * size));
            let meets = met_by_a_pixel_ray(&cam, &world, lo, hi);
            // Without a sun the sphere's radius plays no part.
            let reached = sight.reaches_boxes(&world, (lo, hi), &[], 0.0);
            assert!(reached || !meets, "box {k} at {at}: a pixel ray meets it but it is not reached");
            met += meets as u32;
            spared += (!reached) as u32;
            // Spared by the box itself: its bounding sphere is reached.
            let sphere = sight
                .reaches(world.transform_point3((lo + hi) * 0.5), farthest_corner(&world.matrix3, (hi - lo) * 0.5));
            by_box += (!reached && sphere) as u32;
        }
        assert!(met > 300 && spared > 1200 && by_box > 50, "met {met}, spared {spared}, by the box alone {by_box}");
    }

    /// A box's slack is room: the box turned about a point and moved so that none of its
    /// points travels as far as the slack is still met by no pixel's ray (brute force over
    /// all pixels, and `reaches_boxes`). It is not much more: grown by a little more than the
    /// slack, a turned box below the cap is reached. With a sun there is no room.
    #[test]
    fn a_box_moved_within_its_slack_stays_clear_of_the_rays() {
        let mut rng = Rng::new(33);
        let (cam, sight) = box_view();
        let met_by_a_ray = |world: &DAffine3, lo: DVec3, hi: DVec3| met_by_a_pixel_ray(&cam, world, lo, hi);
        let cap = 1.5;
        let (mut roomy, mut tight) = (0, 0);
        for k in 0..2500 {
            let yaw = rng.f64() * 6.3;
            let q = if k % 3 == 0 {
                glam::DQuat::from_euler(glam::EulerRot::XYZ, rng.f64() * 6.3, yaw, rng.f64() * 6.3)
            } else {
                glam::DQuat::from_rotation_y(yaw)
            };
            let scale =
                if k % 3 == 0 { DVec3::new(0.5 + rng.f64(), 0.5 + rng.f64(), 0.5 + rng.f64()) } else { DVec3::ONE };
            let at = DVec3::new(rng.f64() * 50.0 - 25.0, rng.f64() * 30.0 - 15.0, rng.f64() * 70.0 - 40.0);
            let world = DAffine3::from_scale_rotation_translation(scale, q, at);
            let size = 0.1 + rng.f64() * 2.0;
            let (lo, hi) = (-DVec3::new(size, 0.2 * size, 0.5 * size), DVec3::new(size, 0.3 * size, 0.4 * size));
            let slack = sight.boxes_slack(&world, (lo, hi), &[], 0.0, cap);
            assert_eq!(slack.is_none(), sight.reaches_boxes(&world, (lo, hi), &[], 0.0), "box {k}: slack {slack:?}");
            let Some(slack) = slack else { continue };
            assert!((0.0..=cap).contains(&slack), "box {k}: slack {slack}");
            if slack == 0.0 {
                continue;
            }
            roomy += 1;
            // Turned about its origin by up to half the slack at its farthest point, moved by
            // up to the other half.
            let far = box_corners(lo, hi).iter().map(|&p| world.transform_vector3(p).length()).fold(0.0, f64::max);
            let turn = glam::DQuat::from_axis_angle(rng.unit_vector().as_dvec3().normalize(), 0.49 * slack / far);
            let shift = rng.unit_vector().as_dvec3().normalize() * 0.49 * slack * rng.f64();
            let moved = DAffine3::from_translation(at + shift)
                * DAffine3::from_quat(turn)
                * DAffine3::from_translation(-at)
                * world;
            assert!(!met_by_a_ray(&moved, lo, hi), "box {k}: moved within its slack {slack}, a ray meets it");
            assert!(
                !sight.reaches_boxes(&moved, (lo, hi), &[], 0.0),
                "box {k}: moved within its slack {slack}, reached"
            );
            // Every face pushed out by the slack (in the box's frame, where a world length
            // shrinks by the scale) holds every such move: still met by no ray.
            let g = DVec3::splat(slack / scale.max_element());
            assert!(!met_by_a_ray(&world, lo - g, hi + g), "box {k}: grown by its slack {slack}, a ray meets it");
            if k % 3 != 0 && slack < 0.9 * cap {
                // Grown by a little more than the slack (and the paddings): reached.
                let pad = padding(size * 1.2, world.translation - cam.eye);
                let g = DVec3::splat(slack * 1.02 + 4.0 * pad);
                assert!(sight.reaches_boxes(&world, (lo - g, hi + g), &[], 0.0), "box {k}: slack {slack} is too small");
                tight += 1;
            }
        }
        assert!(roomy > 1000 && tight > 200, "{roomy} boxes with room, {tight} checked for tightness");
        // With a sun's shadow rays: no room.
        let sunny = Sight::new(
            &cam,
            &sun_lights(Vec3::new(0.3, 1.0, 0.2)),
            FrameRays { shadows: true, ..PRIMARY },
            (DVec3::splat(-30.0), DVec3::splat(30.0)),
        )
        .unwrap();
        let far_away = DAffine3::from_translation(DVec3::new(0.0, 0.0, -100.0));
        assert_eq!(sunny.boxes_slack(&far_away, (-DVec3::ONE, DVec3::ONE), &[], 1.8, cap), Some(0.0));
    }

    /// Parts (two to four boxes placed by one map, inside their outline, as a car's): every
    /// set some pixel's ray meets in one of its parts is reached (brute force), and many sets
    /// whose outline a ray meets are not; a set's room is about the least of its parts' own,
    /// and moved by it no part is met by a pixel's ray (brute force).
    #[test]
    fn parts_are_reached_and_have_room_as_their_boxes() {
        let mut rng = Rng::new(47);
        let (cam, sight) = box_view();
        let cap = 1.5;
        let (mut reached, mut clear, mut by_parts, mut close) = (0, 0, 0, 0);
        for k in 0..1500 {
            let q = glam::DQuat::from_rotation_y(rng.f64() * 6.3);
            let at = DVec3::new(rng.f64() * 50.0 - 25.0, rng.f64() * 30.0 - 15.0, rng.f64() * 70.0 - 40.0);
            let world = DAffine3::from_rotation_translation(q, at);
            let parts: Vec<(DVec3, DVec3)> = (0..2 + k % 3)
                .map(|_| {
                    let c = DVec3::new(rng.f64() * 6.0 - 3.0, rng.f64() * 2.0 - 1.0, rng.f64() * 3.0 - 1.5);
                    let e = DVec3::new(0.05 + rng.f64() * 0.6, 0.05 + rng.f64() * 0.4, 0.05 + rng.f64() * 0.4);
                    (c - e, c + e)
                })
                .collect();
            let outline =
                parts.iter().fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), &(a, b)| (lo.min(a), hi.max(b)));
            let met = parts.iter().any(|&(lo, hi)| met_by_a_pixel_ray(&cam, &world, lo, hi));
            let is_reached = sight.reaches_boxes(&world, outline, &parts, 0.0);
            assert!(is_reached || !met, "set {k}: a part is met by a pixel's ray, not reached");
            by_parts += (!is_reached && sight.reaches_boxes(&world, outline, &[], 0.0)) as u32;
            let slack = sight.boxes_slack(&world, outline, &parts, 0.0, cap);
            assert_eq!(slack.is_none(), is_reached, "set {k}: slack {slack:?}");
            let Some(slack) = slack else {
                reached += 1;
                continue;
            };
            clear += 1;
            // About the least of the parts' own (each padded as its outline is here).
            let least =
                parts.iter().map(|&b| sight.boxes_slack(&world, b, &[], 0.0, cap).unwrap_or(0.0)).fold(cap, f64::min);
            // (Less only close to the eye, where the outline's rectangle holds too many pixels
            // to give room.)
            let (c, corner, pad) = sight.box_sphere(&world, outline).unwrap();
            let near_eye = sight.grid.near(&[c], corner + pad + cap).area(&cam) > MAX_TESTED_PIXELS;
            assert!(
                slack <= least + 1e-9 && (slack >= least - 0.01 || near_eye),
                "set {k}: room {slack}, the parts' least {least}"
            );
            close += near_eye as u32;
            // Moved by up to the slack (less the rounding room): no part is met by a ray.
            let shift = rng.unit_vector().as_dvec3().normalize() * 0.98 * slack;
            let moved = DAffine3::from_translation(shift) * world;
            for &(lo, hi) in &parts {
                assert!(!met_by_a_pixel_ray(&cam, &moved, lo, hi), "set {k}: moved by its room {slack}, met");
            }
        }
        assert!(
            reached > 200 && clear > 500 && by_parts > 100 && close < clear / 4,
            "{reached} reached, {clear} clear ({by_parts} by the parts, {close} close to the eye)"
        );
    }

    /// With a sun, every sphere that shadows some visible point of a pixel ray (a point on
    /// the ray inside the surfaces' box whose ray towards the sun meets the sphere) is
    /// reached, though no primary ray meets it.
    #[test]
    fn every_sphere_that_shadows_a_visible_point_is_reached() {
        let mut rng = Rng::new(9);
        let (w, h) = (24, 16);
        let cam = camera(DVec3::new(6.0, 9.0, -24.0), w, h);
        let surfaces = (DVec3::new(-12.0, -1.0, -12.0), DVec3::new(12.0, 6.0, 12.0));
        let to_sun = Vec3::new(0.4, 0.8, 0.3).normalize();
        let lights = sun_lights(to_sun);
        let sight = Sight::new(&cam, &lights, FrameRays { shadows: true, ..PRIMARY }, surfaces).unwrap();
        let primary_only = Sight::new(&cam, &lights, PRIMARY, surfaces).unwrap();
        let b = cam.basis();
        let l = to_sun.as_dvec3();
        let (mut shadowing, mut only_by_shadow) = (0, 0);
        for _ in 0..1500 {
            let c =
                DVec3::new(rng.range(-11.0, 11.0) as f64, rng.range(-0.5, 12.0) as f64, rng.range(-11.0, 11.0) as f64);
            let r = 0.05 + rng.f64() * 0.6;
            // Points along each pixel's ray inside the box, every few centimetres.
            let shadows = (0..h).any(|y| {
                (0..w).any(|x| {
                    let d = cam.ray_dir(&b, x, y);
                    (0..2000).any(|k| {
                        let p = cam.eye + d * (k as f64 * 0.025);
                        let inside = p.cmpge(surfaces.0).all() && p.cmple(surfaces.1).all();
                        inside && sphere_interval(c, r, p, l).is_some()
                    })
                })
            });
            if shadows {
                shadowing += 1;
                assert!(sight.reaches(c, r), "sphere {c} r {r} shadows a visible point but is not reached");
                only_by_shadow += (!primary_only.reaches(c, r)) as u32;
            }
        }
        assert!(shadowing > 100 && only_by_shadow > 20, "{shadowing} shadowing, {only_by_shadow} only by shadow");
    }

    #[test]
    fn gi_local_lights_and_splats_are_unbounded() {
        let cam = camera(DVec3::new(0.0, 1.0, -5.0), 8, 8);
        let box_ = (DVec3::splat(-1.0), DVec3::splat(1.0));
        let mut lights = Lights::default();
        assert_eq!(Sight::new(&cam, &lights, FrameRays { gi: true, ..PRIMARY }, box_).err(), Some(Unbounded::Gi));
        assert_eq!(
            Sight::new(&cam, &lights, FrameRays { traced: false, ..PRIMARY }, box_).err(),
            Some(Unbounded::Splats)
        );
        lights.points.push(crate::scene::lights::PointLight { position: DVec3::ONE, intensity: Vec3::ONE });
        assert!(Sight::new(&cam, &lights, PRIMARY, box_).is_ok(), "no shadow rays: points do not matter");
        assert_eq!(
            Sight::new(&cam, &lights, FrameRays { shadows: true, ..PRIMARY }, box_).err(),
            Some(Unbounded::LocalLights)
        );
        let bad = (DVec3::splat(-1.0), DVec3::splat(f64::INFINITY));
        assert_eq!(Sight::new(&cam, &Lights::default(), PRIMARY, bad).err(), Some(Unbounded::Surfaces));
    }

    #[test]
    fn the_ray_segment_distance_matches_sampling() {
        let mut rng = Rng::new(3);
        for _ in 0..500 {
            let d = rng.unit_vector().as_dvec3().normalize();
            let a = DVec3::new(rng.range(-3.0, 3.0) as f64, rng.range(-3.0, 3.0) as f64, rng.range(-3.0, 3.0) as f64);
            let b =
                a + DVec3::new(rng.range(-3.0, 3.0) as f64, rng.range(-3.0, 3.0) as f64, rng.range(-3.0, 3.0) as f64);
            let got = ray_segment_distance(d, a, b);
            let mut sampled = f64::INFINITY;
            for i in 0..=400 {
                let p = a + (b - a) * (i as f64 / 400.0);
                sampled = sampled.min((p - d * p.dot(d).max(0.0)).length());
            }
            assert!(got <= sampled + 1e-12 && got >= sampled - 0.02, "{got} against {sampled}");
        }
    }
}
