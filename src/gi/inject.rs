//! Light injection: the light each occupied world cell sends out, from the sun (N·L × albedo
//! / π × irradiance, visible only if a shadow ray through the SVO instances escapes) and from
//! MTL emitters: sampled as area lights with shadow rays when they are lights (their own
//! glow then stays out of the volume, since every shaded point samples it directly), or
//! their emitted radiance itself when they are not sampled. Stored with the cell's opacity (occupancy clamped to 1) and premultiplied by
//! it, ready for the level chain and front-to-back cone accumulation.

use super::volume::{Volume, VolumeSpec};
use crate::render::bvh::Bvh;
use crate::render::emitters::{emitter_light, EmitterShadows, EmitterTable};
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

/// One world cell's accumulated sums (weight × attribute) and its centre: what injection and
/// the bounces read, from either volume layout.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CellSums {
    /// Summed weight.
    pub occupancy: f32,
    /// Summed weight × linear albedo.
    pub albedo: Vec3,
    /// Summed weight × world normal.
    pub normal: Vec3,
    /// Summed weight × emitted radiance.
    pub emission: Vec3,
    /// World centre.
    pub centre: DVec3,
}

/// A volume's stored cells, by index: every cell of the dense volume, every cell of every
/// allocated brick of the sparse one.
pub trait Cells: Sync {
    /// Placement.
    fn spec(&self) -> VolumeSpec;
    /// Stored cells.
    fn cell_count(&self) -> usize;
    /// Cell `i`.
    fn sums(&self, i: usize) -> CellSums;
}

impl Cells for Volume {
    fn spec(&self) -> VolumeSpec {
        self.spec
    }
    fn cell_count(&self) -> usize {
        self.occupancy.len()
    }
    fn sums(&self, i: usize) -> CellSums {
        let r = self.spec.res as usize;
        let c = [(i % r) as u32, ((i / r) % r) as u32, (i / (r * r)) as u32];
        CellSums {
            occupancy: self.occupancy[i],
            albedo: self.albedo[i],
            normal: self.normal[i],
            emission: self.emission[i],
            centre: self.spec.cell_centre(c),
        }
    }
}

/// Lights every occupied cell of `vol`; `scene` supplies the shadow-ray occluders; sampled
/// emitters get `cell_samples` points per cell ([`inject_cells`]).
pub fn inject(vol: &Volume, scene: &Scene, lights: &Lights, cell_samples: u32) -> Injected {
    let spec = vol.spec;
    let (rgba, shadow_rays) = inject_cells(vol, scene, lights, cell_samples);
    Injected { res: spec.res, cell: spec.cell, min: spec.min, rgba, shadow_rays }
}

/// Lights every occupied cell of `cells`: (radiance × alpha, alpha) per stored cell and the
/// shadow rays traced. Where the lights sample their emitters (`Lights::emitter_samples` > 0),
/// each cell draws `cell_samples` points on them (`GiSettings::cell_light_samples`: the
/// cones average many cells, so fewer than a pixel's suffice).
pub fn inject_cells(cells: &impl Cells, scene: &Scene, lights: &Lights, cell_samples: u32) -> (Vec<Vec4>, u64) {
    let spec = cells.spec();
    let eye = spec.min + DVec3::splat(spec.cell * spec.res as f64 * 0.5);
    // The volume is lit at full detail, whatever level a frame is traced at (its shadow rays
    // go down to the voxels: `u32::MAX` below).
    let prepared = prepare(scene, eye, true);
    let (bvh, search) = Bvh::when_worthwhile(&prepared);
    let fi = FrameInstances { parts: &scene.parts, prepared: &prepared, bvh: bvh.as_ref(), starts: None };
    let mut rgba = vec![Vec4::ZERO; cells.cell_count()];
    let mut shadow_rays = 0u64;
    let samples = if lights.emitter_sampling() > 0 { cell_samples } else { 0 };
    let emitters = if samples > 0 { EmitterTable::new(scene, eye) } else { EmitterTable::default() };
    for (i, out) in rgba.iter_mut().enumerate() {
        let cell = cells.sums(i);
        let occ = cell.occupancy;
        if occ <= 0.0 {
            continue;
        }
        let albedo = cell.albedo / occ;
        let n = cell.normal;
        let mut radiance = Vec3::ZERO;
        if let (Some(sun), true) = (lights.sun, n.length_squared() > 1e-6) {
            let n = n.normalize();
            let cos = n.dot(sun.to_sun);
            if cos > 0.0 {
                shadow_rays += 1;
                // Start one cell off the surface so the cell's own voxels do not shadow it.
                let start = cell.centre + n.as_dvec3() * spec.cell - eye;
                if !occluded(&fi, start, sun.to_sun.as_dvec3(), f64::INFINITY, search, u32::MAX) {
                    radiance += albedo * sun.irradiance * (cos / std::f32::consts::PI);
                }
            }
        }
        if lights.has_extra() && n.length_squared() > 1e-6 {
            // The other suns, points and spots, each with a shadow ray from the same start.
            let n = n.normalize();
            let start = cell.centre + n.as_dvec3() * spec.cell - eye;
            for inc in lights.incident_extra(cell.centre) {
                let cos = n.dot(inc.to_light.as_vec3());
                if cos > 0.0 {
                    shadow_rays += 1;
                    if !occluded(&fi, start, inc.to_light, inc.distance, search, u32::MAX) {
                        radiance += albedo * inc.irradiance * (cos / std::f32::consts::PI);
                    }
                }
            }
        }
        if !emitters.is_empty() && n.length_squared() > 1e-6 {
            let n = n.normalize();
            let at = cell.centre - eye;
            let start = at + n.as_dvec3() * spec.cell;
            // Keyed by the cell's place in the grid, so dense and sparse volumes (whose stored
            // order differs) draw the same points.
            let key = cell_key(spec, cell.centre);
            radiance += emitter_light(
                &emitters,
                samples,
                key,
                at,
                start,
                n,
                -n,
                albedo,
                0.0,
                1.0,
                EmitterShadows::Rays(&mut |o, d, len| {
                    shadow_rays += 1;
                    !occluded(&fi, o, d, len, search, u32::MAX)
                }),
            );
        } else if lights.use_mtl_emitters && lights.emitter_sampling() == 0 {
            radiance += cell.emission / occ;
        }
        let alpha = occ.min(1.0);
        *out = (radiance * alpha).extend(alpha);
    }
    (rgba, shadow_rays)
}

/// The random-number key of the cell centred at `centre`: its grid index x + res·(y + res·z)
/// (WGSL: `gi_cell_key`).
pub fn cell_key(spec: VolumeSpec, centre: DVec3) -> u32 {
    let c = ((centre - spec.min) / spec.cell).floor();
    let r = spec.res as u64;
    (c.x as u64 + r * (c.y as u64 + r * c.z as u64)) as u32
}
