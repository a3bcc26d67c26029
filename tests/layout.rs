//! Every struct in wgsl/shared/layout.wgsl has the size and field offsets of its Rust twin.
#![cfg(feature = "gpu")]
//! Offsets on the WGSL side follow the WGSL layout rules for the scalar and vector types
//! used there (an unknown type fails the test rather than being guessed).

use std::mem::{offset_of, size_of};
use voxray::gi::CacheVoxel;
use voxray::gpu::layout::*;
use voxray::svo::Attr;

/// (struct name, [(field, WGSL type)]) parsed from WGSL source.
fn wgsl_structs(src: &str) -> Vec<(String, Vec<(String, String)>)> {
    let code: String = src.lines().map(|l| l.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n");
    let mut out = Vec::new();
    let mut rest = code.as_str();
    while let Some(i) = rest.find("struct ") {
        rest = &rest[i + 7..];
        let name = rest[..rest.find('{').unwrap()].trim().to_string();
        let body = &rest[rest.find('{').unwrap() + 1..rest.find('}').unwrap()];
        let fields = body
            .split(',')
            .filter(|f| !f.trim().is_empty())
            .map(|f| {
                let (n, t) = f.split_once(':').expect("field: type");
                (n.trim().to_string(), t.trim().to_string())
            })
            .collect();
        out.push((name, fields));
        rest = &rest[rest.find('}').unwrap() + 1..];
    }
    out
}

/// WGSL (align, size) of a type.
fn align_size(t: &str) -> (usize, usize) {
    match t {
        "u32" | "i32" | "f32" => (4, 4),
        "vec2<f32>" | "vec2<u32>" | "vec2<i32>" => (8, 8),
        "vec3<f32>" | "vec3<u32>" | "vec3<i32>" => (16, 12),
        "vec4<f32>" | "vec4<u32>" | "vec4<i32>" => (16, 16),
        other => panic!("layout test does not know WGSL type {other}"),
    }
}

/// (size, [(field, offset)]) by the WGSL rules.
fn wgsl_layout(fields: &[(String, String)]) -> (usize, Vec<(String, usize)>) {
    let (mut off, mut max_align, mut offs) = (0usize, 1usize, Vec::new());
    for (n, t) in fields {
        let (a, s) = align_size(t);
        off = off.div_ceil(a) * a;
        offs.push((n.clone(), off));
        off += s;
        max_align = max_align.max(a);
    }
    (off.div_ceil(max_align) * max_align, offs)
}

/// (name, size, [(field, offset)]) of a Rust struct.
type RustStruct = (&'static str, usize, Vec<(&'static str, usize)>);

#[test]
fn wgsl_structs_match_rust() {
    let rust: Vec<RustStruct> = vec![
        (
            "Attr",
            size_of::<Attr>(),
            vec![
                ("albedo", offset_of!(Attr, albedo)),
                ("normal", offset_of!(Attr, normal)),
                ("emission", offset_of!(Attr, emission)),
            ],
        ),
        (
            "Part",
            size_of::<GpuPart>(),
            vec![
                ("node_base", offset_of!(GpuPart, node_base)),
                ("mask_base", offset_of!(GpuPart, mask_base)),
                ("attr_base", offset_of!(GpuPart, attr_base)),
                ("depth", offset_of!(GpuPart, depth)),
            ],
        ),
        (
            "Inst",
            size_of::<GpuInstance>(),
            vec![
                ("to_unit_x", offset_of!(GpuInstance, to_unit_x)),
                ("to_unit_y", offset_of!(GpuInstance, to_unit_y)),
                ("to_unit_z", offset_of!(GpuInstance, to_unit_z)),
                ("normal_x", offset_of!(GpuInstance, normal_x)),
                ("normal_y", offset_of!(GpuInstance, normal_y)),
                ("normal_z", offset_of!(GpuInstance, normal_z)),
                ("sphere", offset_of!(GpuInstance, sphere)),
                ("part", offset_of!(GpuInstance, part)),
                ("stretch_size", offset_of!(GpuInstance, stretch_size)),
                ("moved", offset_of!(GpuInstance, moved)),
                ("radius", offset_of!(GpuInstance, radius)),
            ],
        ),
        (
            "Frame",
            size_of::<GpuFrame>(),
            vec![
                ("forward", offset_of!(GpuFrame, forward)),
                ("right", offset_of!(GpuFrame, right)),
                ("up", offset_of!(GpuFrame, up)),
                ("sun_dir", offset_of!(GpuFrame, sun_dir)),
                ("sun_irradiance", offset_of!(GpuFrame, sun_irradiance)),
                ("sky", offset_of!(GpuFrame, sky)),
                ("width", offset_of!(GpuFrame, width)),
                ("height", offset_of!(GpuFrame, height)),
                ("instances", offset_of!(GpuFrame, instances)),
                ("max_level", offset_of!(GpuFrame, max_level)),
                ("moved", offset_of!(GpuFrame, moved)),
                ("bvh_nodes", offset_of!(GpuFrame, bvh_nodes)),
                ("count", offset_of!(GpuFrame, count)),
                ("moved_tiles_x", offset_of!(GpuFrame, moved_tiles_x)),
                ("emitters", offset_of!(GpuFrame, emitters)),
                ("emitter_samples", offset_of!(GpuFrame, emitter_samples)),
                ("lights", offset_of!(GpuFrame, lights)),
                ("keep_colours", offset_of!(GpuFrame, keep_colours)),
                ("moved_bvh_nodes", offset_of!(GpuFrame, moved_bvh_nodes)),
                ("pad4a", offset_of!(GpuFrame, pad4a)),
                ("pad4b", offset_of!(GpuFrame, pad4b)),
                ("pad4c", offset_of!(GpuFrame, pad4c)),
            ],
        ),
        (
            "Light",
            size_of::<GpuLight>(),
            vec![("a", offset_of!(GpuLight, a)), ("b", offset_of!(GpuLight, b)), ("c", offset_of!(GpuLight, c))],
        ),
        (
            "Emitter",
            size_of::<GpuEmitter>(),
            vec![
                ("a", offset_of!(GpuEmitter, a)),
                ("e1", offset_of!(GpuEmitter, e1)),
                ("e2", offset_of!(GpuEmitter, e2)),
                ("normal", offset_of!(GpuEmitter, normal)),
                ("emission", offset_of!(GpuEmitter, emission)),
            ],
        ),
        (
            "BvhNode",
            size_of::<GpuBvhNode>(),
            vec![("lo", offset_of!(GpuBvhNode, lo)), ("hi", offset_of!(GpuBvhNode, hi))],
        ),
        (
            "Hit",
            size_of::<GpuHit>(),
            vec![
                ("t", offset_of!(GpuHit, t)),
                ("instance", offset_of!(GpuHit, instance)),
                ("albedo", offset_of!(GpuHit, albedo)),
                ("voxel", offset_of!(GpuHit, voxel)),
                ("nx", offset_of!(GpuHit, nx)),
                ("ny", offset_of!(GpuHit, ny)),
                ("nz", offset_of!(GpuHit, nz)),
                ("fx", offset_of!(GpuHit, fx)),
                ("fy", offset_of!(GpuHit, fy)),
                ("fz", offset_of!(GpuHit, fz)),
                ("work", offset_of!(GpuHit, work)),
                ("reused", offset_of!(GpuHit, reused)),
                ("material", offset_of!(GpuHit, material)),
                ("emission", offset_of!(GpuHit, emission)),
            ],
        ),
        (
            "MovedSphere",
            size_of::<GpuSphere>(),
            vec![
                ("sphere", offset_of!(GpuSphere, sphere)),
                ("rect", offset_of!(GpuSphere, rect)),
                ("instance", offset_of!(GpuSphere, instance)),
            ],
        ),
        (
            "RayIn",
            size_of::<GpuRay>(),
            vec![
                ("origin", offset_of!(GpuRay, origin)),
                ("dir", offset_of!(GpuRay, dir)),
                ("t_min", offset_of!(GpuRay, t_min)),
                ("t_max", offset_of!(GpuRay, t_max)),
                ("max_level", offset_of!(GpuRay, max_level)),
                ("pad", offset_of!(GpuRay, pad)),
            ],
        ),
        (
            "RayOut",
            size_of::<GpuRayHit>(),
            vec![
                ("t", offset_of!(GpuRayHit, t)),
                ("level", offset_of!(GpuRayHit, level)),
                ("hit", offset_of!(GpuRayHit, hit)),
                ("steps", offset_of!(GpuRayHit, steps)),
                ("coord", offset_of!(GpuRayHit, coord)),
            ],
        ),
        (
            "CastOut",
            size_of::<GpuCastHit>(),
            vec![
                ("instance", offset_of!(GpuCastHit, instance)),
                ("t", offset_of!(GpuCastHit, t)),
                ("level", offset_of!(GpuCastHit, level)),
                ("pad", offset_of!(GpuCastHit, pad)),
                ("coord", offset_of!(GpuCastHit, coord)),
                ("attr", offset_of!(GpuCastHit, attr)),
                ("face_normal", offset_of!(GpuCastHit, face_normal)),
            ],
        ),
        (
            "CacheVoxel",
            size_of::<CacheVoxel>(),
            vec![
                ("coord", offset_of!(CacheVoxel, coord)),
                ("albedo", offset_of!(CacheVoxel, albedo)),
                ("normal", offset_of!(CacheVoxel, normal)),
                ("emission", offset_of!(CacheVoxel, emission)),
            ],
        ),
        (
            "GiJob",
            size_of::<GpuGiJob>(),
            vec![
                ("grid_x", offset_of!(GpuGiJob, grid_x)),
                ("grid_y", offset_of!(GpuGiJob, grid_y)),
                ("grid_z", offset_of!(GpuGiJob, grid_z)),
                ("normal_x", offset_of!(GpuGiJob, normal_x)),
                ("normal_y", offset_of!(GpuGiJob, normal_y)),
                ("normal_z", offset_of!(GpuGiJob, normal_z)),
                ("voxel_base", offset_of!(GpuGiJob, voxel_base)),
                ("voxel_count", offset_of!(GpuGiJob, voxel_count)),
                ("first_thread", offset_of!(GpuGiJob, first_thread)),
                ("pad", offset_of!(GpuGiJob, pad)),
            ],
        ),
        (
            "SplatEntry",
            size_of::<GpuSplatEntry>(),
            vec![
                ("view_x", offset_of!(GpuSplatEntry, view_x)),
                ("view_y", offset_of!(GpuSplatEntry, view_y)),
                ("view_z", offset_of!(GpuSplatEntry, view_z)),
                ("first", offset_of!(GpuSplatEntry, first)),
                ("base", offset_of!(GpuSplatEntry, base)),
                ("count", offset_of!(GpuSplatEntry, count)),
                ("instance", offset_of!(GpuSplatEntry, instance)),
                ("half_px", offset_of!(GpuSplatEntry, half_px)),
                ("half_depth", offset_of!(GpuSplatEntry, half_depth)),
                ("voxel", offset_of!(GpuSplatEntry, voxel)),
                ("pad", offset_of!(GpuSplatEntry, pad)),
            ],
        ),
        (
            "SplatFrame",
            size_of::<GpuSplatFrame>(),
            vec![
                ("entries", offset_of!(GpuSplatFrame, entries)),
                ("total", offset_of!(GpuSplatFrame, total)),
                ("row_threads", offset_of!(GpuSplatFrame, row_threads)),
                ("near", offset_of!(GpuSplatFrame, near)),
                ("width", offset_of!(GpuSplatFrame, width)),
                ("height", offset_of!(GpuSplatFrame, height)),
                ("tan_half", offset_of!(GpuSplatFrame, tan_half)),
                ("aspect", offset_of!(GpuSplatFrame, aspect)),
            ],
        ),
        (
            "GiSplat",
            size_of::<GpuGiSplat>(),
            vec![
                ("res", offset_of!(GpuGiSplat, res)),
                ("jobs", offset_of!(GpuGiSplat, jobs)),
                ("threads", offset_of!(GpuGiSplat, threads)),
                ("row_threads", offset_of!(GpuGiSplat, row_threads)),
                ("nearest", offset_of!(GpuGiSplat, nearest)),
                ("mark", offset_of!(GpuGiSplat, mark)),
                ("pad1", offset_of!(GpuGiSplat, pad1)),
                ("pad2", offset_of!(GpuGiSplat, pad2)),
            ],
        ),
        (
            "GiFrame",
            size_of::<GpuGiFrame>(),
            vec![
                ("min_cell", offset_of!(GpuGiFrame, min_cell)),
                ("offsets_a", offset_of!(GpuGiFrame, offsets_a)),
                ("offsets_b", offset_of!(GpuGiFrame, offsets_b)),
                ("offsets_c", offset_of!(GpuGiFrame, offsets_c)),
                ("res_a", offset_of!(GpuGiFrame, res_a)),
                ("res_b", offset_of!(GpuGiFrame, res_b)),
                ("res_c", offset_of!(GpuGiFrame, res_c)),
                ("res", offset_of!(GpuGiFrame, res)),
                ("levels", offset_of!(GpuGiFrame, levels)),
                ("cones", offset_of!(GpuGiFrame, cones)),
                ("bounces", offset_of!(GpuGiFrame, bounces)),
                ("spread", offset_of!(GpuGiFrame, spread)),
                ("tilt", offset_of!(GpuGiFrame, tilt)),
                ("max_distance", offset_of!(GpuGiFrame, max_distance)),
                ("cells", offset_of!(GpuGiFrame, cells)),
                ("row_threads", offset_of!(GpuGiFrame, row_threads)),
                ("top_res", offset_of!(GpuGiFrame, top_res)),
                ("tex_size", offset_of!(GpuGiFrame, tex_size)),
                ("specular_cone", offset_of!(GpuGiFrame, specular_cone)),
                ("bricks", offset_of!(GpuGiFrame, bricks)),
                ("half", offset_of!(GpuGiFrame, half)),
                ("half_width", offset_of!(GpuGiFrame, half_width)),
                ("caches", offset_of!(GpuGiFrame, caches)),
                ("cache_tile", offset_of!(GpuGiFrame, cache_tile)),
                ("cache_res", offset_of!(GpuGiFrame, cache_res)),
                ("cache_radius", offset_of!(GpuGiFrame, cache_radius)),
                ("cache_per_tile", offset_of!(GpuGiFrame, cache_per_tile)),
                ("cache_tiles_x", offset_of!(GpuGiFrame, cache_tiles_x)),
                ("cache_slots", offset_of!(GpuGiFrame, cache_slots)),
                ("cache_stride", offset_of!(GpuGiFrame, cache_stride)),
                ("cache_placement", offset_of!(GpuGiFrame, cache_placement)),
                ("cache_spread", offset_of!(GpuGiFrame, cache_spread)),
                ("cache_row_threads", offset_of!(GpuGiFrame, cache_row_threads)),
                ("cell_samples", offset_of!(GpuGiFrame, cell_samples)),
                ("tail", offset_of!(GpuGiFrame, tail)),
            ],
        ),
        (
            "GiLevelStep",
            size_of::<GpuGiLevelStep>(),
            vec![
                ("src_offset", offset_of!(GpuGiLevelStep, src_offset)),
                ("src_res", offset_of!(GpuGiLevelStep, src_res)),
                ("dst_offset", offset_of!(GpuGiLevelStep, dst_offset)),
                ("dst_res", offset_of!(GpuGiLevelStep, dst_res)),
                ("bricks", offset_of!(GpuGiLevelStep, bricks)),
                ("row_threads", offset_of!(GpuGiLevelStep, row_threads)),
                ("src_faces", offset_of!(GpuGiLevelStep, src_faces)),
                ("pad1", offset_of!(GpuGiLevelStep, pad1)),
            ],
        ),
        (
            "GiTri",
            size_of::<GpuGiTri>(),
            vec![
                ("a", offset_of!(GpuGiTri, a)),
                ("b", offset_of!(GpuGiTri, b)),
                ("c", offset_of!(GpuGiTri, c)),
                ("emission", offset_of!(GpuGiTri, emission)),
            ],
        ),
        (
            "CrowdCar",
            size_of::<GpuCrowdCar>(),
            vec![
                ("origin_hi", offset_of!(GpuCrowdCar, origin_hi)),
                ("origin_lo", offset_of!(GpuCrowdCar, origin_lo)),
                ("spin", offset_of!(GpuCrowdCar, spin)),
                ("travel", offset_of!(GpuCrowdCar, travel)),
                ("pad0", offset_of!(GpuCrowdCar, pad0)),
                ("pad1", offset_of!(GpuCrowdCar, pad1)),
                ("inst_a", offset_of!(GpuCrowdCar, inst_a)),
                ("inst_b", offset_of!(GpuCrowdCar, inst_b)),
                ("part_a", offset_of!(GpuCrowdCar, part_a)),
                ("part_b", offset_of!(GpuCrowdCar, part_b)),
            ],
        ),
        (
            "CrowdPart",
            size_of::<GpuCrowdPart>(),
            vec![
                ("box_centre", offset_of!(GpuCrowdPart, box_centre)),
                ("box_half", offset_of!(GpuCrowdPart, box_half)),
                ("cube_min", offset_of!(GpuCrowdPart, cube_min)),
            ],
        ),
        (
            "CrowdFrame",
            size_of::<GpuCrowdFrame>(),
            vec![
                ("eye_hi", offset_of!(GpuCrowdFrame, eye_hi)),
                ("eye_lo", offset_of!(GpuCrowdFrame, eye_lo)),
                ("spin", offset_of!(GpuCrowdFrame, spin)),
                ("lap_spin", offset_of!(GpuCrowdFrame, lap_spin)),
                ("cars", offset_of!(GpuCrowdFrame, cars)),
                ("pad", offset_of!(GpuCrowdFrame, pad)),
            ],
        ),
        (
            "RefitLevel",
            size_of::<GpuRefitLevel>(),
            vec![
                ("first", offset_of!(GpuRefitLevel, first)),
                ("count", offset_of!(GpuRefitLevel, count)),
                ("pad0", offset_of!(GpuRefitLevel, pad0)),
                ("pad1", offset_of!(GpuRefitLevel, pad1)),
            ],
        ),
    ];
    let parsed = wgsl_structs(include_str!("../wgsl/shared/layout.wgsl"));
    assert_eq!(parsed.len(), rust.len(), "every WGSL struct needs a Rust twin in this test");
    for (name, size, fields) in rust {
        let (_, wfields) = parsed.iter().find(|(n, _)| n == name).unwrap_or_else(|| panic!("{name} missing in WGSL"));
        let (wsize, woffs) = wgsl_layout(wfields);
        assert_eq!(wsize, size, "{name}: size");
        let woffs: Vec<(&str, usize)> = woffs.iter().map(|(n, o)| (n.as_str(), *o)).collect();
        assert_eq!(woffs, fields, "{name}: fields and offsets");
    }
}

#[test]
fn layout_rules_are_applied() {
    // A vec3 after a scalar aligns to 16 and the struct rounds up to its alignment.
    let f = |v: &[(&str, &str)]| v.iter().map(|(a, b)| (a.to_string(), b.to_string())).collect::<Vec<_>>();
    assert_eq!(wgsl_layout(&f(&[("a", "u32"), ("b", "vec3<f32>")])), (32, vec![("a".into(), 0), ("b".into(), 16)]));
    assert_eq!(wgsl_layout(&f(&[("a", "vec3<f32>"), ("b", "f32")])).0, 16);
}

#[test]
fn shared_constants_come_from_rust_once() {
    use voxray::gpu::prelude::{prelude, shared};
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("wgsl");
    let mut all = String::new();
    // The passes and, in wgsl/shared/, the includes they share.
    let files: Vec<_> = [dir.clone(), dir.join("shared")]
        .iter()
        .flat_map(|d| std::fs::read_dir(d).unwrap().map(|e| e.unwrap().path()))
        .filter(|p| p.extension().is_some_and(|x| x == "wgsl"))
        .collect();
    assert!(files.len() > 10, "{} shader files", files.len());
    for path in files {
        let src = std::fs::read_to_string(&path).unwrap();
        for (name, _, _) in shared() {
            let defined = src.lines().any(|l| l.trim_start().starts_with(&format!("const {name}:")));
            assert!(!defined, "{} defines {name} itself; it comes from src/gpu/prelude.rs", path.display());
        }
        all += &src;
    }
    let p = prelude();
    for (name, ty, value) in shared() {
        assert!(p.contains(&format!("const {name}: {ty} = {value};")), "{name} missing from the prelude");
        assert!(all.contains(name), "no shader uses {name}");
        if ty == "f32" {
            // The literal reads back as exactly the Rust value's f32.
            assert!(value.parse::<f32>().is_ok_and(|v| v.is_finite()), "{name} = {value}");
        }
    }
    assert!(p.contains(&format!("const MAX_DEPTH: u32 = {}u;", voxray::svo::MAX_DEPTH)));
    assert!(p.contains(&format!("const PARALLEL_RATIO: f32 = {:?};", voxray::ray::PARALLEL_RATIO)));
}

/// The tracer's bind groups are numbered once, in Rust (`gpu::prelude::binding`): its shaders
/// name every binding by the prelude's constant, each constant once.
#[test]
fn tracer_bindings_are_named_from_rust() {
    use voxray::gpu::prelude::binding::ALL;
    let src = [
        include_str!("../wgsl/shared/search.wgsl"),
        include_str!("../wgsl/trace.wgsl"),
        include_str!("../wgsl/gi_trace.wgsl"),
        include_str!("../wgsl/splat.wgsl"),
    ]
    .concat();
    let bindings: Vec<&str> = src.lines().filter(|l| l.trim_start().starts_with("@group(")).collect();
    assert_eq!(bindings.len(), ALL.len(), "{bindings:#?}");
    // (group, number) of each binding, read from the line that names its constant.
    let mut slots = Vec::new();
    for (name, number) in ALL {
        let lines: Vec<&&str> = bindings.iter().filter(|l| l.contains(&format!("@binding({name})"))).collect();
        assert_eq!(lines.len(), 1, "{name} binds {} variables", lines.len());
        let group = lines[0].trim_start()["@group(".len()..].split(')').next().unwrap().to_string();
        slots.push((group, number));
    }
    // Within a group, no two numbers are the same.
    let n = slots.len();
    slots.sort();
    slots.dedup();
    assert_eq!(slots.len(), n, "two bindings share a group and number");
}
