//! The CPU renderer: one primary ray per pixel through every part, the nearest hit shaded
//! with the sun (with a shadow ray through the SVOs), the ambient sky and MTL emitters.
//! Rays are formed camera-relative in f64 and rounded to f32 only in each SVO's unit cube.

use crate::ray::UnitRay;
use crate::scene::{Camera, Lights};
use crate::svo::Svo;
use crate::traverse::{trace_unit, TraceOptions};
use glam::{DVec3, Vec3};

/// Renderer settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderOptions {
    /// Trace shadow rays towards the sun.
    pub shadows: bool,
    /// Level-of-detail limit (levels below the root); `u32::MAX` for full detail.
    pub max_level: u32,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions { shadows: true, max_level: u32::MAX }
    }
}

/// A rendered image with its AOVs (row 0 at the top).
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Linear radiance per pixel.
    pub radiance: Vec<Vec3>,
    /// Ray parameter along the unit-length camera ray; +∞ for a miss.
    pub t: Vec<f32>,
    /// Part/instance index hit; −1 for a miss.
    pub instance: Vec<i32>,
    /// World-space unit normal facing the camera; zero for a miss.
    pub normal: Vec<Vec3>,
    /// Primary rays traced (pixels × parts tested is not counted; one per pixel).
    pub primary_rays: u64,
    /// Shadow rays traced.
    pub shadow_rays: u64,
}

/// One row of each frame buffer, as rayon's zipped chunk iterators hand them out.
type RowBuffers<'a> = (((&'a mut [Vec3], &'a mut [f32]), &'a mut [i32]), &'a mut [Vec3]);

struct Nearest {
    t: f32,
    part: usize,
    hit: crate::traverse::Hit,
}

fn nearest(parts: &[Svo], origin: DVec3, dir: DVec3, opts: &TraceOptions) -> Option<Nearest> {
    let mut best: Option<Nearest> = None;
    for (i, p) in parts.iter().enumerate() {
        let cube = &p.bounds;
        let Some(ur) = UnitRay::from_unit(cube.to_unit(origin), dir / cube.size as f64) else { continue };
        // Only hits closer than the best so far matter.
        let o = TraceOptions { t_max: best.as_ref().map_or(opts.t_max, |b| b.t), ..*opts };
        if let Some(hit) = trace_unit(p, &ur, &o).hit {
            if best.as_ref().is_none_or(|b| hit.t < b.t) {
                best = Some(Nearest { t: hit.t, part: i, hit });
            }
        }
    }
    best
}

fn occluded(parts: &[Svo], origin: DVec3, dir: DVec3) -> bool {
    parts.iter().any(|p| {
        let cube = &p.bounds;
        UnitRay::from_unit(cube.to_unit(origin), dir / cube.size as f64)
            .is_some_and(|ur| trace_unit(p, &ur, &TraceOptions::default()).hit.is_some())
    })
}

/// Renders the parts. `progress(rows_done, rows)` is called as rows finish.
pub fn render(
    parts: &[Svo],
    camera: &Camera,
    lights: &Lights,
    opts: &RenderOptions,
    progress: &(dyn Fn(u32, u32) + Sync),
) -> Frame {
    let (w, h) = (camera.width, camera.height);
    let basis = camera.basis();
    let sky = lights.sky();
    let trace_opts = TraceOptions { max_level: opts.max_level, ..TraceOptions::default() };
    let done = std::sync::atomic::AtomicU32::new(0);
    let shadow_rays = std::sync::atomic::AtomicU64::new(0);
    let pixel = |px: u32, py: u32| -> (Vec3, f32, i32, Vec3) {
        let dir = camera.ray_dir(&basis, px, py);
        let Some(n) = nearest(parts, camera.eye, dir, &trace_opts) else {
            return (sky, f32::INFINITY, -1, Vec3::ZERO);
        };
        let part = &parts[n.part];
        let dir32 = dir.as_vec3();
        let mut normal = n.hit.normal();
        if !(normal.length_squared() > 0.5) {
            normal = if n.hit.face_normal != Vec3::ZERO { n.hit.face_normal } else { -dir32 };
        }
        // Two-sided surfaces: shade the side facing the camera.
        if normal.dot(dir32) > 0.0 {
            normal = -normal;
        }
        let albedo = n.hit.albedo();
        let mut radiance = albedo * sky;
        if let Some(sun) = lights.sun {
            let cos = normal.dot(sun.to_sun);
            if cos > 0.0 {
                let p = camera.eye + dir * n.t as f64;
                let visible = !opts.shadows || {
                    shadow_rays.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    // Leave the hit voxel: one voxel along the normal, a little along the
                    // entered face, so the voxel does not shadow itself.
                    let voxel = part.bounds.voxel_size(n.hit.level) as f64;
                    let start = p + normal.as_dvec3() * voxel + n.hit.face_normal.as_dvec3() * (0.1 * voxel);
                    !occluded(parts, start, sun.to_sun.as_dvec3())
                };
                if visible {
                    radiance += albedo * sun.irradiance * (cos / std::f32::consts::PI);
                }
            }
        }
        if lights.use_mtl_emitters {
            radiance += n.hit.attr.emission();
        }
        (radiance, n.t, n.part as i32, normal)
    };
    // Rows are written straight into the frame's buffers (no per-row temporaries).
    let row = |py: usize, (((rad, t), inst), nrm): RowBuffers| {
        for px in 0..w as usize {
            (rad[px], t[px], inst[px], nrm[px]) = pixel(px as u32, py as u32);
        }
        let d = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        progress(d, h);
    };
    let n = w as usize * h as usize;
    let mut f = Frame {
        width: w,
        height: h,
        radiance: vec![Vec3::ZERO; n],
        t: vec![f32::INFINITY; n],
        instance: vec![-1; n],
        normal: vec![Vec3::ZERO; n],
        primary_rays: n as u64,
        shadow_rays: 0,
    };
    let wu = w as usize;
    #[cfg(feature = "parallel")]
    {
        use rayon::prelude::*;
        f.radiance
            .par_chunks_mut(wu)
            .zip(f.t.par_chunks_mut(wu))
            .zip(f.instance.par_chunks_mut(wu))
            .zip(f.normal.par_chunks_mut(wu))
            .enumerate()
            .for_each(|(py, bufs)| row(py, bufs));
    }
    #[cfg(not(feature = "parallel"))]
    f.radiance
        .chunks_mut(wu)
        .zip(f.t.chunks_mut(wu))
        .zip(f.instance.chunks_mut(wu))
        .zip(f.normal.chunks_mut(wu))
        .enumerate()
        .for_each(|(py, bufs)| row(py, bufs));
    f.shadow_rays = shadow_rays.into_inner();
    f
}
