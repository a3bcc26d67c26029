//! Lights of DESIGN.md's interface: a sun (direction towards it, irradiance on a sun-facing
//! plane), a uniform ambient sky (radiance), and MTL emitters; besides them more suns, point
//! lights and spot lights (docs/lights.md).

use glam::{DVec3, Vec3};

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

/// A point light: radiant intensity (radiance × area per steradian), so the irradiance on a
/// surface facing it at distance d is `intensity / d²`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "json", serde(deny_unknown_fields))]
pub struct PointLight {
    /// World position.
    pub position: DVec3,
    /// Radiant intensity (linear RGB).
    pub intensity: Vec3,
}

/// A spot light: a point light whose intensity is full within `inner_deg` of its direction,
/// falls off smoothly (smoothstep of the cosine) to zero at `outer_deg`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "json", serde(deny_unknown_fields))]
pub struct SpotLight {
    /// World position.
    pub position: DVec3,
    /// Direction the spot points in (normalized on validation).
    pub direction: Vec3,
    /// Radiant intensity on its axis (linear RGB).
    pub intensity: Vec3,
    /// Half-angle of full intensity (degrees).
    pub inner_deg: f32,
    /// Half-angle beyond which it is dark (degrees, inner ≤ outer < 180).
    pub outer_deg: f32,
}

/// Most suns, point and spot lights together besides [`Lights::sun`]: each costs a shadow
/// ray per shaded pixel and per lit GI cell.
pub const MAX_EXTRA_LIGHTS: usize = 64;

/// One light that arrives from a single direction (a sun, a point or a spot), as a shaded
/// point sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Incident {
    /// Unit direction towards the light.
    pub to_light: DVec3,
    /// Distance to it (∞ for a sun): how far a shadow ray must get.
    pub distance: f64,
    /// Irradiance on a plane facing it.
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
#[derive(Clone, Debug, PartialEq)]
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
    /// Points sampled on the emitters per shaded pixel, each with a shadow ray: more give
    /// smoother soft shadows (GI's cells draw `GiSettings::cell_light_samples` instead). 0:
    /// emitters glow and reach other surfaces only through GI's cones (as before emitters were
    /// lights).
    #[cfg_attr(feature = "json", serde(default = "default_emitter_samples"))]
    pub emitter_samples: u32,
    /// More suns.
    #[cfg_attr(feature = "json", serde(default))]
    pub suns: Vec<Sun>,
    /// Point lights.
    #[cfg_attr(feature = "json", serde(default))]
    pub points: Vec<PointLight>,
    /// Spot lights.
    #[cfg_attr(feature = "json", serde(default))]
    pub spots: Vec<SpotLight>,
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
            suns: Vec::new(),
            points: Vec::new(),
            spots: Vec::new(),
        }
    }
}

/// Why lights are unusable.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LightsError {
    /// Too many suns, points and spots.
    #[error("lights: at most {MAX_EXTRA_LIGHTS} suns, points and spots together besides \"sun\", got {0}")]
    TooMany(usize),
    /// A spot light's angles are out of order or range.
    #[error("lights: spots[{0}] needs 0 ≤ inner_deg ≤ outer_deg < 180")]
    SpotAngles(usize),
    /// Too many emitter samples.
    #[error("lights: emitter_samples must be at most {MAX_EMITTER_SAMPLES}, got {0}")]
    Samples(u32),
    /// A value is negative, NaN or infinite.
    #[error("lights: {0} must be finite and non-negative")]
    Value(&'static str),
    /// A point's or spot's position is not finite, or a spot's direction is zero.
    #[error("lights: {0} must be finite (and a direction non-zero)")]
    Placement(String),
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
        let extra = self.suns.len() + self.points.len() + self.spots.len();
        if extra > MAX_EXTRA_LIGHTS {
            return Err(LightsError::TooMany(extra));
        }
        let colour = |v: Vec3| v.is_finite() && v.min_element() >= 0.0;
        for (i, sun) in self.suns.iter_mut().enumerate() {
            if !colour(sun.irradiance) {
                return Err(LightsError::Placement(format!("suns[{i}].irradiance")));
            }
            if !sun.to_sun.is_finite() || sun.to_sun.length_squared() == 0.0 {
                return Err(LightsError::Placement(format!("suns[{i}].to_sun")));
            }
            sun.to_sun = sun.to_sun.normalize();
        }
        for (i, p) in self.points.iter().enumerate() {
            if !colour(p.intensity) {
                return Err(LightsError::Placement(format!("points[{i}].intensity")));
            }
            if !p.position.is_finite() {
                return Err(LightsError::Placement(format!("points[{i}].position")));
            }
        }
        for (i, sp) in self.spots.iter_mut().enumerate() {
            if !colour(sp.intensity) {
                return Err(LightsError::Placement(format!("spots[{i}].intensity")));
            }
            if !sp.position.is_finite() {
                return Err(LightsError::Placement(format!("spots[{i}].position")));
            }
            if !sp.direction.is_finite() || sp.direction.length_squared() == 0.0 {
                return Err(LightsError::Placement(format!("spots[{i}].direction")));
            }
            sp.direction = sp.direction.normalize();
            if !(0.0 <= sp.inner_deg && sp.inner_deg <= sp.outer_deg && sp.outer_deg < 180.0) {
                return Err(LightsError::SpotAngles(i));
            }
        }
        if self.emitter_samples > MAX_EMITTER_SAMPLES {
            return Err(LightsError::Samples(self.emitter_samples));
        }
        Ok(self)
    }

    /// Whether there are suns, points or spots besides [`Lights::sun`].
    pub fn has_extra(&self) -> bool {
        !(self.suns.is_empty() && self.points.is_empty() && self.spots.is_empty())
    }

    /// Whether any sun, point or spot gives light (each needs shadow rays).
    pub fn has_direct(&self) -> bool {
        let lit = |v: Vec3| v.max_element() > 0.0;
        self.sun.is_some_and(|s| lit(s.irradiance))
            || self.suns.iter().any(|s| lit(s.irradiance))
            || self.points.iter().any(|p| lit(p.intensity))
            || self.spots.iter().any(|p| lit(p.intensity))
    }

    /// The light that the extra suns, points and spots (not [`Lights::sun`]) send to the world
    /// point `at`, in order: suns, points, spots. Lights that give nothing there (black ones,
    /// ones at `at` itself, spots facing away) are left out (WGSL: `incident`).
    pub fn incident_extra(&self, at: DVec3) -> impl Iterator<Item = Incident> + '_ {
        let suns = self.suns.iter().map(|s| Incident {
            to_light: s.to_sun.as_dvec3(),
            distance: f64::INFINITY,
            irradiance: s.irradiance,
        });
        let points = self.points.iter().filter_map(move |p| point_incident(p.position, p.intensity, at));
        let spots = self.spots.iter().filter_map(move |sp| {
            let mut inc = point_incident(sp.position, sp.intensity, at)?;
            inc.irradiance *= spot_falloff(sp, -inc.to_light.as_vec3());
            Some(inc)
        });
        suns.chain(points).chain(spots).filter(|inc| inc.irradiance.max_element() > 0.0)
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

/// A point light of `intensity` at `position` seen from `at`.
fn point_incident(position: DVec3, intensity: Vec3, at: DVec3) -> Option<Incident> {
    let to = position - at;
    let d2 = to.length_squared();
    if !(d2 > 0.0) {
        return None;
    }
    let distance = d2.sqrt();
    Some(Incident { to_light: to / distance, distance, irradiance: intensity / d2 as f32 })
}

/// A spot's intensity fraction towards unit direction `out` (from the light): 1 within the
/// inner cone, smoothstep of the cosine down to 0 at the outer one (WGSL: `spot_falloff`).
pub fn spot_falloff(sp: &SpotLight, out: Vec3) -> f32 {
    let c = sp.direction.dot(out);
    let (ci, co) = (sp.inner_deg.to_radians().cos(), sp.outer_deg.to_radians().cos());
    if c >= ci {
        return 1.0;
    }
    if c <= co || ci <= co {
        return 0.0;
    }
    let x = (c - co) / (ci - co);
    x * x * (3.0 - 2.0 * x)
}
