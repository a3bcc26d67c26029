//! Voxel cone tracing over the level chain (CPU reference). A cone marches from one cell off
//! the surface, stepping half its current diameter, sampling the level whose cells match that
//! diameter (quadrilinear: trilinear within the two nearest levels, blended between them) and
//! accumulating front to back, `c += (1 − a)·s.rgb; a += (1 − a)·s.a` (DESIGN.md). The
//! samples overlap (each step is half a sample's size) and their opacity is used as it is, not
//! corrected for the overlap: with the correction a cone through a wall one cell thick kept
//! only 0.82 of its opacity (light leaks through walls), without it 0.97 or more.

use super::levels::{face_weights, Chain, FaceWeights};
use glam::{DVec3, Vec3, Vec4};

/// How indirect light is gathered.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConeSettings {
    /// Diffuse cones: one along the normal, the rest in a ring around it.
    pub diffuse_cones: u32,
    /// Full aperture of each diffuse cone, degrees.
    pub aperture_deg: f64,
    /// Longest distance a cone travels (world units).
    pub max_distance: f64,
    /// Glossy hits (specular reflectance ks > 0) trace a specular cone along the mirror
    /// direction; off, their specular ambient term stays the flat sky's (ks × sky).
    pub specular_cone: bool,
}

impl Default for ConeSettings {
    fn default() -> Self {
        ConeSettings { diffuse_cones: 6, aperture_deg: 60.0, max_distance: f64::INFINITY, specular_cone: true }
    }
}

/// Invalid cone settings.
#[derive(Debug, thiserror::Error)]
pub enum ConeError {
    /// No cones or absurdly many.
    #[error("diffuse cones must be 1…64, not {0}")]
    Cones(u32),
    /// Aperture not in (0°, 180°).
    #[error("cone aperture must lie strictly between 0° and 180°, not {0}°")]
    Aperture(f64),
    /// Distance not positive.
    #[error("cone distance must be positive, not {0}")]
    Distance(f64),
}

impl ConeSettings {
    /// Checks the knobs.
    pub fn validated(self) -> Result<Self, ConeError> {
        if !(1..=64).contains(&self.diffuse_cones) {
            return Err(ConeError::Cones(self.diffuse_cones));
        }
        if !(self.aperture_deg > 0.0 && self.aperture_deg < 180.0) {
            return Err(ConeError::Aperture(self.aperture_deg));
        }
        if !(self.max_distance > 0.0) {
            return Err(ConeError::Distance(self.max_distance));
        }
        Ok(self)
    }

    /// Unit directions and weights (summing to 1) of the diffuse cones about normal `n`:
    /// weights follow cos θ, as the Lambertian integrand does.
    pub fn directions(&self, n: DVec3) -> Vec<(DVec3, f64)> {
        let n = n.normalize_or(DVec3::Y);
        let ring = self.diffuse_cones - 1;
        if ring == 0 {
            return vec![(n, 1.0)];
        }
        let (t, b) = n.any_orthonormal_pair();
        // The ring sits one aperture away from the normal, capped short of the horizon.
        let tilt = self.aperture_deg.to_radians().min(80f64.to_radians());
        let mut dirs = vec![(n, 1.0)];
        for k in 0..ring {
            let phi = std::f64::consts::TAU * k as f64 / ring as f64;
            let d = n * tilt.cos() + (t * phi.cos() + b * phi.sin()) * tilt.sin();
            dirs.push((d, tilt.cos()));
        }
        let sum: f64 = dirs.iter().map(|d| d.1).sum();
        dirs.into_iter().map(|(d, w)| (d, w / sum)).collect()
    }
}

/// Trilinear sample of one level at world point `p` (cell centres hold the cell values;
/// outside the volume is empty).
pub fn sample_level<C: Chain + ?Sized>(levels: &C, level: usize, p: DVec3) -> Vec4 {
    levels.trilinear(level, p)
}

/// Quadrilinear sample: trilinear in the levels either side of the fractional `level`.
pub fn sample<C: Chain + ?Sized>(levels: &C, p: DVec3, level: f64) -> Vec4 {
    quadrilinear(levels, level, |l| sample_level(levels, l, p))
}

/// [`sample`] as a cone with the face weights `faces` sees it ([`Chain::trilinear_dir`]).
pub fn sample_dir<C: Chain + ?Sized>(levels: &C, p: DVec3, level: f64, faces: &FaceWeights) -> Vec4 {
    quadrilinear(levels, level, |l| levels.trilinear_dir(l, p, faces))
}

/// The blend of `at(l)` over the two levels either side of the fractional `level` (clamped to
/// the chain).
fn quadrilinear<C: Chain + ?Sized>(levels: &C, level: f64, at: impl Fn(usize) -> Vec4) -> Vec4 {
    let top = (levels.count() - 1) as f64;
    let l = level.clamp(0.0, top);
    let lo = l.floor() as usize;
    let hi = (lo + 1).min(levels.count() - 1);
    let f = (l - lo as f64) as f32;
    let a = at(lo);
    if f == 0.0 || hi == lo {
        return a;
    }
    a * (1.0 - f) + at(hi) * f
}

/// Cells of clearance a sample needs from the surface a cone starts on: voxelization puts a
/// surface's occupancy up to half a cell off it and split filtering spreads it one cell more,
/// and a trilinear sample reaches one cell further.
pub(crate) const CLEARANCE: f64 = 1.5;

/// Marches one cone from surface point `origin` with unit normal `normal` along unit `dir`,
/// full aperture `aperture` (radians); returns the gathered radiance and the accumulated
/// opacity.
///
/// The cone starts one finest cell off the surface (along the normal). Near the surface a
/// sample as wide as the cone would reach back into the cells that hold the surface itself,
/// and with coverage opacity a flat floor then occluded every cone leaving it (a floor under
/// an open sky measured 0.3 % open). So each sample's size is also limited by its height `h`
/// above the surface's tangent plane — at most (h − 1.5 cells) / 1.5, so the sample and its
/// trilinear footprint stay clear of the surface's own cells — and sampling begins where
/// that allows one finest cell. Steps are half the sample size actually used.
pub fn trace<C: Chain + ?Sized>(
    levels: &C,
    origin: DVec3,
    normal: DVec3,
    dir: DVec3,
    aperture: f64,
    max_distance: f64,
) -> Vec4 {
    march(levels, origin, normal, dir, aperture, max_distance, None)
}

/// A surface a cone ends on: the cone must not sample its cells (an emitter's own voxels
/// would shadow it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConeEnd {
    /// Distance along the cone to the surface.
    pub distance: f64,
    /// Cosine between the cone and the surface's normal (> 0): how fast the cone closes in on
    /// the surface's plane.
    pub cos: f64,
}

/// How much of a light seen as a disc of full angle `aperture` from surface point `origin`
/// (unit normal `normal`) along unit `dir` reaches it through the level chain's opacity: 1 −
/// the opacity a cone gathers on its way to `end` (cone-traced soft shadows). The march is
/// [`trace`]'s, clear of the surface it ends on as it is clear of the one it starts from, so
/// neither surface's own voxels shadow the light.
pub fn visibility<C: Chain + ?Sized>(
    levels: &C,
    origin: DVec3,
    normal: DVec3,
    dir: DVec3,
    aperture: f64,
    end: ConeEnd,
) -> f32 {
    1.0 - march(levels, origin, normal, dir, aperture, end.distance, Some(end)).w
}

/// [`trace`]'s march; with `target`, each sample also keeps clear of the surface the cone
/// ends on (its size at most the distance left to that plane, less 1.5 cells, over 1.5), and
/// the march ends where no one-cell sample is clear of it.
fn march<C: Chain + ?Sized>(
    levels: &C,
    origin: DVec3,
    normal: DVec3,
    dir: DVec3,
    aperture: f64,
    max_distance: f64,
    target: Option<ConeEnd>,
) -> Vec4 {
    let cell0 = levels.cell(0);
    let extent = cell0 * levels.res(0) as f64 * 1.75; // the volume's diagonal
    let end = max_distance.min(extent);
    let spread = 2.0 * (aperture * 0.5).tan();
    // The coarsest levels (the last two: 2³ and 1³ cells for a power-of-two volume) blur the
    // whole volume together and carry no direction: one wall anywhere made the single top cell
    // opaque and occluded every long cone. A cone wider than the coarsest level used goes on
    // sampling that level (narrower than the cone) until it leaves the volume; stopping there
    // instead let the sky into a closed room through every cone longer than a third of it.
    let max_level = levels.count().saturating_sub(3) as f64;
    let lift = cell0;
    let o = origin + normal * lift;
    let cos = dir.dot(normal).max(0.05);
    // The faces an anisotropic chain shows this cone: one direction, found once.
    let faces = face_weights(dir);
    let clear_size = |t: f64| (lift + t * cos - CLEARANCE * cell0) / CLEARANCE;
    // The largest sample clear of the target's plane at t (∞ without a target).
    let end_size = |t: f64| match target {
        Some(e) => ((e.distance - t) * e.cos.max(0.05) - CLEARANCE * cell0) / CLEARANCE,
        None => f64::INFINITY,
    };
    let (mut c, mut a) = (Vec3::ZERO, 0.0f32);
    // The first t at which a one-cell (level 0) sample is clear of the surface.
    let mut t = ((CLEARANCE * (cell0 + cell0) - lift) / cos).max(cell0);
    while t < end && a < 0.99 {
        let room = end_size(t);
        if room < cell0 {
            break;
        }
        let diameter = (spread * t).max(cell0);
        // Quadrilinear sampling blends in the next coarser level too, so that one must be
        // clear: whole levels only below the clearance limit.
        let clear_level = (clear_size(t).min(room) / cell0).max(1.0).log2().floor();
        let level = (diameter / cell0).log2().min(clear_level).min(max_level);
        let size = cell0 * level.exp2();
        let s = sample_dir(levels, o + dir * t, level, &faces);
        let sa = s.w.clamp(0.0, 1.0);
        if sa > 0.0 {
            c += (1.0 - a) * s.truncate() * (sa / s.w);
            a += (1.0 - a) * sa;
        }
        t += size * 0.5;
    }
    c.extend(a)
}

/// Indirect light at a surface point: (radiance arriving over the hemisphere, cosine-weighted
/// and normalized so that a uniform environment L gives L; the sky fills what the cones do not
/// see) and the ambient occlusion (the fraction of the weighted cones that reaches the sky).
pub fn gather<C: Chain + ?Sized>(levels: &C, p: DVec3, n: DVec3, sky: Vec3, s: &ConeSettings) -> (Vec3, f32) {
    let aperture = s.aperture_deg.to_radians();
    let n = n.normalize_or(DVec3::Y);
    let (mut light, mut open) = (Vec3::ZERO, 0.0f32);
    for (d, w) in s.directions(n) {
        let r = trace(levels, p, n, d, aperture, s.max_distance);
        let w = w as f32;
        light += (r.truncate() + sky * (1.0 - r.w)) * w;
        open += (1.0 - r.w) * w;
    }
    (light, open)
}
