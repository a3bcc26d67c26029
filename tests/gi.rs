//! GI voxel transformation (CPU reference): split filtering conserves occupancy, a 90°
//! rotation with nearest filtering gives exactly the occupancy of re-voxelizing the rotated
//! triangles, and bad settings give clear errors.

use glam::{DAffine3, DMat3, DQuat, DVec3, Vec3};
use voxray::gi::{Filter, GiError, Volume, VolumeSpec, VoxelCache};
use voxray::mesh::{Material, Part, Triangle};
use voxray::rng::Rng;
use voxray::svo::Cube;
use voxray::voxelize::{voxelize_in, VoxelGrid};

/// An open box with a shelf: faces on integer planes and a slanted shelf, off-centre so a
/// wrong rotation or offset shows.
fn part(transform: impl Fn(Vec3) -> Vec3) -> Part {
    let quad = |a: Vec3, b: Vec3, c: Vec3, d: Vec3| [[a, b, c], [a, c, d]];
    let v = Vec3::new;
    let mut tris = Vec::new();
    for q in [
        quad(v(1.0, 1.0, 1.0), v(9.0, 1.0, 1.0), v(9.0, 1.0, 6.0), v(1.0, 1.0, 6.0)), // floor
        quad(v(1.0, 1.0, 1.0), v(1.0, 7.0, 1.0), v(1.0, 7.0, 6.0), v(1.0, 1.0, 6.0)), // wall
        quad(v(1.0, 1.0, 1.0), v(9.0, 1.0, 1.0), v(9.0, 5.0, 1.0), v(1.0, 5.0, 1.0)), // back
        quad(v(2.3, 2.2, 1.7), v(7.6, 3.9, 1.7), v(7.6, 3.9, 5.1), v(2.3, 2.2, 5.1)), // shelf
    ] {
        for t in q {
            tris.push(Triangle { positions: t.map(&transform), uvs: None, material: 0 });
        }
    }
    Part { name: "box".into(), triangles: tris }
}

fn materials() -> Vec<Material> {
    vec![Material::new("grey", Vec3::splat(0.5))]
}

#[test]
fn split_filtering_conserves_occupancy_for_any_pose() {
    let cube = Cube { min: Vec3::ZERO, size: 16.0 };
    let grid = voxelize_in(&part(|p| p), &materials(), cube, 4, false, &|_, _| {}).unwrap();
    let cache = VoxelCache::from_grid(&grid).unwrap();
    assert!(cache.voxels.len() > 100);
    let spec = VolumeSpec::new(64, DVec3::splat(-40.0), 1.25).unwrap();
    let mut rng = Rng::new(7);
    for _ in 0..20 {
        let axis = DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5).normalize();
        let scale = DVec3::new(0.5 + rng.f64(), 0.5 + rng.f64(), 0.5 + rng.f64());
        let t = DVec3::new(rng.f64() * 20.0 - 10.0, rng.f64() * 20.0 - 10.0, rng.f64() * 20.0 - 10.0);
        let world = DAffine3::from_scale_rotation_translation(scale, DQuat::from_axis_angle(axis, rng.f64() * 6.3), t);
        for filter in [Filter::Split, Filter::Nearest] {
            let mut vol = Volume::new(spec);
            let stats = vol.splat(&cache, &world, filter).unwrap();
            assert_eq!(stats.outside, 0.0, "the pose stays inside the volume");
            let total = vol.total_occupancy();
            let n = cache.voxels.len() as f64;
            assert!((total - n).abs() <= 1e-4 * n, "{filter:?}: total occupancy {total} for {n} voxels");
            assert!(vol.occupancy.iter().all(|o| o.is_finite()) && vol.normal.iter().all(|v| v.is_finite()));
        }
    }
}

#[test]
fn split_weights_land_on_the_eight_neighbours_in_trilinear_proportion() {
    // One voxel whose moved centre sits at cell coordinates (3.25, 4.5, 5.75).
    let grid =
        voxelize_in(&part(|p| p), &materials(), Cube { min: Vec3::ZERO, size: 16.0 }, 4, false, &|_, _| {}).unwrap();
    let mut cache = VoxelCache::from_grid(&grid).unwrap();
    cache.voxels.truncate(1);
    let centre = cache.centre(&cache.voxels[0]).as_dvec3();
    let spec = VolumeSpec::new(16, DVec3::ZERO, 1.0).unwrap();
    let target = DVec3::new(3.25, 4.5, 5.75) + 0.5;
    let world = DAffine3::from_translation(target - centre);
    let mut vol = Volume::new(spec);
    vol.splat(&cache, &world, Filter::Split).unwrap();
    let w = |c: [u32; 3]| vol.occupancy[vol.index(c)];
    assert!((w([3, 4, 5]) - 0.75 * 0.5 * 0.25).abs() < 1e-6);
    assert!((w([4, 5, 6]) - 0.25 * 0.5 * 0.75).abs() < 1e-6);
    assert!((w([3, 5, 6]) - 0.75 * 0.5 * 0.75).abs() < 1e-6);
    assert_eq!(vol.occupied().len(), 8);
}

#[test]
fn a_quarter_turn_with_nearest_filtering_equals_revoxelizing_the_turned_triangles() {
    let mats = materials();
    let cube = Cube { min: Vec3::ZERO, size: 16.0 };
    let grid = voxelize_in(&part(|p| p), &mats, cube, 4, false, &|_, _| {}).unwrap();
    let cache = VoxelCache::from_grid(&grid).unwrap();
    // World volume: cells of 1 unit from (-16, -16, -16), 32 per side.
    let world_cube = Cube { min: Vec3::splat(-16.0), size: 32.0 };
    let spec = VolumeSpec::new(32, DVec3::splat(-16.0), 1.0).unwrap();
    // A quarter turn about y, exact on the triangles: (x, y, z) → (z, y, −x); plus a whole-cell shift.
    let shift = Vec3::new(-3.0, 2.0, 5.0);
    let turned = part(|p| Vec3::new(p.z, p.y, -p.x) + shift);
    let rot = DMat3::from_cols(DVec3::new(0.0, 0.0, -1.0), DVec3::Y, DVec3::new(1.0, 0.0, 0.0));
    let world = DAffine3::from_mat3_translation(rot, shift.as_dvec3());
    assert_eq!(world.transform_point3(DVec3::new(1.0, 2.0, 3.0)), DVec3::new(3.0, 2.0, -1.0) + shift.as_dvec3());
    let mut vol = Volume::new(spec);
    vol.splat(&cache, &world, Filter::Nearest).unwrap();
    let moved: Vec<[u32; 3]> = vol.occupied();
    let revox = voxelize_in(&turned, &mats, world_cube, 5, false, &|_, _| {}).unwrap();
    let mut direct: Vec<[u32; 3]> = revox.coords().collect();
    direct.sort_by_key(|c| (c[2], c[1], c[0]));
    assert_eq!(moved.len(), cache.voxels.len(), "nearest filtering kept voxels apart");
    assert_eq!(moved, direct);
    // Every cell holds exactly one voxel.
    assert!(vol.occupancy.iter().all(|&o| o == 0.0 || o == 1.0));
}

#[test]
fn bad_settings_and_transforms_give_clear_errors() {
    assert!(matches!(VolumeSpec::new(0, DVec3::ZERO, 1.0), Err(GiError::Resolution(0))));
    assert!(matches!(VolumeSpec::new(4096, DVec3::ZERO, 1.0), Err(GiError::Resolution(4096))));
    assert!(VolumeSpec::new(8, DVec3::splat(f64::NAN), 1.0).is_err());
    assert!(VolumeSpec::new(8, DVec3::ZERO, -1.0).is_err());
    assert!(VolumeSpec::following(DVec3::ZERO, f64::INFINITY, 8).is_err());
    assert!("bilinear".parse::<Filter>().unwrap_err().contains("nearest or split"));
    let grid =
        voxelize_in(&part(|p| p), &materials(), Cube { min: Vec3::ZERO, size: 16.0 }, 4, false, &|_, _| {}).unwrap();
    let cache = VoxelCache::from_grid(&grid).unwrap();
    let mut vol = Volume::new(VolumeSpec::new(8, DVec3::ZERO, 1.0).unwrap());
    for bad in [DAffine3::from_scale(DVec3::new(1.0, 0.0, 1.0)), DAffine3::from_translation(DVec3::splat(f64::NAN))] {
        let e = vol.splat(&cache, &bad, Filter::Split).unwrap_err();
        assert!(e.to_string().contains("not finite and invertible"), "{e}");
    }
    assert_eq!(vol.total_occupancy(), 0.0, "a refused transform writes nothing");
    let deep = VoxelGrid::from_coords(11, Cube { min: Vec3::ZERO, size: 16.0 }, [[0, 0, 0]], Vec3::ONE);
    assert!(VoxelCache::from_grid(&deep).unwrap_err().to_string().contains("too deep"));
    assert!(VoxelCache::build(&part(|p| p), &materials(), 11).unwrap_err().to_string().contains("too deep"));
}

#[test]
fn following_volumes_snap_to_whole_cells() {
    let a = VolumeSpec::following(DVec3::new(0.3, 0.0, 0.0), 16.0, 32).unwrap();
    let b = VolumeSpec::following(DVec3::new(0.4, 0.0, 0.0), 16.0, 32).unwrap();
    assert_eq!(a.cell, 0.5);
    assert_eq!((a.min / a.cell).fract(), DVec3::ZERO);
    assert_eq!(a, b, "a small camera move keeps the same cells");
}

fn quad_part(name: &str, y: f32, lo: f32, hi: f32) -> Part {
    let v = |x: f32, z: f32| Vec3::new(x, y, z);
    // Wound so the normal points up (+y).
    let tris = [[v(lo, lo), v(hi, hi), v(hi, lo)], [v(lo, lo), v(lo, hi), v(hi, hi)]];
    Part {
        name: name.into(),
        triangles: tris.iter().map(|t| Triangle { positions: *t, uvs: None, material: 0 }).collect(),
    }
}

#[test]
fn injection_lights_cells_the_sun_sees_and_darkens_those_in_shadow() {
    use std::sync::Arc;
    use voxray::gi::inject;
    use voxray::scene::{Instance, Lights, Scene, Sun, Transform};
    let mats = materials();
    let cube = Cube { min: Vec3::ZERO, size: 16.0 };
    let floor = quad_part("floor", 1.0, 0.0, 10.0);
    let roof = quad_part("roof", 5.0, 2.0, 6.0);
    let grid = |p: &Part| voxelize_in(p, &mats, cube, 4, false, &|_, _| {}).unwrap();
    let (gf, gr) = (grid(&floor), grid(&roof));
    let mut scene =
        Scene::new(vec![Arc::new(voxray::svo::build(&gf).unwrap()), Arc::new(voxray::svo::build(&gr).unwrap())]);
    for part in 0..2 {
        scene.add(Instance { part, parent: None, local: Transform::IDENTITY }).unwrap();
    }
    scene.update().unwrap();
    let mut vol = Volume::new(VolumeSpec::new(16, DVec3::ZERO, 1.0).unwrap());
    for g in [&gf, &gr] {
        vol.splat(&VoxelCache::from_grid(g).unwrap(), &DAffine3::IDENTITY, Filter::Nearest).unwrap();
    }
    // Sun straight above with irradiance π: a lit cell sends out exactly its albedo.
    let pi = std::f32::consts::PI;
    let lights = Lights {
        sun: Some(Sun { to_sun: Vec3::Y, irradiance: Vec3::splat(pi) }),
        ambient: None,
        use_mtl_emitters: false,
        ..Lights::default()
    };
    let inj = inject(&vol, &scene, &lights, 1);
    assert!(inj.shadow_rays > 100);
    let at = |x: u32, y: u32, z: u32| inj.rgba[vol.index([x, y, z])];
    for (x, z) in [(8, 8), (9, 1), (0, 9), (8, 3)] {
        let c = at(x, 1, z);
        let albedo = vol.mean_albedo([x, 1, z]);
        assert_eq!(c.w, 1.0);
        assert!((c.truncate() - albedo).abs().max_element() < 1e-5, "lit ({x}, {z}): {c} vs albedo {albedo}");
    }
    for (x, z) in [(3, 3), (4, 4), (3, 4)] {
        assert_eq!(at(x, 1, z).truncate(), Vec3::ZERO, "({x}, {z}) is under the roof");
        assert_eq!(at(x, 1, z).w, 1.0, "a shadowed surface is still opaque");
    }
    // The roof's top is lit; empty cells stay empty.
    assert!(at(4, 5, 4).x > 0.3);
    assert_eq!(at(12, 12, 12), glam::Vec4::ZERO);
    assert!(inj.rgba.iter().all(|c| c.is_finite()));
    // No sun: nothing is injected (no emitters here), and no shadow rays are traced.
    let dark =
        inject(&vol, &scene, &Lights { sun: None, ambient: None, use_mtl_emitters: false, ..Lights::default() }, 1);
    assert_eq!(dark.shadow_rays, 0);
    assert!(dark.rgba.iter().all(|c| c.truncate() == Vec3::ZERO));
}

#[test]
fn coarse_levels_keep_thin_walls_opaque_and_colours_unchanged() {
    use glam::Vec4;
    use voxray::gi::{levels, Injected};
    let res = 8u32;
    let idx = |x: u32, y: u32, z: u32| (x + res * (y + res * z)) as usize;
    let mut rgba = vec![Vec4::ZERO; 512];
    let colour = Vec3::new(0.2, 0.4, 0.6);
    for y in 0..res {
        for z in 0..res {
            rgba[idx(3, y, z)] = colour.extend(1.0); // a wall one cell thick
        }
    }
    for (x, y, z) in [(6, 0, 0), (7, 0, 0), (6, 1, 0), (7, 1, 0), (6, 0, 1), (7, 0, 1), (6, 1, 1), (7, 1, 1)] {
        rgba[idx(x, y, z)] = (colour * 0.5).extend(0.5); // a solid block, half covered
    }
    rgba[idx(0, 7, 7)] = colour.extend(1.0); // a lone cell
    let inj = Injected { res, cell: 1.0, min: DVec3::ZERO, rgba, shadow_rays: 0 };
    let chain = levels::build(&inj);
    assert_eq!(chain.levels.iter().map(|l| l.res).collect::<Vec<_>>(), [8, 4, 2, 1]);
    for l in &chain.levels {
        let wall_x = 3 >> chain.levels.iter().position(|m| m.res == l.res).unwrap();
        for y in 0..l.res {
            for z in 0..l.res {
                let c = l.rgba[l.index([wall_x, y, z])];
                assert_eq!(c.w, 1.0, "level res {}: wall cell alpha {}", l.res, c.w);
                assert!((c.truncate() - colour).abs().max_element() < 1e-6, "level res {}: colour {c}", l.res);
            }
        }
        assert!(l.rgba.iter().all(|c| c.is_finite() && c.w <= 1.0));
    }
    let l1 = &chain.levels[1];
    // The half-covered solid block: 8 children of alpha ½ → coverage 1, colour kept.
    let block = l1.rgba[l1.index([3, 0, 0])];
    assert_eq!(block.w, 1.0);
    assert!((block.truncate() - colour).abs().max_element() < 1e-6, "{block}");
    // The lone cell: a quarter of the coverage, same colour once un-premultiplied.
    let lone = l1.rgba[l1.index([0, 3, 3])];
    assert_eq!(lone.w, 0.25);
    assert!((lone.truncate() / lone.w - colour).abs().max_element() < 1e-6);
}

/// A 32³ level chain with an opaque wall of colour `c` filling the plane of cells x = 20.
fn wall_levels(c: Vec3) -> voxray::gi::Levels {
    use voxray::gi::{levels, Injected};
    let res = 32u32;
    let mut rgba = vec![glam::Vec4::ZERO; (res as usize).pow(3)];
    for z in 0..res {
        for y in 0..res {
            rgba[(20 + res * (y + res * z)) as usize] = c.extend(1.0);
        }
    }
    levels::build(&Injected { res, cell: 1.0, min: DVec3::ZERO, rgba, shadow_rays: 0 })
}

#[test]
fn cones_see_an_opaque_wall_its_colour_and_the_sky_elsewhere() {
    use voxray::gi::{cone, gather, ConeSettings};
    let c = Vec3::new(0.9, 0.3, 0.1);
    let sky = Vec3::new(0.2, 0.3, 0.4);
    let chain = wall_levels(c);
    let p = DVec3::new(10.5, 16.0, 16.0);
    // One narrow cone straight at the wall: its colour, nearly fully occluded (a wall one cell
    // thick, sampled trilinearly, lets about 6 % through: the method's leak, measured here).
    let r = cone::trace(&chain, p, DVec3::X, DVec3::X, 30f64.to_radians(), f64::INFINITY);
    assert!(r.w > 0.9, "opacity {}", r.w);
    assert!((r.truncate() - c * r.w).abs().max_element() < 0.02, "{r}");
    // The default six 60° cones facing the wall from close enough that the tilted ones meet it
    // inside the volume: all wall.
    let near = DVec3::new(16.5, 16.0, 16.0);
    let (light, open) = gather(&chain, near, DVec3::X, sky, &ConeSettings::default());
    assert!(open < 0.05, "open {open}");
    assert!((light - c).abs().max_element() < 0.06, "{light} vs {c}");
    // Facing away, nothing but sky: exactly the sky and no occlusion.
    let (light, open) = gather(&chain, p, -DVec3::X, sky, &ConeSettings::default());
    assert_eq!(open, 1.0);
    assert!((light - sky).abs().max_element() < 1e-6, "{light}");
    // An empty volume: the sky, whatever the settings.
    let empty = voxray::gi::levels::build(&voxray::gi::Injected {
        res: 8,
        cell: 1.0,
        min: DVec3::ZERO,
        rgba: vec![glam::Vec4::ZERO; 512],
        shadow_rays: 0,
    });
    for cones in [1, 6, 16] {
        let s = ConeSettings { diffuse_cones: cones, ..ConeSettings::default() };
        let (light, open) = gather(&empty, DVec3::splat(4.0), DVec3::Y, sky, &s);
        assert!((light - sky).abs().max_element() < 1e-6 && (open - 1.0).abs() < 1e-6, "{cones} cones: {light} {open}");
    }
}

/// A 32³ chain with an emitting "panel" filling the cells y = 28 and, if `blocker` says so
/// for a cell x, an opaque grey plate in the cells y = 16.
fn panel_levels(blocker: impl Fn(u32) -> bool) -> voxray::gi::Levels {
    use voxray::gi::{levels, Injected};
    let res = 32u32;
    let mut rgba = vec![glam::Vec4::ZERO; (res as usize).pow(3)];
    for z in 0..res {
        for x in 0..res {
            rgba[(x + res * (28 + res * z)) as usize] = glam::Vec4::new(5.0, 4.0, 3.0, 1.0);
            if blocker(x) {
                rgba[(x + res * (16 + res * z)) as usize] = glam::Vec4::new(0.2, 0.2, 0.2, 1.0);
            }
        }
    }
    levels::build(&Injected { res, cell: 1.0, min: DVec3::ZERO, rgba, shadow_rays: 0 })
}

#[test]
fn shadow_cones_see_a_light_past_its_own_cells_and_not_through_a_plate() {
    use voxray::gi::cone::{self, ConeEnd};
    let p = DVec3::new(16.0, 4.0, 16.0);
    // The panel's lower face is 24 cells above the point.
    let end = ConeEnd { distance: 24.0, cos: 1.0 };
    let see = |chain: &voxray::gi::Levels| cone::visibility(chain, p, DVec3::Y, DVec3::Y, 60f64.to_radians(), end);
    let open = panel_levels(|_| false);
    let v = see(&open);
    assert!(v > 0.95, "nothing between the point and the panel, yet visibility {v}");
    // The plain cone runs into the panel's own cells: that is what the end clearance avoids.
    let plain = cone::trace(&open, p, DVec3::Y, DVec3::Y, 60f64.to_radians(), 24.0).w;
    assert!(plain > 0.5, "a cone without the end clearance saw the panel only {plain} opaque");
    let shut = see(&panel_levels(|_| true));
    assert!(shut < 0.1, "a plate across the whole volume lets {shut} through");
    // A plate over half the cone: soft, in between.
    let half = see(&panel_levels(|x| x < 16));
    assert!((0.2..0.8).contains(&half), "a plate over half the cone lets {half} through");
}

#[test]
fn cell_light_samples_are_checked_and_drawn() {
    use voxray::gi::inject::inject_cells;
    assert!(voxray::gi::GiSettings { cell_light_samples: 0, ..Default::default() }.validated().is_err());
    assert!(voxray::gi::GiSettings { cell_light_samples: 1025, ..Default::default() }.validated().is_err());
    let scene = voxray::bench::gi::panel_room_scene(6).unwrap();
    let lights = voxray::model::panel_room::lights();
    let s = voxray::gi::GiSettings { res: 32, ..Default::default() };
    let camera = voxray::model::panel_room::camera(64, 48);
    let mut caches = voxray::gi::GiCaches::new();
    let (spec, levels_of) = voxray::gi::plan_volume(&scene, &camera, &s, &mut caches).unwrap();
    let mut vol = Volume::new(spec);
    for (i, inst) in scene.instances().iter().enumerate() {
        vol.splat(caches.get(&scene.parts[inst.part], levels_of[inst.part]).unwrap(), &scene.world(i), s.filter)
            .unwrap();
    }
    // The panel is the only light: every shadow ray is an emitter sample's, so the rays grow
    // with the samples per cell (a sample facing away traces none).
    let (one, rays_one) = inject_cells(&vol, &scene, &lights, 1);
    let (four, rays_four) = inject_cells(&vol, &scene, &lights, 4);
    assert!(rays_one > 1000 && rays_four > 3 * rays_one && rays_four < 5 * rays_one, "{rays_one} and {rays_four} rays");
    // The same light on average, drawn from other points.
    let total = |v: &[glam::Vec4]| v.iter().map(|c| c.truncate().element_sum()).sum::<f32>();
    assert_ne!(one, four);
    assert!((total(&one) / total(&four) - 1.0).abs() < 0.1, "{} against {}", total(&one), total(&four));
}

#[test]
fn samples_are_quadrilinear() {
    use voxray::gi::cone::{sample, sample_level};
    let chain = wall_levels(Vec3::ONE);
    // At a cell centre, level 0 gives the cell; half-way to the next cell, half of it.
    assert_eq!(sample_level(&chain, 0, DVec3::new(20.5, 3.5, 7.5)).w, 1.0);
    assert!((sample_level(&chain, 0, DVec3::new(21.0, 3.5, 7.5)).w - 0.5).abs() < 1e-6);
    assert_eq!(sample_level(&chain, 0, DVec3::new(25.5, 3.5, 7.5)).w, 0.0);
    // Between levels: the blend of the two trilinear samples.
    let p = DVec3::new(19.3, 10.2, 4.9);
    let (a, b) = (sample_level(&chain, 1, p), sample_level(&chain, 2, p));
    let m = sample(&chain, p, 1.25);
    assert!((m - (a * 0.75 + b * 0.25)).abs().max_element() < 1e-6);
    // Levels beyond the chain clamp to its ends.
    assert_eq!(sample(&chain, p, -3.0), sample_level(&chain, 0, p));
    assert_eq!(sample(&chain, p, 99.0), sample_level(&chain, chain.levels.len() - 1, p));
}

#[test]
fn every_cone_knob_value_gives_finite_light_and_bad_ones_clear_errors() {
    use voxray::gi::{gather, ConeSettings};
    let chain = wall_levels(Vec3::new(0.5, 0.6, 0.7));
    for cones in [1, 2, 3, 6, 16, 64] {
        for aperture in [0.5, 10.0, 60.0, 120.0, 179.5] {
            for n in [DVec3::X, DVec3::Y, DVec3::new(1.0, 1e-12, 0.0), DVec3::ZERO] {
                let s = ConeSettings {
                    diffuse_cones: cones,
                    aperture_deg: aperture,
                    max_distance: 50.0,
                    specular_cone: true,
                }
                .validated()
                .unwrap();
                let (light, open) = gather(&chain, DVec3::new(10.0, 16.0, 16.0), n, Vec3::splat(0.3), &s);
                assert!(
                    light.is_finite() && open.is_finite() && (0.0..=1.0 + 1e-6).contains(&open),
                    "{cones} {aperture} {n}"
                );
            }
        }
    }
    let base = ConeSettings::default();
    for (bad, needle) in [
        (ConeSettings { diffuse_cones: 0, ..base }, "1…64"),
        (ConeSettings { diffuse_cones: 65, ..base }, "1…64"),
        (ConeSettings { aperture_deg: 0.0, ..base }, "aperture"),
        (ConeSettings { aperture_deg: 180.0, ..base }, "aperture"),
        (ConeSettings { aperture_deg: f64::NAN, ..base }, "aperture"),
        (ConeSettings { max_distance: -1.0, ..base }, "distance"),
    ] {
        assert!(bad.validated().unwrap_err().to_string().contains(needle));
    }
}

#[test]
fn caches_from_an_svo_hold_its_voxels_at_every_level() {
    let grid =
        voxelize_in(&part(|p| p), &materials(), Cube { min: Vec3::ZERO, size: 16.0 }, 5, false, &|_, _| {}).unwrap();
    let svo = voxray::svo::build(&grid).unwrap();
    let full = VoxelCache::from_svo(&svo, 5).unwrap();
    assert_eq!(full.voxels.len() as u64, svo.voxel_count);
    let direct = VoxelCache::from_grid(&grid).unwrap();
    let (mut a, mut b): (Vec<_>, Vec<_>) =
        (full.voxels.iter().map(|v| v.coord()).collect(), direct.voxels.iter().map(|v| v.coord()).collect());
    a.sort();
    b.sort();
    assert_eq!(a, b);
    // A coarser level: each voxel's parent, once.
    let coarse = VoxelCache::from_svo(&svo, 3).unwrap();
    let mut parents: Vec<[u32; 3]> = b.iter().map(|c| [c[0] >> 2, c[1] >> 2, c[2] >> 2]).collect();
    parents.sort();
    parents.dedup();
    let mut got: Vec<[u32; 3]> = coarse.voxels.iter().map(|v| v.coord()).collect();
    got.sort();
    assert_eq!(got, parents);
    assert_eq!(coarse.voxel_size, 2.0);
}

#[test]
fn gi_bleeds_a_red_wall_onto_a_white_floor_and_leaves_the_sky_alone() {
    use voxray::gi::{render_with_gi, GiSettings};
    use voxray::mesh::Mesh;
    use voxray::render::{render, Features, FramePlan, RenderOptions};
    use voxray::scene::{Camera, Instance, Lights, Scene, Sun, Transform};
    let v = Vec3::new;
    let tri = |p: [Vec3; 3], material: u32| Triangle { positions: p, uvs: None, material };
    // Floor y = 0 facing up (white), wall x = 4 facing −x (red).
    let floor = Part {
        name: "floor".into(),
        triangles: vec![
            tri([v(0.0, 0.0, 0.0), v(8.0, 0.0, 8.0), v(8.0, 0.0, 0.0)], 0),
            tri([v(0.0, 0.0, 0.0), v(0.0, 0.0, 8.0), v(8.0, 0.0, 8.0)], 0),
        ],
    };
    let wall = Part {
        name: "wall".into(),
        triangles: vec![
            tri([v(4.0, 0.0, 0.0), v(4.0, 4.0, 8.0), v(4.0, 4.0, 0.0)], 1),
            tri([v(4.0, 0.0, 0.0), v(4.0, 0.0, 8.0), v(4.0, 4.0, 8.0)], 1),
        ],
    };
    let mesh = Mesh {
        parts: vec![floor, wall],
        materials: vec![Material::new("white", Vec3::splat(0.8)), Material::new("red", v(0.9, 0.1, 0.1))],
        ..Default::default()
    };
    let parts = voxray::pipeline::build_parts(&mesh, voxray::voxelize::Resolution::Depth(7)).unwrap();
    let mut scene = Scene::new(parts);
    for part in 0..2 {
        scene.add(Instance { part, parent: None, local: Transform::IDENTITY }).unwrap();
    }
    scene.update().unwrap();
    let cam = Camera {
        eye: glam::DVec3::new(0.5, 5.0, 4.0),
        target: glam::DVec3::new(3.0, 0.0, 4.0),
        up: glam::DVec3::Y,
        vfov_deg: 50.0,
        width: 64,
        height: 48,
    };
    let lights = Lights {
        sun: Some(Sun { to_sun: v(-1.0, 1.0, 0.2).normalize(), irradiance: Vec3::splat(3.0) }),
        ..Lights::default()
    };
    let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
    let plain = render(&scene, &cam, &lights, &plan, &RenderOptions::default(), None, &|_, _| {}).unwrap();
    let s = GiSettings { res: 64, extent: Some(12.0), ..GiSettings::default() };
    let mut caches = voxray::gi::GiCaches::new();
    let opts = RenderOptions::default();
    let (lit, stats) = render_with_gi(&scene, &cam, &lights, &plan, &opts, None, &s, &mut caches, &|_, _| {}).unwrap();
    assert!(stats.occupied > 100, "{stats:?}");
    assert!(lit.radiance.iter().all(|c| c.is_finite() && c.min_element() >= 0.0));
    let redness = |f: &voxray::render::Frame| {
        let (mut r, mut g) = (0.0f64, 0.0f64);
        for k in 0..f.radiance.len() {
            if f.instance[k] == 0 {
                r += f.radiance[k].x as f64;
                g += f.radiance[k].y as f64;
            }
        }
        r / g
    };
    let (before, after) = (redness(&plain), redness(&lit));
    println!("floor red/green without GI {before:.3}, with GI {after:.3}; {stats:?}");
    assert!(after > before * 1.05, "floor red/green {before:.3} → {after:.3}: no colour bleeding");
    for k in 0..lit.radiance.len() {
        if lit.instance[k] < 0 {
            assert_eq!(lit.radiance[k], plain.radiance[k], "sky pixel {k} changed");
        }
    }
}

/// A floor under an open sky, voxelized, moved into the volume and traced from: every cone
/// sees the sky. Cones used to sample the floor's own cells (coverage opacity makes them
/// opaque at every level) and a floor measured 0.3 % open at 128³.
#[test]
fn a_floor_under_an_open_sky_does_not_occlude_itself() {
    use voxray::gi::{gather, inject, levels, ConeSettings, Filter, Volume, VolumeSpec, VoxelCache};
    use voxray::scene::{Lights, Scene};
    let v = Vec3::new;
    let tri = |p: [Vec3; 3]| Triangle { positions: p, uvs: None, material: 0 };
    let floor = Part {
        name: "floor".into(),
        triangles: vec![
            tri([v(-1.0, 0.0, -1.0), v(1.0, 0.0, 1.0), v(1.0, 0.0, -1.0)]),
            tri([v(-1.0, 0.0, -1.0), v(-1.0, 0.0, 1.0), v(1.0, 0.0, 1.0)]),
        ],
    };
    let mats = vec![Material::new("white", Vec3::splat(0.8))];
    let sky = v(0.2, 0.3, 0.4);
    let no_light = Lights { sun: None, ambient: None, use_mtl_emitters: false, ..Lights::default() };
    for res in [32u32, 64, 128] {
        for filter in [Filter::Nearest, Filter::Split] {
            let spec = VolumeSpec::following(DVec3::new(0.013, 0.0, -0.007), 2.2, res).unwrap();
            let depth = (2.0 / spec.cell).log2().round() as u32;
            let cache = VoxelCache::build(&floor, &mats, depth).unwrap();
            let mut vol = Volume::new(spec);
            vol.splat(&cache, &glam::DAffine3::IDENTITY, filter).unwrap();
            let chain = levels::build(&inject(&vol, &Scene::new(vec![]), &no_light, 1));
            for p in [DVec3::new(0.1, 0.0, 0.05), DVec3::new(-0.37, 0.0, 0.21)] {
                let (light, open) = gather(&chain, p, DVec3::Y, sky, &ConeSettings::default());
                assert!(open > 0.97, "{res}³ {filter:?} at {p}: open {open}");
                assert!((light - sky).abs().max_element() < 0.02, "{light}");
            }
        }
    }
}

/// Renders the box with GI on the CPU, carrying `caches` between calls.
fn box_gi(
    scene: &voxray::scene::Scene,
    lights: &voxray::scene::Lights,
    caches: &mut voxray::gi::GiCaches,
) -> (Vec<Vec3>, voxray::gi::GiStats) {
    use voxray::render::{Features, FramePlan, RenderOptions};
    let cam = voxray::model::room::camera(32, 24);
    let plan = FramePlan::new(scene, &cam, lights, &Features::default(), None);
    let s = voxray::gi::GiSettings { res: 32, ..Default::default() };
    let opts = RenderOptions::default();
    let (f, stats) =
        voxray::gi::render_with_gi(scene, &cam, lights, &plan, &opts, None, &s, caches, &|_, _| {}).unwrap();
    (f.radiance, stats)
}

#[test]
fn static_frames_reuse_the_volume_and_render_what_a_fresh_frame_renders() {
    use voxray::gi::{GiCaches, GiReuse};
    let mut scene = voxray::bench::gi::room_scene(5).unwrap();
    let lights = voxray::model::room::lights();
    let mut caches = GiCaches::new();
    let (a, sa) = box_gi(&scene, &lights, &mut caches);
    assert_eq!(sa.reuse, GiReuse::Nothing);
    let (b, sb) = box_gi(&scene, &lights, &mut caches);
    assert_eq!(sb.reuse, GiReuse::Levels, "nothing moved, same lights");
    assert_eq!((sb.voxels, sb.occupied), (0, sa.occupied));
    assert_eq!(a, b);
    // Only the lights changed: the volume is kept and lit again.
    let mut dim = lights;
    if let Some(sun) = dim.sun.as_mut() {
        sun.irradiance *= 0.5;
    }
    let (c, sc) = box_gi(&scene, &dim, &mut caches);
    assert_eq!(sc.reuse, GiReuse::Volume);
    assert_ne!(c, a);
    assert_eq!(c, box_gi(&scene, &dim, &mut GiCaches::new()).0, "a re-lit volume equals a fresh one");
    // An instance moved: everything again.
    let t = voxray::scene::Transform { translation: DVec3::new(0.05, 0.0, 0.0), ..voxray::scene::Transform::IDENTITY };
    scene.set_local(scene.instances().len() - 1, t).unwrap();
    scene.update().unwrap();
    let (d, sd) = box_gi(&scene, &dim, &mut caches);
    assert_eq!(sd.reuse, GiReuse::Nothing);
    assert_eq!(d, box_gi(&scene, &dim, &mut GiCaches::new()).0);
}

/// With GI the CPU lights each hit once, with the cones as its ambient term, and a colour kept
/// by the hit buffer is one whose light was kept too: a static second frame keeps colours
/// (the level chain and the cones are the same) and equals a fresh frame; other cones, or GI
/// switched off, keep none and equal fresh frames of their own settings.
#[test]
fn cpu_gi_keeps_colours_only_where_the_light_was_kept() {
    use voxray::gi::{render_with_gi, GiCaches, GiReuse, GiSettings};
    use voxray::render::{render, Features, FramePlan, HitBuffer, RenderOptions};
    let scene = voxray::bench::gi::room_scene(5).unwrap();
    let lights = voxray::model::room::lights();
    let cam = voxray::model::room::camera(32, 24);
    let opts = RenderOptions::default();
    let (mut hits, mut caches) = (HitBuffer::new(), GiCaches::new());
    let fresh = |s: &GiSettings| {
        let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
        render_with_gi(&scene, &cam, &lights, &plan, &opts, None, s, &mut GiCaches::new(), &|_, _| {}).unwrap().0
    };
    let mut frame = |s: Option<&GiSettings>, hits: &mut HitBuffer, first: bool| {
        let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), (!first).then_some(&*hits));
        match s {
            Some(s) => {
                let (f, st) =
                    render_with_gi(&scene, &cam, &lights, &plan, &opts, Some(hits), s, &mut caches, &|_, _| {})
                        .unwrap();
                (f, Some(st))
            }
            None => (render(&scene, &cam, &lights, &plan, &opts, Some(hits), &|_, _| {}).unwrap(), None),
        }
    };
    let s = GiSettings { res: 32, ..Default::default() };
    let (a, _) = frame(Some(&s), &mut hits, true);
    let (b, sb) = frame(Some(&s), &mut hits, false);
    let sb = sb.unwrap();
    assert!(sb.reuse == GiReuse::Levels && sb.reuse_pixels);
    let pixels = (cam.width * cam.height) as u64;
    assert_eq!(b.shade_reused, pixels, "a static frame keeps every colour");
    assert_eq!(a.radiance, b.radiance);
    assert_eq!(b.radiance, fresh(&s).radiance);
    // Other cones: the chain is kept, the pixels' light is not.
    let fewer = GiSettings { cones: voxray::gi::ConeSettings { diffuse_cones: 3, ..s.cones }, ..s };
    let (c, sc) = frame(Some(&fewer), &mut hits, false);
    let sc = sc.unwrap();
    assert!(sc.reuse == GiReuse::Levels && !sc.reuse_pixels);
    assert_eq!(c.shade_reused, 0);
    assert_ne!(c.radiance, b.radiance);
    assert_eq!(c.radiance, fresh(&fewer).radiance);
    // GI off: the kept colours were lit by the cones, not the sky.
    let (d, _) = frame(None, &mut hits, false);
    assert_eq!(d.shade_reused, 0);
    let plain = render(
        &scene,
        &cam,
        &lights,
        &FramePlan::new(&scene, &cam, &lights, &Features::default(), None),
        &opts,
        None,
        &|_, _| {},
    )
    .unwrap();
    assert_eq!(d.radiance, plain.radiance);
}

/// The CPU's GI passes tell a progress hook what they are doing, bounce by bounce, before the
/// pixels (on a large volume they take long enough to need it); a frame that reuses the whole
/// light says nothing.
#[test]
fn gi_passes_report_their_stages() {
    use std::sync::{Arc, Mutex};
    use voxray::render::{Features, FramePlan, RenderOptions};
    let scene = voxray::bench::gi::room_scene(5).unwrap();
    let lights = voxray::model::room::lights();
    let cam = voxray::model::room::camera(16, 12);
    let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
    let s = voxray::gi::GiSettings { res: 32, bounces: 3, ..Default::default() };
    let heard = Arc::new(Mutex::new(Vec::<String>::new()));
    let mut caches = voxray::gi::GiCaches::new();
    let h = heard.clone();
    caches.on_stage(move |what| h.lock().unwrap().push(what.to_string()));
    let frame = |caches: &mut voxray::gi::GiCaches| {
        voxray::gi::render_with_gi(
            &scene,
            &cam,
            &lights,
            &plan,
            &RenderOptions::default(),
            None,
            &s,
            caches,
            &|_, _| {},
        )
        .unwrap()
    };
    let (_, stats) = frame(&mut caches);
    let stages = heard.lock().unwrap().clone();
    let occupied = stats.occupied;
    assert_eq!(
        stages,
        [
            format!("GI: moving {} instances' voxels into the volume", scene.instances().len()),
            format!("GI: injecting light into {occupied} cells"),
            format!("GI: bounce 2 of 3 over {occupied} cells"),
            format!("GI: bounce 3 of 3 over {occupied} cells"),
        ]
    );
    heard.lock().unwrap().clear();
    frame(&mut caches);
    assert!(heard.lock().unwrap().is_empty(), "a static frame reran passes: {:?}", heard.lock().unwrap());
}

/// The half-resolution gather on the box: about a quarter of the cones, the sample pixels'
/// colours exactly the per-pixel gather's, the rest close to them; and the cones' ambient
/// occlusion AOV: open for the sky, darker in the corners than on the open floor.
#[test]
fn half_resolution_gather_and_the_ao_aov_on_the_box() {
    use voxray::gi::{render_with_gi, GiCaches, GiSettings};
    use voxray::render::{Features, FramePlan, Gather, RenderOptions};
    let scene = voxray::bench::gi::room_scene(5).unwrap();
    let lights = voxray::model::room::lights();
    let cam = voxray::model::room::camera(128, 96);
    let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
    let opts = RenderOptions::default();
    let frame = |gather| {
        let s = GiSettings { res: 32, gather, ..Default::default() };
        render_with_gi(&scene, &cam, &lights, &plan, &opts, None, &s, &mut GiCaches::new(), &|_, _| {}).unwrap().0
    };
    let (full, half) = (frame(Gather::Pixels), frame(Gather::Half));
    let hits = full.instance.iter().filter(|&&i| i >= 0).count() as u64;
    assert_eq!(full.gathers, hits);
    assert!(half.gathers < hits / 2, "{} gathers for {hits} hits", half.gathers);
    let (w, mut err, mut n) = (cam.width as usize, 0.0f64, 0);
    for k in 0..full.radiance.len() {
        let (x, y) = (k % w, k / w);
        if x % 2 == 0 && y % 2 == 0 {
            assert_eq!(half.radiance[k], full.radiance[k], "sample pixel ({x}, {y})");
            assert_eq!(half.ao[k], full.ao[k]);
        } else if full.instance[k] >= 0 {
            err += ((half.radiance[k] - full.radiance[k]).length() / full.radiance[k].length().max(1e-3)) as f64;
            n += 1;
        }
    }
    println!("half gather: {} of {hits} gathers, mean relative difference {:.4}", half.gathers, err / n as f64);
    assert!(err / (n as f64) < 0.08, "mean relative difference {}", err / n as f64);
    // AO: one value per pixel in [0, 1], 1 for the sky; some corners are well occluded.
    assert_eq!(full.ao.len(), full.radiance.len());
    assert!(full.ao.iter().all(|a| (0.0..=1.0).contains(a)));
    assert!(full.instance.iter().zip(&full.ao).all(|(&i, &a)| i >= 0 || a == 1.0));
    let hit_ao: Vec<f32> = full.instance.iter().zip(&full.ao).filter(|(&i, _)| i >= 0).map(|(_, &a)| a).collect();
    let (lo, hi) = hit_ao.iter().fold((1.0f32, 0.0f32), |(l, h), &a| (l.min(a), h.max(a)));
    assert!(lo < 0.5 && hi - lo > 0.2, "AO from {lo} to {hi}");
}

/// The flicker measurement on a small clip: the still pixels are found (the ground), the
/// numbers are finite, and nearest filtering's indirect light jumps more from frame to frame
/// than split filtering's (the voxel-transformation paper's claim, docs/accuracy.md).
#[test]
fn split_filtering_flickers_less_than_nearest() {
    let cfg = voxray::bench::gi::AccuracyConfig {
        size: (48, 32),
        depth: 6,
        spp: 1,
        repeats: 1,
        resolutions: vec![],
        cones: vec![],
        bounces: vec![],
        command: String::new(),
        machine: String::new(),
    };
    let records = voxray::bench::gi::flicker(&cfg, &mut |_| {}).unwrap();
    let f: Vec<_> = records.iter().map(|r| r.flicker.unwrap()).collect();
    println!("{f:?}");
    // Nearest and split with the per-pixel gather, split with the half gather and with caches.
    assert_eq!(f.len(), 4);
    assert!(f.iter().all(|f| f.still > 0.2 && f.still < 1.0 && f.change.is_finite() && f.jerk.is_finite()));
    let (nearest, split) = (f[0], f[1]);
    assert!(split.jerk < 0.5 * nearest.jerk, "second difference: split {} vs nearest {}", split.jerk, nearest.jerk);
}

/// The path tracer on the source triangles: the box's image is close to the one traced
/// through its voxels (the same lights and materials; the voxelization moves edges and
/// normals a little), nearly every pixel sees the same part, and a part without triangles
/// is refused with a clear error.
#[test]
fn the_reference_traces_the_source_triangles_too() {
    use voxray::gi::{PathTracer, ReferenceError, ReferenceSettings, TriangleSceneError};
    let scene = voxray::bench::gi::room_scene(6).unwrap();
    let mesh = voxray::model::room::mesh();
    let (cam, lights) = (voxray::model::room::camera(40, 30), voxray::model::room::lights());
    let settings = ReferenceSettings { spp: 16, bounces: Some(1), seed: 3 };
    let frame = |pt: Result<PathTracer, ReferenceError>| {
        let mut pt = pt.unwrap();
        pt.run(&mut |_, _| {});
        pt.frame()
    };
    let voxels = frame(PathTracer::new(&scene, &cam, &lights, settings));
    let triangles = frame(PathTracer::on_triangles(&scene, &mesh, &cam, &lights, settings));
    let n = voxels.radiance.len();
    assert!(triangles.radiance.iter().all(|c| c.is_finite() && c.min_element() >= 0.0));
    let same = voxels.instance.iter().zip(&triangles.instance).filter(|(a, b)| a == b).count();
    assert!(same as f64 >= 0.95 * n as f64, "{same} of {n} pixels see the same part");
    let mean = |f: &voxray::render::Frame| f.radiance.iter().map(|c| c.element_sum()).sum::<f32>() / n as f32;
    let (mv, mt) = (mean(&voxels), mean(&triangles));
    assert!((mv - mt).abs() < 0.1 * mv, "mean radiance: voxels {mv}, triangles {mt}");
    assert_ne!(voxels.radiance, triangles.radiance);
    // A mesh with fewer parts than the scene: the missing part is named.
    let mut short = mesh.clone();
    short.parts.pop();
    let e = PathTracer::on_triangles(&scene, &short, &cam, &lights, settings).err();
    let parts = short.parts.len();
    assert_eq!(e, Some(ReferenceError::Triangles(TriangleSceneError::MissingPart { part: parts, parts })));
}

/// Radiance caches on the box against a path-traced one-bounce reference, beside the
/// per-pixel gather (the same light gathered at every pixel): a few caches and few fallback
/// gathers stand in for every pixel's cones at about the per-pixel gather's error, clustered
/// or evenly placed, and the stage times are reported.
#[test]
fn radiance_caches_light_the_box_about_as_well_as_the_per_pixel_gather() {
    use voxray::gi::{render_with_gi, GiCaches, GiSettings, PathTracer, ReferenceSettings};
    use voxray::render::radiance_cache::{CacheSettings, Placement};
    use voxray::render::{Features, FramePlan, Gather, RenderOptions};
    let scene = voxray::bench::gi::room_scene(5).unwrap();
    let lights = voxray::model::room::lights();
    let cam = voxray::model::room::camera(128, 96);
    let plan = FramePlan::new(&scene, &cam, &lights, &Features::default(), None);
    let opts = RenderOptions::default();
    let frame = |gather| {
        let s = GiSettings { res: 32, gather, ..Default::default() };
        render_with_gi(&scene, &cam, &lights, &plan, &opts, None, &s, &mut GiCaches::new(), &|_, _| {}).unwrap().0
    };
    let mut pt =
        PathTracer::new(&scene, &cam, &lights, ReferenceSettings { spp: 64, bounces: Some(1), seed: 1 }).unwrap();
    pt.run(&mut |_, _| {});
    let reference = pt.frame();
    let rmse = |f: &voxray::render::Frame| {
        let (mut e, mut n) = (0.0f64, 0);
        for (a, b) in f.radiance.iter().zip(&reference.radiance) {
            e += (*a - *b).length_squared() as f64;
            n += 1;
        }
        (e / n as f64).sqrt()
    };
    let full = frame(Gather::Pixels);
    let hits = full.instance.iter().filter(|&&i| i >= 0).count();
    let base = rmse(&full);
    for placement in [Placement::Clustered, Placement::Even] {
        let c = frame(Gather::Caches(CacheSettings { placement, ..Default::default() }));
        let stages = c.cache_stages.expect("the cache gather reports its stages");
        let tiles = cam.width.div_ceil(16) * cam.height.div_ceil(16);
        let e = rmse(&c);
        println!(
            "{placement:?}: {} caches, {} fallback gathers of {hits} hits, RMSE {e:.4} (per pixel {base:.4}), {stages:?}",
            stages.caches, c.gathers
        );
        assert!(stages.caches >= tiles as u64 && stages.caches <= 3 * tiles as u64, "{} caches", stages.caches);
        assert!((c.gathers as usize) < hits / 20, "{} fallback gathers", c.gathers);
        assert!(e < 1.1 * base, "{placement:?}: RMSE {e} against the per-pixel gather's {base}");
        assert!(c.radiance.iter().all(|r| r.is_finite()));
        assert!(c.ao.iter().all(|a| (0.0..=1.0).contains(a)));
    }
}

/// A wall two cells thick across a 16³ volume at x = 8 and 9: the cells at x = 9 (the far
/// side, seen travelling +x) lit `lit`, those at x = 8 dark; both opaque.
fn thick_wall_level(lit: Vec3) -> voxray::gi::levels::Level {
    let res = 16u32;
    let mut rgba = vec![glam::Vec4::ZERO; (res as usize).pow(3)];
    for z in 0..res {
        for y in 0..res {
            rgba[(8 + res * (y + res * z)) as usize] = glam::Vec4::new(0.0, 0.0, 0.0, 1.0);
            rgba[(9 + res * (y + res * z)) as usize] = lit.extend(1.0);
        }
    }
    voxray::gi::levels::Level { res, cell: 1.0, rgba }
}

#[test]
fn anisotropic_levels_keep_a_walls_lit_far_side_behind_its_dark_near_side() {
    use voxray::gi::levels::{build_aniso_from, build_from, face_weights, Chain};
    let lit = Vec3::new(0.8, 0.6, 0.2);
    let iso = build_from(thick_wall_level(lit), DVec3::ZERO);
    let aniso = build_aniso_from(thick_wall_level(lit), DVec3::ZERO);
    assert_eq!(aniso.count(), iso.count());
    for l in 0..iso.count() {
        assert_eq!((aniso.res(l), aniso.cell(l)), (iso.res(l), iso.cell(l)), "level {l}");
    }
    // Level 0 is the injected volume itself, whatever the direction.
    let p = DVec3::new(8.7, 5.5, 5.5);
    assert_eq!(aniso.trilinear_dir(0, p, &face_weights(DVec3::X)), iso.trilinear(0, p));
    // Level 1's cell 4 holds the whole wall; level 2's cell 2 the wall and empty space after
    // it. The isotropic average shows half the lit side to a cone coming from the dark side.
    for (l, x) in [(1usize, 9.0), (2, 10.0)] {
        let centre = DVec3::new(x, 2.5 * iso.cell(l), 2.5 * iso.cell(l));
        let i = iso.trilinear(l, centre);
        assert!(i.w == 1.0 && (i.truncate() - lit * 0.5).abs().max_element() < 1e-6, "level {l}: isotropic {i}");
        // Travelling +x the dark side is in front: opaque and black.
        let from_dark = aniso.trilinear_dir(l, centre, &face_weights(DVec3::X));
        assert_eq!(from_dark, glam::Vec4::new(0.0, 0.0, 0.0, 1.0), "level {l}");
        // Travelling −x the lit side is in front.
        let from_lit = aniso.trilinear_dir(l, centre, &face_weights(-DVec3::X));
        assert!((from_lit - lit.extend(1.0)).abs().max_element() < 1e-6, "level {l}: {from_lit}");
        // Along the wall each column is all dark or all lit, and at level 2 half the columns
        // pass beside the wall.
        let along = aniso.trilinear_dir(l, centre, &face_weights(DVec3::Y));
        let expect = if l == 1 { (lit * 0.5).extend(1.0) } else { (lit * 0.25).extend(0.5) };
        assert!((along - expect).abs().max_element() < 1e-6, "level {l}: {along}");
    }
    // A cone leaving the dark side through the wall: the isotropic chain lets lit light through,
    // the anisotropic one (almost) none.
    let o = DVec3::new(0.5, 8.0, 8.0);
    let through_iso = voxray::gi::cone::trace(&iso, o, DVec3::X, DVec3::X, 90f64.to_radians(), f64::INFINITY);
    let through_aniso = voxray::gi::cone::trace(&aniso, o, DVec3::X, DVec3::X, 90f64.to_radians(), f64::INFINITY);
    assert!(through_aniso.truncate().length() < 0.3 * through_iso.truncate().length(), "{through_iso} {through_aniso}");
}

#[test]
fn a_lone_child_covers_a_quarter_from_every_side_as_in_the_isotropic_chain() {
    use voxray::gi::levels::{coarsen, coarsen_faces};
    let c = glam::Vec4::new(0.4, 0.2, 0.1, 1.0);
    for k in 0..8u32 {
        let faces = coarsen_faces(|_, child| if child == k { c } else { glam::Vec4::ZERO });
        for (f, v) in faces.iter().enumerate() {
            assert_eq!(*v, coarsen(c), "child {k}, face {f}");
        }
    }
    // Eight opaque children: opaque from every side.
    let full = coarsen_faces(|_, _| c);
    assert!(full.iter().all(|v| *v == c), "{full:?}");
}

#[test]
fn anisotropic_gi_settings_keep_to_the_dense_volume() {
    use voxray::gi::shade::VolumeChoice;
    use voxray::gi::{GiSettings, Layout};
    let s = GiSettings { res: 256, anisotropic: true, ..Default::default() };
    assert_eq!(s.layout(), Layout::Dense);
    assert_eq!(GiSettings { anisotropic: false, ..s }.layout(), Layout::Sparse);
    let e = GiSettings { volume: VolumeChoice::Sparse, ..s }.validated().unwrap_err().to_string();
    assert!(e.contains("dense volume"), "{e}");
}
