//! The pictures of docs/gi.md's radiance-cache section: the box lit with `--gi-gather caches`
//! with every cache's position marked over the image (coloured by its normal), and one cache's
//! hemispherical map with its mip pyramid and its irradiance map (exposed so that its
//! brightest texel is white).
//!
//! `cargo run --release --example radiance_caches [OUT_DIR]` (default docs/images) writes
//! `caches-box.png` and `caches-map.png`, and prints how many caches were placed and where
//! the time went.

use glam::{DVec3, Vec3};
use std::path::PathBuf;
use voxray::gi::{render_with_gi, GiCaches, GiSettings};
use voxray::render::radiance_cache::{self, CacheSettings, CacheStages, MapLevel};
use voxray::render::{Features, FramePlan, Gather, RenderOptions};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "docs/images".into()));
    std::fs::create_dir_all(&out)?;
    let scene = voxray::bench::gi::room_scene(7)?;
    let lights = voxray::model::room::lights();
    let camera = voxray::model::room::camera(320, 240);
    let plan = FramePlan::new(&scene, &camera, &lights, &Features::default(), None);
    let settings = CacheSettings::default();
    let gi = GiSettings { gather: Gather::Caches(settings), ..Default::default() };
    let mut caches = GiCaches::new();
    let (frame, stats) =
        render_with_gi(&scene, &camera, &lights, &plan, &RenderOptions::default(), None, &gi, &mut caches, &|_, _| {})?;
    println!(
        "GI {:.0} ms, of which the gather {:.0} ms: {:?}",
        stats.cones_ms + stats.inject_ms,
        stats.cones_ms,
        frame.cache_stages
    );

    // The same caches again, from the frame's G-buffer, to draw them.
    let (_, _, cone, _) = caches.ambient(&lights).ok_or("no GI light")?;
    let basis = camera.basis();
    let w = camera.width as usize;
    let hit = |x: u32, y: u32| {
        let k = y as usize * w + x as usize;
        (frame.instance[k] >= 0).then(|| {
            let d = camera.ray_dir(&basis, x, y);
            (camera.eye + d * frame.t[k] as f64, frame.normal[k].as_dvec3().normalize_or(DVec3::Y))
        })
    };
    let mut stages = CacheStages::default();
    let placed = radiance_cache::build(&settings, &camera, &hit, &cone, &mut stages);
    println!("{} caches on {} tiles", placed.maps.len(), placed.tiles_x * placed.tiles_y);

    let mut img = voxray::render::output::srgb8(&frame);
    for c in &placed.maps {
        let colour = (c.at.normal * 0.5 + 0.5).as_vec3() * 255.0;
        let (cx, cy) = (c.at.pixel.0 as i64, c.at.pixel.1 as i64);
        for dy in -2i64..=2 {
            for dx in -2i64..=2 {
                let (x, y) = (cx + dx, cy + dy);
                if x < 0 || y < 0 || x >= w as i64 || y >= camera.height as i64 {
                    continue;
                }
                let k = 3 * (y as usize * w + x as usize);
                // A dark ring around a dot in the normal's colour.
                let rgb = if dx.abs() == 2 || dy.abs() == 2 { Vec3::ZERO } else { colour };
                img[k..k + 3].copy_from_slice(&[rgb.x as u8, rgb.y as u8, rgb.z as u8]);
            }
        }
    }
    let path = out.join("caches-box.png");
    image::save_buffer(&path, &img, camera.width, camera.height, image::ColorType::Rgb8)?;
    println!("wrote {}", path.display());

    // The cache nearest the image's centre: its map level by level, each blown up to 128²,
    // then its irradiance map.
    let centre = (camera.width as f64 / 2.0, camera.height as f64 / 2.0);
    let dist = |c: &radiance_cache::CacheMap| {
        (c.at.pixel.0 as f64 - centre.0).powi(2) + (c.at.pixel.1 as f64 - centre.1).powi(2)
    };
    let one = placed.maps.iter().min_by(|a, b| dist(a).total_cmp(&dist(b))).ok_or("no cache placed")?;
    let levels: Vec<&MapLevel> = one.mips.iter().chain(std::iter::once(&one.irradiance)).collect();
    let (side, gap) = (128usize, 8usize);
    let width = levels.len() * (side + gap) - gap;
    let mut strip = vec![255u8; width * side * 3];
    // Exposed so that the brightest texel of the finest level is white.
    let peak = one.mips[0].texels.iter().fold(1e-6f32, |m, t| m.max(t.x).max(t.y).max(t.z));
    let srgb = |v: f32| (255.0 * (v / peak).clamp(0.0, 1.0).powf(1.0 / 2.2)) as u8;
    for (i, level) in levels.iter().enumerate() {
        for y in 0..side {
            for x in 0..side {
                let t = level.texels[(y * level.n / side) * level.n + x * level.n / side];
                let k = 3 * (y * width + i * (side + gap) + x);
                strip[k..k + 3].copy_from_slice(&[srgb(t.x), srgb(t.y), srgb(t.z)]);
            }
        }
    }
    let path = out.join("caches-map.png");
    image::save_buffer(&path, &strip, width as u32, side as u32, image::ColorType::Rgb8)?;
    println!(
        "wrote {} (the cache at pixel {:?}, normal {:.2}: levels {}, then the irradiance map)",
        path.display(),
        one.at.pixel,
        one.at.normal,
        one.mips.iter().map(|m| format!("{}²", m.n)).collect::<Vec<_>>().join(", ")
    );
    Ok(())
}
