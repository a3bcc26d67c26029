//! Constants the Rust code and the WGSL shaders share, written once: every shader source
//! starts with [`prelude`], generated here from the Rust constants, and no `.wgsl` file
//! defines them itself (`tests/layout.rs` checks both).

/// Binding numbers of the tracer's bind groups (`wgsl/trace.wgsl` group 0,
/// `wgsl/gi_trace.wgsl` group 1): WGSL reads them as `B_<name>` from the prelude.
pub mod binding {
    /// Tracer group 0: `nodes`.
    pub const NODES: u32 = 0;
    /// Tracer group 0: `attrs`.
    pub const ATTRS: u32 = 1;
    /// Tracer group 0: `parts`.
    pub const PARTS: u32 = 2;
    /// Tracer group 0: `insts`.
    pub const INSTS: u32 = 3;
    /// Tracer group 0: `frame`.
    pub const FRAME: u32 = 4;
    /// Tracer group 0: `bvh`.
    pub const BVH: u32 = 5;
    /// Tracer group 0: `bvh_items`.
    pub const BVH_ITEMS: u32 = 6;
    /// Tracer group 0: `hits`.
    pub const HITS: u32 = 7;
    /// Tracer group 0: `moved`.
    pub const MOVED: u32 = 8;
    /// Tracer group 0: `radiance`.
    pub const RADIANCE: u32 = 9;
    /// Tracer group 0: `nodes_hi`.
    pub const NODES_HI: u32 = 10;
    /// Tracer group 0: `attrs_hi`.
    pub const ATTRS_HI: u32 = 11;
    /// Tracer group 0: `stats`.
    pub const STATS: u32 = 12;
    /// Tracer group 0: `emitters`.
    pub const EMITTERS: u32 = 13;
    /// Tracer group 0: `lights`.
    pub const LIGHTS: u32 = 14;
    /// Tracer group 0: `moved_bins`.
    pub const MOVED_BINS: u32 = 15;
    /// Tracer group 0: `moved_bvh`.
    pub const MOVED_BVH: u32 = 16;
    /// Tracer group 0: `moved_bvh_items`.
    pub const MOVED_BVH_ITEMS: u32 = 17;
    /// Tracer group 1 (GI): `gi_accum`.
    pub const GI_ACCUM: u32 = 0;
    /// Tracer group 1 (GI): `gi_levels`.
    pub const GI_LEVELS: u32 = 1;
    /// Tracer group 1 (GI): `gi`.
    pub const GI_FRAME: u32 = 2;
    /// Tracer group 1 (GI): `gi_direct`.
    pub const GI_DIRECT: u32 = 3;
    /// Tracer group 1 (GI): `gi_next`.
    pub const GI_NEXT: u32 = 4;
    /// Tracer group 1 (GI): `gi_top`.
    pub const GI_TOP: u32 = 5;
    /// Tracer group 1 (GI): `gi_brick_top`.
    pub const GI_BRICK_TOP: u32 = 6;
    /// Tracer group 1 (GI): `gi_tex`.
    pub const GI_TEX: u32 = 7;
    /// Tracer group 1 (GI): `gi_sampler`.
    pub const GI_SAMPLER: u32 = 8;
    /// Tracer group 1 (GI): `gi_samples` (the half-resolution gather's samples).
    pub const GI_SAMPLES: u32 = 9;
    /// Tracer group 1 (GI): `gi_cache_points` (the radiance caches' points and normals).
    pub const GI_CACHE_POINTS: u32 = 10;
    /// Tracer group 1 (GI): `gi_cache_maps` (their maps, mips and irradiance maps).
    pub const GI_CACHE_MAPS: u32 = 11;
    /// Tracer group 2 (splats): `splat_frame`.
    pub const SPLAT_FRAME: u32 = 0;
    /// Tracer group 2: `splat_entries`.
    pub const SPLAT_ENTRIES: u32 = 1;
    /// Tracer group 2: `splat_centres`.
    pub const SPLAT_CENTRES: u32 = 2;
    /// Tracer group 2: `splat_attrs`.
    pub const SPLAT_ATTRS: u32 = 3;
    /// Tracer group 2: `splat_depth`.
    pub const SPLAT_DEPTH: u32 = 4;
    /// Tracer group 2: `splat_ids`.
    pub const SPLAT_IDS: u32 = 5;
    /// Tracer group 3 (the splat quads' copy): `splat_raster`.
    pub const SPLAT_RASTER: u32 = 0;
    /// Every binding with its WGSL constant's name.
    pub const ALL: [(&str, u32); 37] = [
        ("B_NODES", NODES),
        ("B_ATTRS", ATTRS),
        ("B_PARTS", PARTS),
        ("B_INSTS", INSTS),
        ("B_FRAME", FRAME),
        ("B_BVH", BVH),
        ("B_BVH_ITEMS", BVH_ITEMS),
        ("B_HITS", HITS),
        ("B_MOVED", MOVED),
        ("B_RADIANCE", RADIANCE),
        ("B_NODES_HI", NODES_HI),
        ("B_ATTRS_HI", ATTRS_HI),
        ("B_STATS", STATS),
        ("B_EMITTERS", EMITTERS),
        ("B_LIGHTS", LIGHTS),
        ("B_MOVED_BINS", MOVED_BINS),
        ("B_MOVED_BVH", MOVED_BVH),
        ("B_MOVED_BVH_ITEMS", MOVED_BVH_ITEMS),
        ("B_GI_ACCUM", GI_ACCUM),
        ("B_GI_LEVELS", GI_LEVELS),
        ("B_GI_FRAME", GI_FRAME),
        ("B_GI_DIRECT", GI_DIRECT),
        ("B_GI_NEXT", GI_NEXT),
        ("B_GI_TOP", GI_TOP),
        ("B_GI_BRICK_TOP", GI_BRICK_TOP),
        ("B_GI_TEX", GI_TEX),
        ("B_GI_SAMPLER", GI_SAMPLER),
        ("B_GI_SAMPLES", GI_SAMPLES),
        ("B_GI_CACHE_POINTS", GI_CACHE_POINTS),
        ("B_GI_CACHE_MAPS", GI_CACHE_MAPS),
        ("B_SPLAT_FRAME", SPLAT_FRAME),
        ("B_SPLAT_ENTRIES", SPLAT_ENTRIES),
        ("B_SPLAT_CENTRES", SPLAT_CENTRES),
        ("B_SPLAT_ATTRS", SPLAT_ATTRS),
        ("B_SPLAT_DEPTH", SPLAT_DEPTH),
        ("B_SPLAT_IDS", SPLAT_IDS),
        ("B_SPLAT_RASTER", SPLAT_RASTER),
    ];
}

/// The shared constants: WGSL name, WGSL type and value (as a WGSL literal).
pub fn shared() -> Vec<(&'static str, &'static str, String)> {
    let u = |v: u64| format!("{v}u");
    // Debug prints the shortest text that reads back as the same f32.
    let f = |v: f32| format!("{v:?}");
    let mut v = vec![
        ("MAX_DEPTH", "u32", u(crate::svo::MAX_DEPTH as u64)),
        ("PARALLEL_RATIO", "f32", f(crate::ray::PARALLEL_RATIO)),
        ("MAX_UNIT_ORIGIN", "f32", f(crate::ray::MAX_UNIT_ORIGIN)),
        ("MOVED_SEARCH_MAX", "u32", u(crate::render::hitbuffer::MOVED_SEARCH_MAX as u64)),
        ("TILE", "u32", u(crate::render::beam::TILE as u64)),
        ("FIX", "f32", f(super::gi::FIX as f32)),
        ("EMIT_FIX", "f32", f(super::gi::EMIT_FIX as f32)),
        ("GI_MAX_EMISSION", "f32", f(crate::gi::volume::GI_MAX_EMISSION)),
        ("OUT_FIX", "f32", f(super::gi::OUT_FIX as f32)),
        ("STRIDE", "u32", u(super::gi::STRIDE as u64)),
        ("GI_BRICK", "u32", u(crate::gi::sparse::BRICK as u64)),
        ("GI_BRICK_LEVELS", "u32", u(crate::gi::sparse::BRICK_LEVELS as u64)),
        ("GI_EMPTY", "u32", u(crate::gi::sparse::EMPTY as u64)),
        ("GI_CLEARANCE", "f32", f(crate::gi::cone::CLEARANCE as f32)),
        ("GI_MAX_TAIL_RATIO", "f32", f(crate::gi::shade::MAX_TAIL_RATIO as f32)),
        ("GI_SAME_NORMAL", "f32", f(crate::render::gather::SAME_NORMAL)),
        ("CAR_PATH_A", "f32", f(crate::scene::car::PATH_A as f32)),
        ("CAR_PATH_PERIOD", "f32", f(crate::scene::car::PATH_PERIOD as f32)),
        ("CAR_DOOR_PERIOD", "f32", f(crate::scene::car::DOOR_PERIOD as f32)),
        ("CAR_DOOR_OPEN", "f32", f(crate::scene::car::DOOR_OPEN as f32)),
        ("CAR_STEER_MAX", "f32", f(crate::scene::car::STEER_MAX as f32)),
        ("CAR_STEERING_RATIO", "f32", f(crate::scene::car::STEERING_RATIO as f32)),
        ("CAR_WHEELBASE", "f32", f(crate::model::car::WHEELBASE)),
        ("CAR_WHEEL_RADIUS", "f32", f(crate::model::car::WHEEL_RADIUS)),
        ("CAR_ARC_STEPS", "u32", u(crate::scene::car::ARC_STEPS as u64)),
        ("SPHERE_PAD", "f32", f(crate::render::instances::SPHERE_PAD as f32)),
    ];
    v.extend(binding::ALL.iter().map(|&(name, b)| (name, "u32", u(b as u64))));
    // Word index of each statistic in the `stats` buffer (GpuStats).
    use super::layout::GpuStats;
    use std::mem::offset_of;
    v.extend(
        [
            ("STAT_REUSED", offset_of!(GpuStats, reused)),
            ("STAT_MOVED_ONLY", offset_of!(GpuStats, moved_only)),
            ("STAT_INSTANCES_TRACED", offset_of!(GpuStats, instances_traced)),
            ("STAT_SPHERES_CULLED", offset_of!(GpuStats, spheres_culled)),
            ("STAT_SHADOW_RAYS", offset_of!(GpuStats, shadow_rays)),
            ("STAT_GATHERS", offset_of!(GpuStats, gathers)),
            ("STAT_SHADE_REUSED", offset_of!(GpuStats, shade_reused)),
        ]
        .map(|(name, off)| (name, "u32", u(off as u64 / 4))),
    );
    v
}

/// The WGSL that every shader source starts with.
pub fn prelude() -> String {
    let mut s =
        String::from("// Generated from the Rust constants (src/gpu/prelude.rs); not defined in any .wgsl file.\n");
    for (name, ty, value) in shared() {
        s += &format!("const {name}: {ty} = {value};\n");
    }
    s
}
