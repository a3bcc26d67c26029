//! Other ray casters a user might pick, on the same model, camera and threads: Intel Embree
//! (triangle BVH, through the `embree` crate and the system library; one ray at a time, and
//! as coherent streams of 8×8 tiles), parry3d's `TriMesh` (triangle BVH) and parry3d's
//! `Voxels` built from the SVO's own leaf voxels. Each traces the nearest hit of every primary
//! ray of a frame. voxray answers the same queries through its primary-ray API
//! ([`crate::render::primary`]: 8×8 tiles with beams, each tile a packet) on the SVO of the same triangles, and
//! renders whole frames of the default view too. Every caster runs on one thread and on all
//! threads, on several views, the casters' frames in turn (one frame each per round); the hit
//! fraction of each is recorded so a reader can see they trace the same thing.

use super::{summarize, Record};
use crate::backend::Backend;
use crate::render::primary::{trace_tiles, Primary, Todo};
use crate::render::visibility::{FrameInstances, Search};
use crate::render::{Features, RenderOptions};
use crate::scene::Camera;
use crate::session::Session;
use crate::svo::Svo;
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::sync::Arc;
use std::time::Instant;

/// One view the peers are measured on.
pub struct PeerView<'a> {
    /// Short name (`default`, `close-up`, …), the first part of each record's setting.
    pub name: String,
    /// The triangles (positions), in the same space as `svo`.
    pub triangles: &'a [[Vec3; 3]],
    /// The same geometry as one SVO, placed at the identity.
    pub svo: Arc<Svo>,
    /// The camera.
    pub camera: Camera,
    /// Also time voxray's whole frame (trace and shade) on this view.
    pub whole_frame: bool,
}

/// What the peers are measured on.
pub struct PeerScene<'a> {
    /// The views.
    pub views: Vec<PeerView<'a>>,
    /// Thread counts to run every caster with.
    pub threads: Vec<usize>,
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
/// the number of hits.
fn frame(camera: &Camera, hit: &(dyn Fn(DVec3, DVec3) -> bool + Sync)) -> u64 {
    let b = camera.basis();
    (0..camera.height)
        .into_par_iter()
        .map(|y| (0..camera.width).filter(|&x| hit(camera.eye, camera.ray_dir(&b, x, y))).count() as u64)
        .sum()
}

/// How one caster answers a frame: the number of pixels that hit.
type FrameFn<'f> = dyn FnMut() -> Result<u64, crate::Error> + Send + 'f;

struct Timing<'a> {
    view: &'a PeerView<'a>,
    threads: usize,
    warmup: usize,
    frames: usize,
}

/// One caster's frame, with what its record says of it.
struct Caster<'f> {
    name: &'static str,
    kind: &'static str,
    what: String,
    run: Box<FrameFn<'f>>,
}

/// In which order round `f` of a round robin visits `n` casters: from caster `f mod n` on,
/// so that each is timed first, second, … equally often (the one after a slow caster meets
/// its caches cold).
fn round_order(f: usize, n: usize) -> impl Iterator<Item = usize> {
    (0..n).map(move |k| (f + k) % n)
}

/// Times every caster on one pool of `t.threads` threads, frame by frame in turn: round `f`
/// runs one frame of each (warm-up rounds first, untimed). A shared machine's slow spells
/// (another tenant, a frequency drop) then fall on every caster alike instead of on
/// whichever was being timed at the time, so the ratios between them hold from run to run.
fn timed(t: &Timing<'_>, casters: &mut [Caster<'_>]) -> Result<Vec<Record>, crate::Error> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(t.threads)
        .build()
        .map_err(|e| crate::Error::Io { path: "thread pool".into(), source: std::io::Error::other(e.to_string()) })?;
    let n = casters.len();
    let mut times = vec![Vec::new(); n];
    let mut hits = vec![0; n];
    for f in 0..t.warmup + t.frames.max(1) {
        for c in round_order(f, n) {
            let start = Instant::now();
            let h = pool.install(&mut *casters[c].run)?;
            if f >= t.warmup {
                times[c].push(start.elapsed().as_secs_f64() * 1e3);
                hits[c] = h;
            }
        }
    }
    let camera = &t.view.camera;
    let pixels = (camera.width * camera.height) as f64;
    Ok(casters
        .iter()
        .zip(times.iter().zip(hits))
        .map(|(c, (times, hits))| {
            let (median_ms, p95_ms, min_ms) = summarize(times);
            Record {
                group: "peers".into(),
                name: c.name.into(),
                setting: format!("{}: {}; hits {:.1}% of pixels", t.view.name, c.what, 100.0 * hits as f64 / pixels),
                x: t.threads as f64,
                backend_kind: c.kind.into(),
                backend: format!("CPU, {} threads", t.threads),
                width: camera.width,
                height: camera.height,
                warmup: t.warmup,
                frames: t.frames.max(1),
                instances: 1,
                median_ms,
                p95_ms,
                min_ms,
                mrays_per_s: pixels / (median_ms.max(1e-9) * 1e-3) / 1e6,
                ..Record::default()
            }
        })
        .collect())
}

/// Runs voxray and every peer on every view and thread count.
pub fn run(scene: &PeerScene<'_>, progress: &mut dyn FnMut(&str)) -> Result<Vec<Record>, crate::Error> {
    let mut out = Vec::new();
    for view in &scene.views {
        let voxray_scene = super::matrix::static_scene(view.svo.clone())?;
        let svo = &view.svo;
        let voxels = format!("{} voxels (depth {})", svo.voxel_count, svo.depth);
        let tris = format!("{} triangles, BVH", view.triangles.len());
        let peers = Peers::new(view)?;
        let stats = svo.stats();
        for &threads in &scene.threads {
            let t = Timing { view, threads, warmup: scene.warmup, frames: scene.frames };
            progress(&format!("peers: {}, {threads} threads", view.name));
            // voxray's primary-ray API: 8×8 tiles, beams, nearest hit only (no shading), the
            // hit t of every pixel into a buffer made once, as Embree fills its rays' tfar.
            let prepared = crate::render::instances::prepare(&voxray_scene, view.camera.eye, false);
            let fi = FrameInstances { parts: &voxray_scene.parts, prepared: &prepared, bvh: None, starts: None };
            // One instance: the plan's search is the plain one (nothing to cull or sort).
            let primary = Primary {
                instances: fi,
                camera: &view.camera,
                search: Search::Plain,
                opts: Default::default(),
                beams: true,
                bvh_beams: false,
                lists: None,
                moved: &[],
                moved_flags: &[],
                missed_before: &[],
            };
            let mut t_hit = vec![f32::INFINITY; (view.camera.width * view.camera.height) as usize];
            let run = move || {
                trace_tiles(
                    &primary,
                    &mut t_hit,
                    |_| Some(()),
                    |_, _, _, _| Todo::All,
                    |t, hit| *t = hit.map_or(f32::INFINITY, |h| h.0.hit.t),
                    |_| {},
                );
                Ok(t_hit.iter().filter(|t| t.is_finite()).count() as u64)
            };
            let mut casters = Vec::new();
            if view.whole_frame {
                casters.push(whole_frame(&voxray_scene, &view.camera, &voxels));
            }
            casters.push(Caster {
                name: "voxray (trace only)",
                kind: "voxray-trace",
                what: format!("SVO, {voxels}, nearest hit, 8×8 tiles with beams, as packets"),
                run: Box::new(run),
            });
            casters.extend(peers.casters(&view.camera, &tris));
            let mut records = timed(&t, &mut casters)?;
            // voxray's rows carry the size of the octree they traced, as the clip runner's do.
            for r in records.iter_mut().filter(|r| r.backend_kind.starts_with("voxray")) {
                (r.geometry_bytes, r.attribute_bytes) = (stats.geometry_bytes, stats.attribute_bytes);
                (r.svo_bytes, r.voxels) = (stats.geometry_bytes + stats.attribute_bytes, stats.voxels);
            }
            out.extend(records);
        }
    }
    for r in &mut out {
        r.machine = scene.machine.clone();
        r.command = scene.command.clone();
    }
    Ok(out)
}

/// voxray's whole frame (trace + shade into the frame buffer of a session, which keeps it
/// from frame to frame), primary rays only: no reuse, no shadows.
fn whole_frame<'f>(scene: &crate::scene::Scene, camera: &'f Camera, voxels: &str) -> Caster<'f> {
    let scene = scene.clone();
    let mut session = Session::new(Backend::Cpu(Box::default()), "CPU".into());
    let lights = crate::scene::Lights::default();
    let features = Features { hit_buffer: false, shadows: false, ..Features::default() };
    let run = move || -> Result<u64, crate::Error> {
        session.frame(&scene, camera, &lights, &features, &RenderOptions::default(), &|_, _| {})?;
        let frame = session.last_frame().ok_or_else(|| crate::Error::Io {
            path: "bench".into(),
            source: std::io::Error::other("the session kept no frame"),
        })?;
        Ok(frame.instance.iter().filter(|&&i| i >= 0).count() as u64)
    };
    Caster {
        name: "voxray (whole frame)",
        kind: "voxray",
        what: format!("SVO, {voxels}, traced and shaded"),
        run: Box::new(run),
    }
}

/// The peers' acceleration structures for one view, built once.
struct Peers {
    embree: EmbreeScene,
    trimesh: parry3d::shape::TriMesh,
    voxels: parry3d::shape::Voxels,
    voxel_count: usize,
    grid_min: DVec3,
}

/// Embree's device and committed scene. The committed scene borrows the scene, which
/// borrows the device, so both are leaked for the life of the process: a benchmark builds a
/// handful of them.
struct EmbreeScene {
    committed: embree::CommittedScene<'static>,
}

impl EmbreeScene {
    fn new(triangles: &[[Vec3; 3]]) -> Self {
        use cgmath::{Vector3, Vector4};
        let device: &'static embree::Device = Box::leak(Box::new(embree::Device::new()));
        let n = triangles.len();
        let mut mesh = embree::TriangleMesh::unanimated(device, n, 3 * n);
        {
            let mut v = mesh.vertex_buffer.map();
            let mut idx = mesh.index_buffer.map();
            for (i, t) in triangles.iter().enumerate() {
                for k in 0..3 {
                    v[3 * i + k] = Vector4::new(t[k].x, t[k].y, t[k].z, 0.0);
                }
                idx[i] = Vector3::new(3 * i as u32, 3 * i as u32 + 1, 3 * i as u32 + 2);
            }
        }
        let mut geom = embree::Geometry::Triangle(mesh);
        geom.commit();
        let scene: &'static mut embree::Scene<'static> = Box::leak(Box::new(embree::Scene::new(device)));
        scene.attach_geometry(geom);
        let scene: &'static embree::Scene<'static> = scene;
        EmbreeScene { committed: scene.commit() }
    }
}

fn embree_ray(o: DVec3, d: DVec3) -> embree::RayHit {
    use cgmath::Vector3;
    embree::RayHit::new(embree::Ray::new(
        Vector3::new(o.x as f32, o.y as f32, o.z as f32),
        Vector3::new(d.x as f32, d.y as f32, d.z as f32),
    ))
}

impl Peers {
    fn new(view: &PeerView<'_>) -> Result<Self, crate::Error> {
        use parry3d::math::{IVector, Vector};
        let verts: Vec<Vector> =
            view.triangles.iter().flat_map(|t| t.iter().map(|p| Vector::new(p.x, p.y, p.z))).collect();
        let idx: Vec<[u32; 3]> = (0..view.triangles.len() as u32).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect();
        let trimesh = parry3d::shape::TriMesh::new(verts, idx).map_err(|e| crate::Error::Io {
            path: "parry3d TriMesh".into(),
            source: std::io::Error::other(format!("{e:?}")),
        })?;
        let coords: Vec<IVector> = view
            .svo
            .at_level(view.svo.depth)
            .iter()
            .map(|(c, _)| IVector::new(c[0] as i32, c[1] as i32, c[2] as i32))
            .collect();
        let size = view.svo.bounds.voxel_size(view.svo.depth);
        let voxels = parry3d::shape::Voxels::new(Vector::splat(size), &coords);
        Ok(Peers {
            embree: EmbreeScene::new(view.triangles),
            trimesh,
            voxels,
            voxel_count: coords.len(),
            grid_min: view.svo.bounds.min.as_dvec3(),
        })
    }

    /// The peers' frames on `camera`, one caster each.
    fn casters<'f>(&'f self, camera: &'f Camera, tris: &str) -> Vec<Caster<'f>> {
        use parry3d::math::Vector;
        use parry3d::query::{Ray, RayCast};
        let committed = &self.embree.committed;

        let one = move |o: DVec3, d: DVec3| {
            let mut ctx = embree::IntersectContext::coherent();
            let mut rh = embree_ray(o, d);
            committed.intersect(&mut ctx, &mut rh);
            rh.hit.hit()
        };

        // Embree's coherent stream API over the same 8×8 tiles voxray uses.
        let stream = move || -> u64 {
            let b = camera.basis();
            let tiles_x = camera.width.div_ceil(8);
            let tiles = tiles_x * camera.height.div_ceil(8);
            (0..tiles)
                .into_par_iter()
                .map(|k| {
                    let (x0, y0) = ((k % tiles_x) * 8, (k / tiles_x) * 8);
                    let mut rays = Vec::with_capacity(64);
                    for y in y0..(y0 + 8).min(camera.height) {
                        for x in x0..(x0 + 8).min(camera.width) {
                            rays.push(embree_ray(camera.eye, camera.ray_dir(&b, x, y)));
                        }
                    }
                    let mut ctx = embree::IntersectContext::coherent();
                    committed.intersect_stream_aos(&mut ctx, &mut rays);
                    rays.iter().filter(|r| r.hit.hit()).count() as u64
                })
                .sum()
        };

        let tri = move |o: DVec3, d: DVec3| {
            let ray = Ray::new(
                Vector::new(o.x as f32, o.y as f32, o.z as f32),
                Vector::new(d.x as f32, d.y as f32, d.z as f32),
            );
            self.trimesh.cast_local_ray(&ray, f32::MAX, true).is_some()
        };

        let vox = move |o: DVec3, d: DVec3| {
            // The grid's own frame: voxel k covers [k·size, (k+1)·size) from the cube corner.
            let l = o - self.grid_min;
            let ray = Ray::new(
                Vector::new(l.x as f32, l.y as f32, l.z as f32),
                Vector::new(d.x as f32, d.y as f32, d.z as f32),
            );
            self.voxels.cast_local_ray(&ray, f32::MAX, true).is_some()
        };
        vec![
            Caster {
                name: "Embree 3",
                kind: "embree",
                what: format!("{tris}, one ray at a time"),
                run: Box::new(move || Ok(frame(camera, &one))),
            },
            Caster {
                name: "Embree 3 (stream)",
                kind: "embree-stream",
                what: format!("{tris}, coherent 8×8 streams"),
                run: Box::new(move || Ok(stream())),
            },
            Caster {
                name: "parry3d TriMesh",
                kind: "parry-trimesh",
                what: tris.into(),
                run: Box::new(move || Ok(frame(camera, &tri))),
            },
            Caster {
                name: "parry3d Voxels",
                kind: "parry-voxels",
                what: format!("the same {} voxels, chunks + BVH", self.voxel_count),
                run: Box::new(move || Ok(frame(camera, &vox))),
            },
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::voxelize::{Resolution, VoxelizeOptions};

    /// The hit percentage a record's setting ends with.
    fn hits(r: &Record) -> f64 {
        let tail = r.setting.rsplit("hits ").next().unwrap_or("");
        tail.trim_end_matches("% of pixels").parse().unwrap_or(f64::NAN)
    }

    /// Frames alternate between the casters, each in every position of a round equally
    /// often, and every caster gets its warm-up and timed frames (the hits of its last).
    #[test]
    fn casters_are_timed_in_turn() {
        for n in 1..6 {
            let mut position = vec![vec![0; n]; n];
            for f in 0..n {
                let order: Vec<usize> = round_order(f, n).collect();
                let mut sorted = order.clone();
                sorted.sort();
                assert_eq!(sorted, (0..n).collect::<Vec<_>>(), "round {f} of {n}");
                for (k, &c) in order.iter().enumerate() {
                    position[c][k] += 1;
                }
            }
            assert!(position.iter().flatten().all(|&p| p == 1), "{n}: {position:?}");
        }
        let grid = crate::voxelize::VoxelGrid::from_coords(
            1,
            crate::svo::Cube { min: Vec3::ZERO, size: 1.0 },
            [[0, 0, 0]],
            Vec3::ONE,
        );
        let svo = Arc::new(crate::svo::build(&grid).unwrap());
        let camera = Camera::framing(Vec3::ZERO, Vec3::ONE, 4, 2);
        let view = PeerView { name: "one".into(), triangles: &[], svo, camera, whole_frame: false };
        let t = Timing { view: &view, threads: 1, warmup: 2, frames: 3 };
        let log = std::sync::Mutex::new(Vec::new());
        let caster = |c: u64| {
            let log = &log;
            let mut calls = 0;
            Caster {
                name: "fake",
                kind: "fake",
                what: String::new(),
                run: Box::new(move || {
                    log.lock().unwrap().push(c);
                    calls += 1;
                    Ok(calls * 2 + c)
                }),
            }
        };
        let mut casters = vec![caster(0), caster(1), caster(2)];
        let records = timed(&t, &mut casters).unwrap();
        drop(casters);
        let log = log.into_inner().unwrap();
        assert_eq!(log, [0, 1, 2, 1, 2, 0, 2, 0, 1, 0, 1, 2, 1, 2, 0]);
        // 5 calls each: the last returned 10 + c of the 8 pixels.
        let hits: Vec<f64> = records.iter().map(hits).collect();
        assert_eq!(hits, [125.0, 137.5, 150.0]);
        assert!(records.iter().all(|r| r.frames == 3 && r.median_ms >= 0.0));
        // A caster that fails fails the measurement instead of recording a frame.
        let failing = Caster {
            name: "failing",
            kind: "failing",
            what: String::new(),
            run: Box::new(|| Err(crate::Error::Io { path: "x".into(), source: std::io::Error::other("no frame") })),
        };
        assert!(timed(&t, &mut [failing]).is_err());
    }

    /// Every caster traces the same thing: the triangle casters agree with each other, the
    /// voxel casters (voxray's SVO, parry3d's `Voxels` of the same leaves) with each other,
    /// and the voxels cover the triangles' pixels plus at most a silhouette band.
    #[test]
    fn peers_hit_the_same_pixels() {
        let mesh = crate::model::embedded::load_default_car().unwrap();
        let body = mesh.parts.iter().position(|p| p.name == "body").unwrap_or(0);
        let opts = VoxelizeOptions { resolution: Resolution::Depth(8), solid: false };
        let svo = Arc::new(crate::pipeline::build_part(&mesh, body, &opts, None, &|_, _| {}).unwrap().svo);
        let triangles: Vec<[Vec3; 3]> = mesh.parts[body].triangles.iter().map(|t| t.positions).collect();
        let (lo, hi) = super::super::matrix::static_scene(svo.clone()).unwrap().bounds();
        let framed = Camera::framing(lo.as_vec3(), hi.as_vec3(), 96, 64);
        let camera = Camera { eye: framed.target + (framed.eye - framed.target) * 0.5, ..framed };
        let view = PeerView { name: "body".into(), triangles: &triangles, svo, camera, whole_frame: true };
        let scene = PeerScene {
            views: vec![view],
            threads: vec![1],
            warmup: 0,
            frames: 1,
            command: String::new(),
            machine: String::new(),
        };
        let records = run(&scene, &mut |_| {}).unwrap();
        let by = |kind: &str| hits(records.iter().find(|r| r.backend_kind == kind).unwrap());
        let (embree, stream, trimesh) = (by("embree"), by("embree-stream"), by("parry-trimesh"));
        let (voxray, whole, voxels) = (by("voxray-trace"), by("voxray"), by("parry-voxels"));
        eprintln!("hits: Embree {embree}/{stream}, TriMesh {trimesh}, voxray {voxray}/{whole}, Voxels {voxels}");
        assert!(embree > 20.0, "the body should fill a good part of the frame: {embree}%");
        assert_eq!(embree, stream, "Embree's two APIs");
        assert!((embree - trimesh).abs() <= 0.1, "Embree {embree}% vs parry3d TriMesh {trimesh}%");
        assert_eq!(voxray, whole, "voxray's trace-only and whole frame");
        assert!((voxray - voxels).abs() <= 0.2, "voxray {voxray}% vs parry3d Voxels {voxels}%");
        assert!(voxray >= embree && voxray - embree < 8.0, "voxels {voxray}% vs triangles {embree}%");
        // voxray's rows name the octree they traced; the peers' rows hold no octree.
        let stats = scene.views[0].svo.stats();
        for r in &records {
            let want = if r.backend_kind.starts_with("voxray") { stats.voxels } else { 0 };
            assert_eq!(r.voxels, want, "{}", r.name);
            assert_eq!(
                r.svo_bytes,
                if want > 0 { stats.geometry_bytes + stats.attribute_bytes } else { 0 },
                "{}",
                r.name
            );
        }
    }
}
