//! Rigid-body transforms: translation · rotation · anisotropic scale, in f64. Rendering
//! converts them camera-relative before anything becomes f32 (see `render::instances`).

use glam::{DAffine3, DMat3, DQuat, DVec3};

/// Smallest accepted |scale| per axis (relative to 1): below it the inverse used to transform
/// rays would amplify rounding by more than 10⁶.
pub const MIN_SCALE: f64 = 1e-6;
/// Largest accepted |scale| per axis.
pub const MAX_SCALE: f64 = 1e6;

/// Why a transform was refused.
#[derive(Clone, Debug, thiserror::Error, PartialEq)]
pub enum TransformError {
    /// A component is NaN or infinite.
    #[error("transform {0} is not finite")]
    NonFinite(&'static str),
    /// A scale component is too small (near-singular) or too large.
    #[error("scale {0:?}: every |component| must lie in [{MIN_SCALE:e}, {MAX_SCALE:e}] (near-singular or degenerate)")]
    Scale(DVec3),
    /// The rotation quaternion is zero.
    #[error("rotation quaternion has zero length")]
    Rotation,
    /// A composed (world) transform is singular or not finite.
    #[error("instance {0}: world transform is singular or not finite")]
    Singular(usize),
}

/// `translation · rotation · scale` (scale applied first).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    /// Translation.
    pub translation: DVec3,
    /// Unit rotation.
    pub rotation: DQuat,
    /// Per-axis scale (negative mirrors).
    pub scale: DVec3,
}

impl Default for Transform {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Transform {
    /// The identity.
    pub const IDENTITY: Transform =
        Transform { translation: DVec3::ZERO, rotation: DQuat::IDENTITY, scale: DVec3::ONE };

    /// A validated transform; the rotation is normalized.
    pub fn new(translation: DVec3, rotation: DQuat, scale: DVec3) -> Result<Self, TransformError> {
        if !translation.is_finite() {
            return Err(TransformError::NonFinite("translation"));
        }
        if !rotation.is_finite() {
            return Err(TransformError::NonFinite("rotation"));
        }
        if !scale.is_finite() {
            return Err(TransformError::NonFinite("scale"));
        }
        let len = rotation.length();
        if !(len > 1e-12) {
            return Err(TransformError::Rotation);
        }
        let a = scale.abs();
        if !(a.min_element() >= MIN_SCALE && a.max_element() <= MAX_SCALE) {
            return Err(TransformError::Scale(scale));
        }
        Ok(Transform { translation, rotation: rotation / len, scale })
    }

    /// A translation.
    pub fn from_translation(t: DVec3) -> Self {
        Transform { translation: t, ..Self::IDENTITY }
    }

    /// A rotation by `angle` radians about the line through `pivot` along unit `axis`
    /// (T(p)·R·T(−p) written as T·R: translation p − R·p).
    pub fn about_pivot(pivot: DVec3, axis: DVec3, angle: f64) -> Self {
        let rotation = DQuat::from_axis_angle(axis.normalize(), angle);
        Transform { translation: pivot - rotation * pivot, rotation, scale: DVec3::ONE }
    }

    /// The affine matrix.
    pub fn to_affine(&self) -> DAffine3 {
        DAffine3::from_scale_rotation_translation(self.scale, self.rotation, self.translation)
    }

    /// Whether this is exactly the identity.
    pub fn is_identity(&self) -> bool {
        *self == Self::IDENTITY
    }
}

/// Whether a world matrix can be inverted safely: finite, and no direction shrunk below
/// [`MIN_SCALE`]³ (products of extreme scales through a hierarchy).
// Inlined into the update's loop: called, the composed matrix went through the stack and its
// reload waited on the stores (update −7 %, docs/benchmarks.md step 80).
#[inline(always)]
pub fn is_well_conditioned(m: &DAffine3) -> bool {
    let l: DMat3 = m.matrix3;
    if !(m.translation.is_finite() && l.is_finite() && l.determinant().abs() > MIN_SCALE.powi(3)) {
        return false;
    }
    // With every entry below 10¹⁴⁰ the adjugate's entries (differences of products of two)
    // stay below 2·10²⁸⁰, and divided by a determinant above 10⁻¹⁸ the inverse is finite:
    // the inverse need only be formed for larger entries.
    let largest = l.x_axis.abs().max(l.y_axis.abs()).max(l.z_axis.abs()).max_element();
    largest < 1e140 || l.inverse().is_finite()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_bad_transforms() {
        let q = DQuat::IDENTITY;
        assert_eq!(Transform::new(DVec3::NAN, q, DVec3::ONE), Err(TransformError::NonFinite("translation")));
        assert_eq!(
            Transform::new(DVec3::ZERO, DQuat::from_xyzw(0., 0., 0., 0.), DVec3::ONE),
            Err(TransformError::Rotation)
        );
        assert!(matches!(Transform::new(DVec3::ZERO, q, DVec3::new(1.0, 0.0, 1.0)), Err(TransformError::Scale(_))));
        assert!(matches!(Transform::new(DVec3::ZERO, q, DVec3::new(1.0, 1e-9, 1.0)), Err(TransformError::Scale(_))));
        assert!(matches!(
            Transform::new(DVec3::ZERO, q, DVec3::splat(f64::INFINITY)),
            Err(TransformError::NonFinite("scale"))
        ));
        assert!(Transform::new(DVec3::ZERO, q * 3.0, DVec3::new(1e-3, -2.0, 1e3)).is_ok());
    }

    /// The check forms the inverse only for entries past 10¹⁴⁰: it answers as the full
    /// definition does, on both sides of that line and where the inverse overflows.
    #[test]
    fn conditioning_agrees_with_forming_the_inverse() {
        let full = |m: &DAffine3| {
            let l = m.matrix3;
            m.translation.is_finite()
                && l.is_finite()
                && l.determinant().abs() > MIN_SCALE.powi(3)
                && l.inverse().is_finite()
        };
        let diag = |a: f64, b: f64, c: f64| DAffine3::from_mat3(DMat3::from_diagonal(DVec3::new(a, b, c)));
        let shear =
            |a: f64, b: f64| DAffine3::from_mat3(DMat3::from_cols_array(&[a, 0.0, 0.0, a, b, 0.0, 0.0, 0.0, 1.0]));
        let cases = [
            (diag(1.0, 2.0, 3.0), true),
            (diag(1e139, 1e139, 1e-259), true),
            // Adjugate entries of 10³²⁰ overflow although the determinant is 10²⁰.
            (diag(1e160, 1e160, 1e-300), false),
            (diag(1e-7, 1e-7, 1e-7), false),
            (shear(1e150, 1e-140), true),
            (diag(f64::NAN, 1.0, 1.0), false),
            (DAffine3 { translation: DVec3::INFINITY, ..diag(1.0, 1.0, 1.0) }, false),
        ];
        for (m, expected) in cases {
            assert_eq!(full(&m), expected, "{m:?}");
            assert_eq!(is_well_conditioned(&m), expected, "{m:?}");
        }
    }

    #[test]
    fn pivot_rotation_keeps_the_pivot() {
        let p = DVec3::new(1.0, 2.0, 3.0);
        let t = Transform::about_pivot(p, DVec3::Y, 1.0).to_affine();
        assert!((t.transform_point3(p) - p).length() < 1e-12);
    }
}
