//! The pinhole camera of DESIGN.md's interface: eye/target/up, full vertical field of view,
//! square pixels, pixel centres at half-integers, row 0 at the top. Positions are f64 so that
//! rays can be formed relative to the camera far from the origin.

use glam::{DVec3, Vec3};

/// Largest accepted image side.
pub const MAX_SIDE: u32 = 16384;
/// Largest accepted pixel count (a frame with its AOVs takes 32 bytes per pixel).
pub const MAX_PIXELS: u64 = 1 << 26;

/// A pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "json", serde(deny_unknown_fields))]
pub struct Camera {
    /// Eye position.
    pub eye: DVec3,
    /// Point looked at.
    pub target: DVec3,
    /// Up hint (need not be orthogonal to the view direction).
    pub up: DVec3,
    /// Full vertical field of view in degrees.
    pub vfov_deg: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

/// Why a camera is unusable.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CameraError {
    /// A field is NaN or infinite.
    #[error("camera {0} is not finite")]
    NonFinite(&'static str),
    /// Eye and target coincide.
    #[error("camera eye and target coincide")]
    NoDirection,
    /// Up is parallel to the view direction.
    #[error("camera up vector is zero or parallel to the view direction")]
    BadUp,
    /// Field of view outside (0, 180).
    #[error("vfov_deg {0} must lie strictly between 0 and 180")]
    Fov(f64),
    /// Image size zero or too large.
    #[error("image size {0}x{1} must be between 1 and {MAX_SIDE} per side and at most {MAX_PIXELS} pixels")]
    Size(u32, u32),
    /// Malformed JSON.
    #[error("camera JSON: {0}")]
    Json(String),
}

/// Orthonormal camera frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Basis {
    /// View direction.
    pub forward: DVec3,
    /// Image right.
    pub right: DVec3,
    /// Image up.
    pub up: DVec3,
    /// tan(vfov/2).
    pub tan_half: f64,
}

impl Basis {
    /// The unit direction `sx` right and `sy` up of the view axis per unit forward (see
    /// [`Camera::screen_x`]).
    #[inline]
    pub fn dir(&self, sx: f64, sy: f64) -> DVec3 {
        (self.forward + self.right * sx + self.up * sy).normalize()
    }
}

/// The pixels whose rays may pass near a point or segment: see [`PixelGrid::near`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelRect {
    /// No pixel centre's ray can pass that near.
    Empty,
    /// The shape reaches the eye's plane: its projection is unbounded (any pixel may).
    Unbounded,
    /// Only the rays of these pixels may (inclusive bounds).
    Pixels {
        /// First column.
        x0: u32,
        /// First row.
        y0: u32,
        /// Last column.
        x1: u32,
        /// Last row.
        y1: u32,
    },
}

impl PixelRect {
    /// How many pixels the rectangle holds (`Unbounded`: the whole image of `camera`).
    pub fn area(&self, camera: &Camera) -> u64 {
        match *self {
            PixelRect::Empty => 0,
            PixelRect::Unbounded => camera.width as u64 * camera.height as u64,
            PixelRect::Pixels { x0, y0, x1, y1 } => (x1 - x0 + 1) as u64 * (y1 - y0 + 1) as u64,
        }
    }
}

/// A camera's pixel centres as slopes from its view axis, for bounding where spheres project
/// ([`PixelGrid::near`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelGrid {
    basis: Basis,
    width: u32,
    height: u32,
    /// Pixels per unit of screen slope, across and down.
    per_x: f64,
    per_y: f64,
}

impl PixelGrid {
    /// The grid of `camera`'s pixels (`basis` is its [`Camera::basis`]).
    pub fn new(camera: &Camera, basis: &Basis) -> PixelGrid {
        let (w, h) = (camera.width as f64, camera.height as f64);
        PixelGrid {
            basis: *basis,
            width: camera.width,
            height: camera.height,
            per_x: 0.5 * w / (basis.tan_half * w / h),
            per_y: 0.5 * h / basis.tan_half,
        }
    }

    /// The rectangle of pixels whose centre's ray (from the eye) may pass within `r` of one of
    /// `ends` (camera-relative points; two ends: of every point of the segment between them):
    /// per end, the slopes X/Z of the sphere's bounding box, [x ± r] over [z ± r], mapped to
    /// the pixel centres as [`Camera::screen_x`] and [`Camera::screen_y`] place them (the
    /// segment's spheres project inside the two ends' rectangles' bounding rectangle). No
    /// roots or library calls: a crowd bounds tens of thousands of spheres a frame. Rounding
    /// is of order 10⁻¹⁵ of the slopes; callers pad `r` well beyond it and test the pixels
    /// inside one by one.
    #[inline]
    pub fn near(&self, ends: &[DVec3], r: f64) -> PixelRect {
        let b = &self.basis;
        let mut slopes = [f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY];
        for p in ends {
            let z = p.dot(b.forward);
            if !(z > r * (1.0 + 1e-9)) {
                // One sphere wholly behind the eye: no ray from it meets it at t ≥ 0. Else it
                // reaches the eye's plane, and its projection is unbounded.
                return if ends.len() == 1 && z < -r { PixelRect::Empty } else { PixelRect::Unbounded };
            }
            let (x, y) = (p.dot(b.right), p.dot(b.up));
            // One division for both reciprocals.
            let inv = 1.0 / ((z - r) * (z + r));
            let (near, far) = ((z + r) * inv, (z - r) * inv);
            for (a, lo, hi) in [(x, 0, 1), (y, 2, 3)] {
                slopes[lo] = slopes[lo].min((a - r) * if a - r < 0.0 { near } else { far });
                slopes[hi] = slopes[hi].max((a + r) * if a + r > 0.0 { near } else { far });
            }
        }
        let (w, h) = (self.width as f64, self.height as f64);
        // Columns whose centre's slope lies in [slopes0, slopes1]; rows the same, flipped.
        let x0 = ceil_within(slopes[0] * self.per_x + 0.5 * w - 0.5, w);
        let x1 = floor_within(slopes[1] * self.per_x + 0.5 * w - 0.5, w);
        let y0 = ceil_within(0.5 * h - slopes[3] * self.per_y - 0.5, h);
        let y1 = floor_within(0.5 * h - slopes[2] * self.per_y - 0.5, h);
        let (x0, y0) = (x0.max(0), y0.max(0));
        let (x1, y1) = (x1.min(self.width as i64 - 1), y1.min(self.height as i64 - 1));
        if x0 > x1 || y0 > y1 {
            return PixelRect::Empty;
        }
        PixelRect::Pixels { x0: x0 as u32, y0: y0 as u32, x1: x1 as u32, y1: y1 as u32 }
    }
}

/// ⌈v⌉ for v clamped to [−1, n], by truncation (a NaN gives 0, a column that exists): without
/// SSE4.1 `f64::ceil` is a library call, and a crowd's projection makes four per sphere.
#[inline]
fn ceil_within(v: f64, n: f64) -> i64 {
    let v = v.clamp(-1.0, n);
    let t = v as i64;
    if (t as f64) < v {
        t + 1
    } else {
        t
    }
}

/// ⌊v⌋ for v clamped to [−1, n], as [`ceil_within`].
#[inline]
fn floor_within(v: f64, n: f64) -> i64 {
    let v = v.clamp(-1.0, n);
    let t = v as i64;
    if (t as f64) > v {
        t - 1
    } else {
        t
    }
}

impl Camera {
    /// A camera looking at a bounding box from the front-left, three-quarters above, framed
    /// to fit it.
    pub fn framing(lo: Vec3, hi: Vec3, width: u32, height: u32) -> Camera {
        Self::framing_from(lo, hi, width, height, DVec3::new(0.95, 0.36, -0.9))
    }

    /// A camera looking at a bounding box from direction `from` (towards the eye), framed to
    /// fit it.
    pub fn framing_from(lo: Vec3, hi: Vec3, width: u32, height: u32, from: DVec3) -> Camera {
        // In f64: the box of a model at 10³⁸ units has an f32 diagonal of +∞, and one of
        // 10⁻⁸ units must not be framed as if it were a micrometre wide.
        let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
        let centre = (lo + hi) * 0.5;
        // A box of one point still gets a view (relative to where it lies, or of 10⁻³⁰).
        let radius = ((hi - lo).length() * 0.5).max(centre.length() * 1e-7).max(1e-30);
        let vfov_deg: f64 = 30.0;
        let aspect = width as f64 / height.max(1) as f64;
        let half = (vfov_deg.to_radians() * 0.5).tan() * aspect.min(1.0);
        let dist = radius / half.atan().sin() * 0.68;
        let dir = from.normalize();
        Camera { eye: centre + dir * dist, target: centre, up: DVec3::Y, vfov_deg, width, height }
    }

    /// Checks every field.
    pub fn validate(&self) -> Result<(), CameraError> {
        for (name, v) in [("eye", self.eye), ("target", self.target), ("up", self.up)] {
            if !v.is_finite() {
                return Err(CameraError::NonFinite(name));
            }
        }
        if !self.vfov_deg.is_finite() {
            return Err(CameraError::NonFinite("vfov_deg"));
        }
        if !(self.vfov_deg > 0.0 && self.vfov_deg < 180.0) {
            return Err(CameraError::Fov(self.vfov_deg));
        }
        let pixels = self.width as u64 * self.height as u64;
        if self.width == 0 || self.height == 0 || self.width > MAX_SIDE || self.height > MAX_SIDE || pixels > MAX_PIXELS
        {
            return Err(CameraError::Size(self.width, self.height));
        }
        let f = self.target - self.eye;
        if !(f.length() > 1e-12 * self.eye.length().max(1.0)) {
            return Err(CameraError::NoDirection);
        }
        if !(f.normalize().cross(self.up).length() > 1e-9) {
            return Err(CameraError::BadUp);
        }
        Ok(())
    }

    /// The camera frame (valid camera assumed).
    pub fn basis(&self) -> Basis {
        let forward = (self.target - self.eye).normalize();
        let right = forward.cross(self.up).normalize();
        let up = right.cross(forward);
        Basis { forward, right, up, tan_half: (self.vfov_deg.to_radians() * 0.5).tan() }
    }

    /// Unit direction of the ray through the centre of pixel (px, py).
    pub fn ray_dir(&self, b: &Basis, px: u32, py: u32) -> DVec3 {
        b.dir(self.screen_x(b, px), self.screen_y(b, py))
    }

    /// How far right of the view axis the rays of pixel column `px` go per unit forward:
    /// [`Self::ray_dir`] is `b.dir(screen_x(px), screen_y(py))`, so a loop over a block of
    /// pixels can form each column's and row's share once (three divisions fewer per ray).
    #[inline]
    pub fn screen_x(&self, b: &Basis, px: u32) -> f64 {
        let (w, h) = (self.width as f64, self.height as f64);
        (2.0 * (px as f64 + 0.5) / w - 1.0) * b.tan_half * w / h
    }

    /// [`Self::screen_x`] of every pixel column and [`Self::screen_y`] of every row: a pass
    /// over many pixels forms `ray_dir(b, x, y)` as `b.dir(columns[x], rows[y])`, the same
    /// value without the three divisions.
    pub fn screen_slopes(&self, b: &Basis) -> (Vec<f64>, Vec<f64>) {
        (
            (0..self.width).map(|px| self.screen_x(b, px)).collect(),
            (0..self.height).map(|py| self.screen_y(b, py)).collect(),
        )
    }

    /// How far above the view axis the rays of pixel row `py` go per unit forward (see
    /// [`Self::screen_x`]).
    #[inline]
    pub fn screen_y(&self, b: &Basis, py: u32) -> f64 {
        (1.0 - 2.0 * (py as f64 + 0.5) / self.height as f64) * b.tan_half
    }

    /// Parses the camera JSON of DESIGN.md and validates it.
    #[cfg(feature = "json")]
    pub fn from_json(text: &str) -> Result<Camera, CameraError> {
        let c: Camera = serde_json::from_str(text.strip_prefix('\u{feff}').unwrap_or(text))
            .map_err(|e| CameraError::Json(e.to_string()))?;
        c.validate()?;
        Ok(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_pixel_looks_forward_and_row_zero_is_top() {
        let c = Camera { eye: DVec3::ZERO, target: DVec3::Z, up: DVec3::Y, vfov_deg: 90.0, width: 3, height: 3 };
        let b = c.basis();
        assert!((c.ray_dir(&b, 1, 1) - DVec3::Z).length() < 1e-12);
        assert!(c.ray_dir(&b, 1, 0).y > 0.0);
        // Right-handed: forward +Z, up +Y → right = forward × up = −X.
        assert!(c.ray_dir(&b, 2, 1).x < 0.0);
        // tan(45°) = 1: the top row centre is at sy = (1 − 1/3).
        let d = c.ray_dir(&b, 1, 0);
        assert!((d.y / d.z - 2.0 / 3.0).abs() < 1e-12);
    }

    /// The slope tables give `ray_dir`'s directions bit for bit, on a wide and a tall image.
    #[test]
    fn slope_tables_give_ray_dir() {
        for (w, h) in [(37, 11), (5, 23)] {
            let c = Camera {
                eye: DVec3::new(1.0, 2.0, -3.0),
                target: DVec3::new(0.3, 0.1, 4.0),
                up: DVec3::Y,
                vfov_deg: 50.0,
                width: w,
                height: h,
            };
            let b = c.basis();
            let (columns, rows) = c.screen_slopes(&b);
            assert_eq!((columns.len(), rows.len()), (w as usize, h as usize));
            for y in 0..h {
                for x in 0..w {
                    let d = b.dir(columns[x as usize], rows[y as usize]);
                    assert_eq!(
                        d.to_array().map(f64::to_bits),
                        c.ray_dir(&b, x, y).to_array().map(f64::to_bits),
                        "pixel {x},{y}"
                    );
                }
            }
        }
    }

    #[test]
    fn invalid_cameras_are_refused() {
        let ok = Camera { eye: DVec3::ZERO, target: DVec3::Z, up: DVec3::Y, vfov_deg: 60.0, width: 4, height: 4 };
        assert!(ok.validate().is_ok());
        assert_eq!(Camera { up: DVec3::Z, ..ok }.validate(), Err(CameraError::BadUp));
        assert_eq!(Camera { target: DVec3::ZERO, ..ok }.validate(), Err(CameraError::NoDirection));
        assert_eq!(Camera { vfov_deg: 180.0, ..ok }.validate(), Err(CameraError::Fov(180.0)));
        assert_eq!(Camera { width: 0, ..ok }.validate(), Err(CameraError::Size(0, 4)));
        assert_eq!(Camera { width: 16384, height: 16384, ..ok }.validate(), Err(CameraError::Size(16384, 16384)));
        assert_eq!(Camera { eye: DVec3::NAN, ..ok }.validate(), Err(CameraError::NonFinite("eye")));
    }

    /// A misspelt field is refused with its name instead of being ignored.
    #[cfg(feature = "json")]
    #[test]
    fn unknown_json_fields_are_refused() {
        let text = r#"{"eye":[0,0,0],"target":[0,0,1],"up":[0,1,0],"vfov_deg":60,"width":4,"height":4,"fov":30}"#;
        let e = Camera::from_json(text).unwrap_err().to_string();
        assert!(e.contains("fov"), "{e}");
        assert!(Camera::from_json(&text.replace(r#","fov":30"#, "")).is_ok());
    }
}
