// A caller's own rays against a scene's instances (cast::SceneCaster's twin, gpu::cast):
// nearest hits (cast_nearest_main) or occlusion within each ray's t_max (cast_occluded_main),
// through the instance searches of search.wgsl. Rays come relative to the point the
// instances were prepared for, with unit directions. Needs layout.wgsl, traverse.wgsl and
// search.wgsl (which declares the scene's bindings).

// Which instance search (render::visibility::Search): 2 cull + sort, 3 BVH.
override SEARCH: u32 = 2u;

// The rays and one result each (bindings of this module alone).
@group(0) @binding(20) var<storage, read> cast_rays: array<RayIn>;
@group(0) @binding(21) var<storage, read_write> cast_hits: array<CastOut>;

// The ray this invocation casts, if any (64 to a workgroup, spread over y past 65 535
// workgroups, as gpu::rays dispatches).
fn cast_index(gid: vec3<u32>) -> u32 {
    return gid.x + gid.y * 65535u * 64u;
}

@compute @workgroup_size(64, 1, 1)
fn cast_nearest_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = cast_index(gid);
    if k >= arrayLength(&cast_rays) {
        return;
    }
    let q = cast_rays[k];
    let best = nearest(q.origin.xyz, q.dir.xyz);
    var out: CastOut;
    out.instance = 0xFFFFFFFFu;
    if best.found {
        out.instance = best.inst;
        out.t = best.tr.t;
        out.level = best.tr.level;
        out.coord = vec4<u32>(best.tr.coord, 0u);
        out.attr = vec4<u32>(best.tr.attr.albedo, best.tr.attr.normal, best.tr.attr.emission, 0u);
        out.face_normal = vec4<f32>(best.tr.face_normal, 0.0);
    }
    cast_hits[k] = out;
}

@compute @workgroup_size(64, 1, 1)
fn cast_occluded_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = cast_index(gid);
    if k >= arrayLength(&cast_rays) {
        return;
    }
    let q = cast_rays[k];
    var out: CastOut;
    out.instance = select(0xFFFFFFFFu, 0u, occluded(q.origin.xyz, q.dir.xyz, q.t_max));
    cast_hits[k] = out;
}
