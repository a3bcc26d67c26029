//! Light injection: the light each occupied world cell sends out, from the sun (N·L × albedo
//! / π × irradiance, visible only if a shadow ray through the SVO instances escapes) and from
//! MTL emitters. Stored with the cell's opacity (occupancy clamped to 1) and premultiplied by
//! it, ready for the level chain and front-to-back cone accumulation.

use super::volume::Volume;
use crate::render::bvh::Bvh;
use crate::render::instances::prepare;
use crate::render::visibility::{occluded, FrameInstances};
use crate::scene::{Lights, Scene};
use glam::{DVec3, Vec3, Vec4};

/// Premultiplied radiance and opacity per cell of a volume.
#[derive(Clone, Debug, PartialEq)]
pub struct Injected {
    /// Cells per side.
    pub res: u32,
    /// Cell edge (world units).
    pub cell: f64,
    /// World corner.
    pub min: DVec3,
    /// (radiance × alpha, alpha) per cell, same order as [`Volume`].
    pub rgba: Vec<Vec4>,
    /// Shadow rays traced.
    pub shadow_rays: u64,
}

/// Lights every occupied cell of `vol`; `scene` supplies the shadow-ray occluders.
pub fn inject(vol: &Volume, scene: &Scene, lights: &Lights) -> Injected {
    let spec = vol.spec;
    let eye = spec.min + DVec3::splat(spec.cell * spec.res as f64 * 0.5);
    let prepared = prepare(scene, eye, true);
    let (bvh, search) = Bvh::when_worthwhile(&prepared);
    let fi = FrameInstances { parts: &scene.parts, prepared: &prepared, bvh: bvh.as_ref() };
    let mut rgba = vec![Vec4::ZERO; vol.occupancy.len()];
    let mut shadow_rays = 0u64;
    let r = spec.res;
    for z in 0..r {
        for y in 0..r {
            for x in 0..r {
                let i = vol.index([x, y, z]);
                let occ = vol.occupancy[i];
                if occ <= 0.0 {
                    continue;
                }
                let albedo = vol.albedo[i] / occ;
                let n = vol.normal[i];
                let mut radiance = Vec3::ZERO;
                if let (Some(sun), true) = (lights.sun, n.length_squared() > 1e-6) {
                    let n = n.normalize();
                    let cos = n.dot(sun.to_sun);
                    if cos > 0.0 {
                        shadow_rays += 1;
                        // Start one cell off the surface so the cell's own voxels do not
                        // shadow it.
                        let start = spec.cell_centre([x, y, z]) + n.as_dvec3() * spec.cell - eye;
                        if !occluded(&fi, start, sun.to_sun.as_dvec3(), search) {
                            radiance += albedo * sun.irradiance * (cos / std::f32::consts::PI);
                        }
                    }
                }
                if lights.use_mtl_emitters {
                    radiance += vol.emission[i] / occ;
                }
                let alpha = occ.min(1.0);
                rgba[i] = (radiance * alpha).extend(alpha);
            }
        }
    }
    Injected { res: spec.res, cell: spec.cell, min: spec.min, rgba, shadow_rays }
}
