//! Lights of DESIGN.md's interface: a sun (direction towards it, irradiance on a sun-facing
//! plane), a uniform ambient sky (radiance), and MTL emitters.

use glam::Vec3;

/// A distant light.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "json", serde(deny_unknown_fields))]
pub struct Sun {
    /// Direction towards the sun (normalized on validation).
    pub to_sun: Vec3,
    /// Irradiance on a plane facing the sun (linear RGB).
    pub irradiance: Vec3,
}

/// Uniform sky.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "json", serde(deny_unknown_fields))]
pub struct Ambient {
    /// Radiance of the sky (linear RGB).
    pub radiance: Vec3,
}

/// All lights of a scene.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "json", serde(deny_unknown_fields))]
pub struct Lights {
    /// The sun, if any.
    #[cfg_attr(feature = "json", serde(default))]
    pub sun: Option<Sun>,
    /// The sky, if any.
    #[cfg_attr(feature = "json", serde(default))]
    pub ambient: Option<Ambient>,
    /// Whether MTL `Ke` makes surfaces emissive: they glow, and light the scene as area
    /// lights ([`crate::render::emitters`]).
    #[cfg_attr(feature = "json", serde(default))]
    pub use_mtl_emitters: bool,
    /// Points sampled on the emitters per shaded pixel (and per GI cell), each with a shadow
    /// ray: more give smoother soft shadows. 0: emitters glow and reach other surfaces only
    /// through GI's cones (as before emitters were lights).
    #[cfg_attr(feature = "json", serde(default = "default_emitter_samples"))]
    pub emitter_samples: u32,
}

/// Default [`Lights::emitter_samples`].
pub const DEFAULT_EMITTER_SAMPLES: u32 = 4;
/// Largest accepted [`Lights::emitter_samples`].
pub const MAX_EMITTER_SAMPLES: u32 = 1024;

#[cfg(feature = "json")]
fn default_emitter_samples() -> u32 {
    DEFAULT_EMITTER_SAMPLES
}

impl Default for Lights {
    /// Afternoon sun from the front left, and a pale blue sky.
    fn default() -> Self {
        Lights {
            sun: Some(Sun { to_sun: Vec3::new(0.55, 0.8, -0.35).normalize(), irradiance: Vec3::new(3.2, 3.0, 2.7) }),
            ambient: Some(Ambient { radiance: Vec3::new(0.22, 0.27, 0.34) }),
            use_mtl_emitters: false,
            emitter_samples: DEFAULT_EMITTER_SAMPLES,
        }
    }
}

/// Why lights are unusable.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LightsError {
    /// Too many emitter samples.
    #[error("lights: emitter_samples must be at most {MAX_EMITTER_SAMPLES}, got {0}")]
    Samples(u32),
    /// A value is negative, NaN or infinite.
    #[error("lights: {0} must be finite and non-negative")]
    Value(&'static str),
    /// The sun direction is zero or not finite.
    #[error("lights: sun.to_sun must be a finite non-zero vector")]
    Direction,
    /// Malformed JSON.
    #[error("lights JSON: {0}")]
    Json(String),
}

impl Lights {
    /// Checks values and normalizes the sun direction.
    pub fn validated(mut self) -> Result<Self, LightsError> {
        if let Some(sun) = &mut self.sun {
            if !sun.irradiance.is_finite() || sun.irradiance.min_element() < 0.0 {
                return Err(LightsError::Value("sun.irradiance"));
            }
            if !sun.to_sun.is_finite() || sun.to_sun.length_squared() == 0.0 {
                return Err(LightsError::Direction);
            }
            sun.to_sun = sun.to_sun.normalize();
        }
        if let Some(a) = &self.ambient {
            if !a.radiance.is_finite() || a.radiance.min_element() < 0.0 {
                return Err(LightsError::Value("ambient.radiance"));
            }
        }
        if self.emitter_samples > MAX_EMITTER_SAMPLES {
            return Err(LightsError::Samples(self.emitter_samples));
        }
        Ok(self)
    }

    /// Light samples per point on the emitters, when they are lights (0 otherwise).
    pub fn emitter_sampling(&self) -> u32 {
        if self.use_mtl_emitters {
            self.emitter_samples
        } else {
            0
        }
    }

    /// Sky radiance (zero without an ambient light).
    pub fn sky(&self) -> Vec3 {
        self.ambient.map_or(Vec3::ZERO, |a| a.radiance)
    }

    /// Parses the lights JSON of DESIGN.md and validates it.
    #[cfg(feature = "json")]
    pub fn from_json(text: &str) -> Result<Lights, LightsError> {
        let l: Lights = serde_json::from_str(text.strip_prefix('\u{feff}').unwrap_or(text))
            .map_err(|e| LightsError::Json(e.to_string()))?;
        l.validated()
    }
}

#[cfg(all(test, feature = "json"))]
mod tests {
    use super::*;

    /// A misspelt field is an error that names it, not a silently ignored light; omitted fields
    /// take their defaults; emitter samples are bounded.
    #[test]
    fn json_fields_are_checked() {
        let e = Lights::from_json(r#"{"use_mtl_emiters": true}"#).unwrap_err().to_string();
        assert!(e.contains("use_mtl_emiters"), "{e}");
        let e = Lights::from_json(r#"{"sun": {"to_sun": [0, 1, 0], "irradiance": [1, 1, 1], "power": 3}}"#)
            .unwrap_err()
            .to_string();
        assert!(e.contains("power"), "{e}");
        let l = Lights::from_json(r#"{"use_mtl_emitters": true}"#).unwrap();
        assert_eq!((l.sun, l.ambient, l.emitter_samples), (None, None, DEFAULT_EMITTER_SAMPLES));
        assert_eq!(l.emitter_sampling(), DEFAULT_EMITTER_SAMPLES);
        assert_eq!(Lights::from_json(r#"{"emitter_samples": 2}"#).unwrap().emitter_sampling(), 0);
        assert!(matches!(Lights::from_json(r#"{"emitter_samples": 5000}"#), Err(LightsError::Samples(5000))));
        assert!(Lights::from_json(r#"{"emitter_samples": -1}"#).is_err());
    }
}
