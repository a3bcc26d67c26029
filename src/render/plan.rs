//! The frame plan: from the scene, the camera, the lights, the user's switches and the
//! previous frame, which passes and features this frame needs. Everything it leaves out is
//! skipped ("leave out what a scene does not need").

use super::hitbuffer::HitBuffer;
use super::visibility::Search;
use crate::scene::{Camera, Lights, Scene};

/// Instances below this count are searched without a BVH (sorting a handful of spheres is
/// cheaper than building and walking a tree; see docs/benchmarks.md for the sweep).
pub const BVH_MIN_INSTANCES: usize = 32;

/// What the user allows (all on by default; the CLI's `--no-*` switches turn them off).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
pub struct Features {
    /// Bounding-sphere culling.
    pub cull: bool,
    /// Depth-sorted early-out.
    pub sort: bool,
    /// Instance BVH.
    pub bvh: bool,
    /// Per-pixel hit buffer.
    pub hit_buffer: bool,
    /// Shadow rays.
    pub shadows: bool,
    /// Beams: primary rays start where their tile's cone first meets each instance.
    #[cfg_attr(feature = "json", serde(default = "yes"))]
    pub beams: bool,
    /// Pose only the cars some ray of the frame can reach ([`crate::scene::car::SeenCars::pose`];
    /// the callers that pose cars read it, the plan does not).
    #[cfg_attr(feature = "json", serde(default = "yes"))]
    pub pose_seen: bool,
}

#[cfg(feature = "json")]
fn yes() -> bool {
    true
}

impl Default for Features {
    fn default() -> Self {
        Features { cull: true, sort: true, bvh: true, hit_buffer: true, shadows: true, beams: true, pose_seen: true }
    }
}

impl Features {
    /// Everything off: the plain oracle path.
    pub const NONE: Features = Features {
        cull: false,
        sort: false,
        bvh: false,
        hit_buffer: false,
        shadows: false,
        beams: false,
        pose_seen: false,
    };

    /// The same switches with shadow rays on (the oracle path of a lit image).
    pub fn with_shadows(self) -> Features {
        Features { shadows: true, ..self }
    }
}

/// What this frame does.
#[derive(Clone, Debug, PartialEq)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
pub struct FramePlan {
    /// Instances in the scene.
    pub instances: usize,
    /// Rays are transformed into each instance (some world transform is not the identity).
    pub transform: bool,
    /// Bounding-sphere culling.
    pub cull: bool,
    /// Depth-sorted early-out.
    pub sort: bool,
    /// Instance BVH.
    pub bvh: bool,
    /// Reuse last frame's hits.
    pub hit_buffer: bool,
    /// Keep this frame's hits for the next one (the hit buffer is switched on).
    #[cfg_attr(feature = "json", serde(default))]
    pub keep_hits: bool,
    /// Shadow rays.
    pub shadows: bool,
    /// Beams for primary rays ([`super::beam`]).
    #[cfg_attr(feature = "json", serde(default))]
    pub beams: bool,
    /// Beams through the instance BVH, for more instances than beams take: a tile whose rays'
    /// pyramid meets no instance's sphere stores misses without tracing ([`super::beam::meets_any`]).
    #[cfg_attr(feature = "json", serde(default))]
    pub bvh_beams: bool,
    /// Per-pixel sphere lists for primary rays, for more instances than beams take: every
    /// instance's sphere projected onto the pixels whose rays it meets, so that a ray searches
    /// only its list instead of walking the BVH ([`super::pixel_spheres`]); where the spheres
    /// overlap too deeply, `bvh_beams` as before.
    #[cfg_attr(feature = "json", serde(default))]
    pub sphere_lists: bool,
    /// GI in this frame (None: off): what it kept from the frame before and the volume's
    /// layout. Decided as GI runs; [`crate::session::Session::frame`] fills it in and adds
    /// its reason line.
    #[cfg_attr(feature = "json", serde(default))]
    pub gi: Option<GiPlan>,
    /// Why each choice was made, one line each.
    pub reasons: Vec<String>,
}

/// The GI part of a frame plan.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
pub struct GiPlan {
    /// What was kept from the frame before.
    pub reuse: crate::gi::GiReuse,
    /// How the world volume is stored (dense or sparse).
    pub layout: crate::gi::Layout,
}

impl FramePlan {
    /// Decides the plan.
    pub fn new(
        scene: &Scene,
        camera: &Camera,
        lights: &Lights,
        features: &Features,
        prev: Option<&HitBuffer>,
    ) -> FramePlan {
        let n = scene.instances().len();
        let mut reasons = Vec::new();
        let transform = scene.worlds().iter().any(|w| *w != glam::DAffine3::IDENTITY);
        reasons.push(if transform {
            "transform: on (instances have non-identity transforms)".into()
        } else {
            "transform: off (every instance at the identity: rays map by the cube offset and scale only)".into()
        });
        let many = n > 1;
        let cull = features.cull && many;
        reasons.push(match (features.cull, many) {
            (false, _) => "cull: off (switched off)".into(),
            (true, false) => "cull: off (one instance: nothing to cull)".into(),
            _ => "cull: on".into(),
        });
        let bvh = features.bvh && features.cull && n >= BVH_MIN_INSTANCES;
        reasons.push(if !features.bvh || !features.cull {
            "bvh: off (switched off)".into()
        } else if bvh {
            format!("bvh: on ({n} instances ≥ {BVH_MIN_INSTANCES})")
        } else {
            format!("bvh: off ({n} instances < {BVH_MIN_INSTANCES})")
        });
        let sort = features.sort && cull && !bvh;
        reasons.push(if bvh {
            "sort: off (the BVH visits instances near to far)".into()
        } else if sort {
            "sort: on (depth-sorted early-out)".into()
        } else if !features.sort {
            "sort: off (switched off)".into()
        } else {
            "sort: off (needs culling)".into()
        });
        let camera_static = prev.is_some_and(|p| p.same_camera(camera));
        let hit_buffer = features.hit_buffer && camera_static;
        reasons.push(match (features.hit_buffer, prev.is_some(), camera_static) {
            (false, _, _) => "hit_buffer: off (switched off)".into(),
            (true, false, _) => "hit_buffer: off (first frame)".into(),
            (true, true, false) => "hit_buffer: off (camera moved)".into(),
            _ => "hit_buffer: on (camera static)".into(),
        });
        let sun = lights.has_direct();
        // Emitters are lights when they are sampled and some part has an emissive triangle.
        let emitters = lights.emitter_sampling() > 0 && scene.parts.iter().any(|p| !p.emitters.is_empty());
        let shadows = features.shadows && (sun || emitters);
        reasons.push(match (features.shadows, sun || emitters) {
            (false, _) => "shadows: off (switched off)".into(),
            (true, false) => "shadows: off (no sun, no sampled emitter)".into(),
            _ => "shadows: on".into(),
        });
        let few = features.beams && n <= super::beam::MAX_INSTANCES;
        // Few instances, each a few pixels wide, in a frame that traces every pixel: sphere
        // lists. (With the hit buffer's pixels kept, building the lists does not pay.)
        let area = (few && cull && !hit_buffer).then(|| super::pixel_spheres::mean_instance_area(scene, camera));
        let small = area.flatten().is_some_and(|a| a < super::beam::MIN_MEAN_AREA);
        let beams = few && !small;
        let bvh_beams = features.beams && bvh && !beams;
        reasons.push(if !features.beams {
            "beams: off (switched off)".into()
        } else if beams {
            format!(
                "beams: on (primary rays start where their {0}×{0} tile's cone meets each instance)",
                super::beam::TILE
            )
        } else if small {
            format!(
                "beams: per-pixel sphere lists ({n} instances of {:.0} pixels each on average < {}: each sphere projected onto the pixels whose rays it meets, a ray searches only its own)",
                area.flatten().unwrap_or(0.0),
                super::beam::MIN_MEAN_AREA
            )
        } else if bvh_beams {
            format!(
                "beams: per-pixel sphere lists ({n} instances > {}: each sphere projected onto the pixels whose rays it meets, a ray searches only its own; through the BVH where they overlap more than {} deep: a {2}×{2} tile whose rays' pyramid meets no instance stores misses untraced)",
                super::beam::MAX_INSTANCES,
                super::pixel_spheres::MAX_PER_PIXEL,
                super::beam::TILE
            )
        } else {
            format!("beams: off ({n} instances > {}, no BVH)", super::beam::MAX_INSTANCES)
        });
        FramePlan {
            instances: n,
            transform,
            cull,
            sort,
            bvh,
            hit_buffer,
            keep_hits: features.hit_buffer,
            shadows,
            beams,
            bvh_beams,
            sphere_lists: bvh_beams || small,
            gi: None,
            reasons,
        }
    }

    /// Records what GI did in this frame, with its reason line.
    pub fn with_gi(&mut self, gi: GiPlan) {
        self.gi = Some(gi);
        self.reasons.retain(|r| !r.starts_with("gi:"));
        let what = gi.reuse.explain().strip_prefix("GI: ").unwrap_or(gi.reuse.explain());
        let layout = format!("{:?}", gi.layout).to_lowercase();
        self.reasons.push(format!("gi: {what}; {layout} volume"));
    }

    /// Turns beams off for a renderer that has none, saying why.
    pub fn without_beams(&mut self, why: &str) {
        self.beams = false;
        self.bvh_beams = false;
        self.sphere_lists = false;
        if let Some(r) = self.reasons.iter_mut().find(|r| r.starts_with("beams:")) {
            *r = format!("beams: off ({why})");
        }
    }

    /// The instance search this plan implies.
    pub fn search(&self) -> Search {
        match (self.cull, self.sort, self.bvh) {
            (_, _, true) => Search::Bvh,
            (true, true, _) => Search::CullSort,
            (true, false, _) => Search::Cull,
            _ => Search::Plain,
        }
    }

    /// Human-readable plan (`--explain`).
    pub fn explain(&self) -> String {
        format!("frame plan ({} instances):\n  {}", self.instances, self.reasons.join("\n  "))
    }
}
