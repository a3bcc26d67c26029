//! The square-splat renderer against its own geometry and against the ray tracer: one voxel
//! covers the pixels its square should, splats and rays see the same instance everywhere but
//! near silhouettes (one pixel against the background; at seams between parts at one depth a
//! voxel's projection, here two pixels), voxels behind the eye draw nothing, and degenerate
//! cameras give no NaN.

use glam::{DVec3, Vec3};
use std::sync::Arc;
use voxray::pipeline::build_parts;
use voxray::render::{render, Features, Frame, FramePlan, RenderOptions, Renderer};
use voxray::scene::{Camera, Instance, Lights, Scene, Transform};
use voxray::svo::{build, Cube};
use voxray::voxelize::{Resolution, VoxelGrid};

fn frame(scene: &Scene, camera: &Camera, renderer: Renderer) -> Frame {
    let lights = Lights::default();
    let features = Features { hit_buffer: false, ..Features::default() };
    let plan = FramePlan::new(scene, camera, &lights, &features, None);
    let opts = RenderOptions { renderer, ..RenderOptions::default() };
    render(scene, camera, &lights, &plan, &opts, None, &|_, _| {}).expect("renders")
}

/// One voxel: a unit cube at the origin (an SVO of depth 1 whose one voxel is the cube's
/// lower octant, so the SVO's cube is [−1, 1]³ and the voxel [−1, 0]³ — moved to be centred).
fn one_voxel() -> Scene {
    let grid = VoxelGrid::from_coords(1, Cube { min: Vec3::splat(-0.5), size: 2.0 }, [[0, 0, 0]], Vec3::splat(0.5));
    let mut scene = Scene::new(vec![Arc::new(build(&grid).unwrap())]);
    scene.add(Instance { part: 0, parent: None, local: Transform::IDENTITY }).unwrap();
    scene.update().unwrap();
    scene
}

#[test]
fn one_voxel_covers_the_pixels_of_its_square() {
    let scene = one_voxel();
    // Face-on from 10 units along +z, 64×64, 30° field of view.
    let camera = Camera {
        eye: DVec3::new(0.0, 0.0, 10.0),
        target: DVec3::ZERO,
        up: DVec3::Y,
        vfov_deg: 30.0,
        width: 64,
        height: 64,
    };
    let f = frame(&scene, &camera, Renderer::Splat);
    // The square: side = edge · focal / z about the centre's projection (the image centre).
    let focal = 64.0 / (2.0 * (15f64.to_radians()).tan());
    let half = 0.5 * voxray::render::splat::DEFAULT_FACTOR as f64 * focal / 10.0;
    let (c, mut covered) = (32.0, 0);
    for y in 0..64 {
        for x in 0..64 {
            let inside = ((x as f64 + 0.5) - c).abs() <= half && ((y as f64 + 0.5) - c).abs() <= half;
            let hit = f.instance[y * 64 + x] == 0;
            assert_eq!(hit, inside, "pixel ({x}, {y})");
            covered += hit as usize;
            if hit {
                // t: the voxel's near side (z = 0.5) along the pixel's ray.
                let d = camera.ray_dir(&camera.basis(), x as u32, y as u32);
                let want = 9.5 / d.dot(DVec3::new(0.0, 0.0, -1.0));
                assert!((f.t[y * 64 + x] as f64 - want).abs() < 1e-4, "t {} vs {want}", f.t[y * 64 + x]);
                assert!(f.radiance[y * 64 + x].is_finite());
            }
        }
    }
    assert!(covered > 100, "{covered} pixels");
    // The ray tracer sees the same voxel on the same pixels but for its border.
    let t = frame(&scene, &camera, Renderer::Trace);
    let differ = (0..64 * 64).filter(|&k| (t.instance[k] == 0) != (f.instance[k] == 0)).count();
    let border = (4.0 * 2.0 * half) as usize + 4;
    assert!(differ <= border, "{differ} pixels differ (border {border})");
}

#[test]
fn voxels_behind_the_eye_draw_nothing_and_degenerate_cameras_give_no_nan() {
    let scene = one_voxel();
    // Looking away from the voxel, from just beside it.
    let away = Camera {
        eye: DVec3::new(0.0, 0.0, 2.0),
        target: DVec3::new(0.0, 0.0, 5.0),
        up: DVec3::Y,
        vfov_deg: 90.0,
        width: 32,
        height: 32,
    };
    let f = frame(&scene, &away, Renderer::Splat);
    assert!(f.instance.iter().all(|&i| i < 0), "nothing behind the eye is drawn");
    // The eye inside the voxel, a needle of a field of view, a 1×1 image, a wide angle.
    let cameras = [
        Camera {
            eye: DVec3::new(0.1, 0.0, 0.0),
            target: DVec3::new(0.0, 0.0, -5.0),
            up: DVec3::Y,
            vfov_deg: 60.0,
            width: 24,
            height: 16,
        },
        Camera {
            eye: DVec3::new(0.0, 0.0, 10.0),
            target: DVec3::ZERO,
            up: DVec3::Y,
            vfov_deg: 1e-3,
            width: 8,
            height: 8,
        },
        Camera {
            eye: DVec3::new(0.0, 0.0, 10.0),
            target: DVec3::ZERO,
            up: DVec3::Y,
            vfov_deg: 30.0,
            width: 1,
            height: 1,
        },
        Camera {
            eye: DVec3::new(0.0, 0.0, 1e-7 + 0.5),
            target: DVec3::ZERO,
            up: DVec3::Y,
            vfov_deg: 179.0,
            width: 16,
            height: 9,
        },
    ];
    for c in cameras {
        let f = frame(&scene, &c, Renderer::Splat);
        assert!(f.radiance.iter().all(|r| r.is_finite()), "{c:?}");
        assert!(f.t.iter().all(|t| !t.is_nan()), "{c:?}");
    }
}

#[test]
fn splats_and_rays_see_the_same_instances_but_at_silhouettes() {
    let parts = build_parts(&voxray::model::car::mesh(), Resolution::Depth(6)).unwrap();
    let mut scene = Scene::new(parts);
    for part in 0..scene.parts.len() {
        scene.add(Instance { part, parent: None, local: Transform::IDENTITY }).unwrap();
    }
    scene.update().unwrap();
    let (lo, hi) = scene.bounds();
    // Voxels of the depth-6 car are about a pixel across at this size.
    let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), 96, 64);
    let (t, s) = (frame(&scene, &camera, Renderer::Trace), frame(&scene, &camera, Renderer::Splat));
    let (w, h) = (96usize, 64usize);
    // Whether the traced image changes instance within `r` pixels of (x, y).
    let near_edge = |x: usize, y: usize, r: usize| {
        let k = y * w + x;
        (y.saturating_sub(r)..(y + r + 1).min(h))
            .flat_map(|yy| (x.saturating_sub(r)..(x + r + 1).min(w)).map(move |xx| (xx, yy)))
            .any(|(xx, yy)| t.instance[yy * w + xx] != t.instance[k])
    };
    let (mut differ, mut outside, mut off_one) = (0, Vec::new(), 0);
    for y in 0..h {
        for x in 0..w {
            let k = y * w + x;
            if t.instance[k] == s.instance[k] {
                continue;
            }
            differ += 1;
            off_one += !near_edge(x, y, 1) as usize;
            // Off every silhouette and seam by more than a voxel's projection (here under
            // two pixels): a square is no longer standing in for its cube there.
            if !near_edge(x, y, 2) {
                outside.push((x, y, t.instance[k], s.instance[k]));
            }
        }
    }
    let covered = t.instance.iter().filter(|&&i| i >= 0).count();
    assert!(covered > 500, "the car fills much of the view ({covered} pixels)");
    assert!(
        outside.is_empty(),
        "{} of {differ} differing pixels are off a silhouette: {:?}",
        outside.len(),
        &outside[..outside.len().min(8)]
    );
    // Against the background every difference is within one pixel; at seams between parts at
    // nearly one depth (a door in the body) a square can win the depth test a pixel further in.
    assert!(
        off_one <= differ / 10 + 1,
        "{off_one} of {differ} differing pixels are more than a pixel off a silhouette"
    );
    assert!(differ < covered / 4, "{differ} differing pixels of {covered}");
}

/// An instance whose bounding sphere holds the eye (the ground under a clip's camera) is
/// splatted at full detail, not as its whole cube at level 0 (which once covered the screen).
#[test]
fn an_instance_around_the_eye_is_splatted_in_full() {
    let parts = build_parts(&voxray::model::car::mesh(), Resolution::Depth(5)).unwrap();
    let st = voxray::scene::stage_cars(&parts, 1, true, true).unwrap();
    let camera = Camera::framing(st.bounds.0.as_vec3(), st.bounds.1.as_vec3(), 64, 40);
    let (t, s) = (frame(&st.scene, &camera, Renderer::Trace), frame(&st.scene, &camera, Renderer::Splat));
    let sky = t.instance.iter().filter(|&&i| i < 0).count();
    assert!(sky > 100, "the traced view shows sky ({sky} pixels)");
    let differ = t.instance.iter().zip(&s.instance).filter(|(a, b)| a != b).count();
    assert!(differ < t.instance.len() / 20, "{differ} of {} pixels differ", t.instance.len());
}
