//! Other ray casters a user might pick, on the same car, camera and thread pool: Intel Embree
//! (triangle BVH, through the `embree` crate and the system library), parry3d's `TriMesh`
//! (triangle BVH) and parry3d's `Voxels` built from the SVO's own leaf voxels. Each traces the
//! nearest hit of every primary ray of a frame; voxray renders the same frame from the merged
//! static SVO, and also answers the same nearest-hit queries through the same loop as the
//! peers (the like-for-like figure). The hit fraction of each is recorded so a reader can see they trace the same
//! thing.

use super::{summarize, Record};
use crate::backend::Backend;
use crate::render::{Features, HitBuffer};
use crate::scene::Camera;
use crate::svo::Svo;
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::sync::Arc;
use std::time::Instant;

/// What the peers trace.
pub struct PeerScene<'a> {
    /// The car's triangles (positions), in the same space as `svo`.
    pub triangles: &'a [[Vec3; 3]],
    /// The car merged into one SVO, placed at the identity.
    pub svo: Arc<Svo>,
    /// The camera.
    pub camera: &'a Camera,
    /// Untimed frames.
    pub warmup: usize,
    /// Timed frames.
    pub frames: usize,
    /// The command line, stored in the records.
    pub command: String,
    /// The machine, stored in the records.
    pub machine: String,
}

/// Traces one frame with `hit` (true on a hit) over every pixel in parallel rows; returns
/// seconds and the number of hits.
fn frame(camera: &Camera, hit: &(dyn Fn(DVec3, DVec3) -> bool + Sync)) -> (f64, u64) {
    let b = camera.basis();
    let start = Instant::now();
    let hits: u64 = (0..camera.height)
        .into_par_iter()
        .map(|y| (0..camera.width).filter(|&x| hit(camera.eye, camera.ray_dir(&b, x, y))).count() as u64)
        .sum();
    (start.elapsed().as_secs_f64(), hits)
}

fn timed(name: &str, what: &str, scene: &PeerScene<'_>, hit: &(dyn Fn(DVec3, DVec3) -> bool + Sync)) -> Record {
    let mut times = Vec::new();
    let mut hits = 0;
    for f in 0..scene.warmup + scene.frames.max(1) {
        let (secs, h) = frame(scene.camera, hit);
        if f >= scene.warmup {
            times.push(secs * 1e3);
            hits = h;
        }
    }
    let (median_ms, p95_ms, min_ms) = summarize(&times);
    let pixels = (scene.camera.width * scene.camera.height) as f64;
    Record {
        group: "peers".into(),
        name: name.into(),
        setting: format!("{what}; hits {:.1}% of pixels", 100.0 * hits as f64 / pixels),
        backend_kind: name.into(),
        backend: format!("CPU, {} threads", rayon::current_num_threads()),
        width: scene.camera.width,
        height: scene.camera.height,
        warmup: scene.warmup,
        frames: scene.frames.max(1),
        instances: 1,
        median_ms,
        p95_ms,
        min_ms,
        mrays_per_s: pixels / (median_ms.max(1e-9) * 1e-3) / 1e6,
        machine: scene.machine.clone(),
        command: scene.command.clone(),
        ..Record::default()
    }
}

/// Runs voxray and every peer on `scene`.
pub fn run(scene: &PeerScene<'_>) -> Result<Vec<Record>, crate::Error> {
    let mut out = Vec::new();

    // voxray: the whole frame (trace + shade), primary rays only, on the merged static SVO.
    let mut voxray_scene = super::matrix::static_scene(scene.svo.clone())?;
    let mut backend = Backend::Cpu(HitBuffer::new());
    let clip = super::Clip {
        scene: &mut voxray_scene,
        cars: &[],
        camera: scene.camera,
        lights: &crate::scene::Lights::default(),
        features: Features { hit_buffer: false, shadows: false, ..Features::default() },
        lod: u32::MAX,
        warmup: scene.warmup,
        frames: scene.frames,
        fps: 30.0,
    };
    let backend_name = format!("CPU, {} threads", rayon::current_num_threads());
    let (mut r, f) = super::run_clip(&mut backend, &backend_name, clip)?;
    let hits = f.instance.iter().filter(|&&i| i >= 0).count();
    let pixels = (scene.camera.width * scene.camera.height) as f64;
    r.group = "peers".into();
    r.name = "voxray".into();
    r.backend_kind = "voxray".into();
    r.setting = format!(
        "SVO, {} voxels (depth {}), whole frame; hits {:.1}% of pixels",
        scene.svo.voxel_count,
        scene.svo.depth,
        100.0 * hits as f64 / pixels
    );
    // Primary rays only (no reuse, no shadows): rays per second of the median frame.
    r.mrays_per_s = pixels / (r.median_ms.max(1e-9) * 1e-3) / 1e6;
    r.machine = scene.machine.clone();
    r.command = scene.command.clone();
    out.push(r);

    // voxray again, on the peers' own terms: per pixel only the nearest-hit query (sphere
    // culling, camera-relative ray into the SVO), no plan, no shading.
    {
        use crate::render::instances::prepare;
        use crate::render::visibility::{nearest, FrameInstances, Search};
        let prepared = prepare(&voxray_scene, scene.camera.eye, false);
        let fi = FrameInstances { parts: &voxray_scene.parts, prepared: &prepared, bvh: None };
        let opts = crate::traverse::TraceOptions::default();
        let hit = |_o: DVec3, d: DVec3| nearest(&fi, DVec3::ZERO, d, Search::Cull, &opts).is_some();
        let mut r = timed("voxray (trace only)", "the same SVO, nearest-hit query only", scene, &hit);
        r.backend_kind = "voxray-trace".into();
        out.push(r);
    }

    // Embree: one triangle geometry, BVH built by the library.
    {
        use cgmath::{Vector3, Vector4};
        let device = embree::Device::new();
        let n = scene.triangles.len();
        let mut mesh = embree::TriangleMesh::unanimated(&device, n, 3 * n);
        {
            let mut v = mesh.vertex_buffer.map();
            let mut idx = mesh.index_buffer.map();
            for (i, t) in scene.triangles.iter().enumerate() {
                for k in 0..3 {
                    v[3 * i + k] = Vector4::new(t[k].x, t[k].y, t[k].z, 0.0);
                }
                idx[i] = Vector3::new(3 * i as u32, 3 * i as u32 + 1, 3 * i as u32 + 2);
            }
        }
        let mut geom = embree::Geometry::Triangle(mesh);
        geom.commit();
        let mut es = embree::Scene::new(&device);
        es.attach_geometry(geom);
        let committed = es.commit();
        let hit = |o: DVec3, d: DVec3| {
            let mut ctx = embree::IntersectContext::coherent();
            let mut rh = embree::RayHit::new(embree::Ray::new(
                Vector3::new(o.x as f32, o.y as f32, o.z as f32),
                Vector3::new(d.x as f32, d.y as f32, d.z as f32),
            ));
            committed.intersect(&mut ctx, &mut rh);
            rh.hit.hit()
        };
        out.push(timed("Embree 3", &format!("{n} triangles, BVH"), scene, &hit));
    }

    // parry3d TriMesh.
    {
        use parry3d::math::Vector;
        use parry3d::query::{Ray, RayCast};
        let verts: Vec<Vector> =
            scene.triangles.iter().flat_map(|t| t.iter().map(|p| Vector::new(p.x, p.y, p.z))).collect();
        let idx: Vec<[u32; 3]> = (0..scene.triangles.len() as u32).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect();
        let tm = parry3d::shape::TriMesh::new(verts, idx).map_err(|e| crate::Error::Io {
            path: "parry3d TriMesh".into(),
            source: std::io::Error::other(format!("{e:?}")),
        })?;
        let hit = |o: DVec3, d: DVec3| {
            let ray = Ray::new(
                Vector::new(o.x as f32, o.y as f32, o.z as f32),
                Vector::new(d.x as f32, d.y as f32, d.z as f32),
            );
            tm.cast_local_ray(&ray, f32::MAX, true).is_some()
        };
        out.push(timed("parry3d TriMesh", &format!("{} triangles, BVH", scene.triangles.len()), scene, &hit));
    }

    // parry3d Voxels on the SVO's own voxels.
    {
        use parry3d::math::{IVector, Vector};
        use parry3d::query::{Ray, RayCast};
        let coords: Vec<IVector> = scene
            .svo
            .at_level(scene.svo.depth)
            .iter()
            .map(|(c, _)| IVector::new(c[0] as i32, c[1] as i32, c[2] as i32))
            .collect();
        let size = scene.svo.bounds.voxel_size(scene.svo.depth);
        let vox = parry3d::shape::Voxels::new(Vector::splat(size), &coords);
        let min = scene.svo.bounds.min.as_dvec3();
        let hit = |o: DVec3, d: DVec3| {
            // The grid's own frame: voxel k covers [k·size, (k+1)·size) from the cube corner.
            let l = o - min;
            let ray = Ray::new(
                Vector::new(l.x as f32, l.y as f32, l.z as f32),
                Vector::new(d.x as f32, d.y as f32, d.z as f32),
            );
            vox.cast_local_ray(&ray, f32::MAX, true).is_some()
        };
        out.push(timed("parry3d Voxels", &format!("the same {} voxels, chunks + BVH", coords.len()), scene, &hit));
    }
    Ok(out)
}
