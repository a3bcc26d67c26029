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
