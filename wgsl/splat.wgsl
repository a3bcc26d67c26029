// Square splats (render::splat): every surface voxel of every drawn instance projected
// through its centre and drawn as a screen-aligned square, the nearest kept per pixel. The
// CPU keeps a 64-bit word (depth bits above, splat number below) with one atomic minimum;
// WGSL has no 64-bit atomics, so the same order is kept in two passes: the nearest depth
// first (splat_depth_main), then the lowest splat number among the squares at that depth
// (splat_id_main). Both store complements with atomicMax, so a buffer cleared to zero is
// empty. splat_resolve_main turns each pixel's winner into the hit record the shading reads.
//
// RenderOptions::splat_draw Quads draws the same squares with the rasterizer instead of the
// first two passes: splat_quad_vertex makes one quad per splat over exactly the pixels whose
// centres splat_square covers, with a depth that orders as the compute passes' key;
// splat_quad_fragment writes the pixel's (key, complemented number) into an Rg32Uint target
// that the depth test keeps nearest-first (ties to the earlier primitive, the lower number);
// splat_copy_main moves that target into splat_depth and splat_ids for the resolve.

@group(2) @binding(B_SPLAT_FRAME) var<uniform> splat_frame: SplatFrame;
@group(2) @binding(B_SPLAT_ENTRIES) var<storage, read> splat_entries: array<SplatEntry>;
@group(2) @binding(B_SPLAT_CENTRES) var<storage, read> splat_centres: array<vec4<f32>>;
@group(2) @binding(B_SPLAT_ATTRS) var<storage, read> splat_attrs: array<Attr>;
@group(2) @binding(B_SPLAT_DEPTH) var<storage, read_write> splat_depth: array<atomic<u32>>;
@group(2) @binding(B_SPLAT_IDS) var<storage, read_write> splat_ids: array<atomic<u32>>;

// The drawn instance whose splat numbers hold `id` (the last entry whose first is <= id).
fn splat_entry_of(id: u32) -> u32 {
    var lo = 0u;
    var hi = splat_frame.entries;
    while hi - lo > 1u {
        let mid = (lo + hi) / 2u;
        if splat_entries[mid].first <= id {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    return lo;
}

// A splat's pixel rectangle (inclusive) and depth key; ok is false when it draws nothing.
struct Square {
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
    key: u32,
    ok: bool,
}

// splat::rasterize's projection of one splat.
fn splat_square(id: u32) -> Square {
    var s: Square;
    s.ok = false;
    let e = splat_entries[splat_entry_of(id)];
    let p = splat_centres[e.base + id - e.first].xyz;
    let c = vec3<f32>(
        dot(e.view_x.xyz, p) + e.view_x.w,
        dot(e.view_y.xyz, p) + e.view_y.w,
        dot(e.view_z.xyz, p) + e.view_z.w,
    );
    let near = splat_frame.near;
    if !(c.z > near) {
        return s;
    }
    let w = f32(splat_frame.width);
    let h = f32(splat_frame.height);
    let tan_half = splat_frame.tan_half;
    let aspect_half = tan_half * splat_frame.aspect;
    let px = (c.x / (c.z * aspect_half) + 1.0) * 0.5 * w;
    let py = (1.0 - c.y / (c.z * tan_half)) * 0.5 * h;
    let half = clamp(e.half_px / c.z, 0.5, w + h);
    // Pixels whose centres lie inside the square.
    let x0 = max(ceil(px - half - 0.5), 0.0);
    let x1 = min(floor(px + half - 0.5), w - 1.0);
    let y0 = max(ceil(py - half - 0.5), 0.0);
    let y1 = min(floor(py + half - 0.5), h - 1.0);
    if !(x0 <= x1 && y0 <= y1) {
        return s;
    }
    let front = max(c.z - e.half_depth, near);
    s.x0 = u32(x0);
    s.x1 = u32(x1);
    s.y0 = u32(y0);
    s.y1 = u32(y1);
    // Positive floats order as their bits; the complement turns the nearest into the largest.
    s.key = ~bitcast<u32>(front);
    s.ok = true;
    return s;
}

fn splat_id(gid: vec3<u32>) -> u32 {
    return gid.y * splat_frame.row_threads + gid.x;
}

@compute @workgroup_size(256, 1, 1)
fn splat_depth_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let id = splat_id(gid);
    if id >= splat_frame.total {
        return;
    }
    let s = splat_square(id);
    if !s.ok {
        return;
    }
    for (var y = s.y0; y <= s.y1; y++) {
        for (var x = s.x0; x <= s.x1; x++) {
            atomicMax(&splat_depth[y * frame.width + x], s.key);
        }
    }
}

@compute @workgroup_size(256, 1, 1)
fn splat_id_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let id = splat_id(gid);
    if id >= splat_frame.total {
        return;
    }
    let s = splat_square(id);
    if !s.ok {
        return;
    }
    for (var y = s.y0; y <= s.y1; y++) {
        for (var x = s.x0; x <= s.x1; x++) {
            let k = y * frame.width + x;
            if atomicLoad(&splat_depth[k]) == s.key {
                atomicMax(&splat_ids[k], ~id);
            }
        }
    }
}

// splat::rasterize's resolve: the pixel's nearest square as a hit record.
@compute @workgroup_size(8, 8, 1)
fn splat_resolve_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= frame.width || gid.y >= frame.height {
        return;
    }
    let idx = gid.y * frame.width + gid.x;
    var h: Hit;
    h.t = BIG;
    h.instance = -1;
    h.reused = 0u;
    h.work = 0u;
    let key = atomicLoad(&splat_depth[idx]);
    if key != 0u {
        let id = ~atomicLoad(&splat_ids[idx]);
        let e = splat_entries[splat_entry_of(id)];
        let a = splat_attrs[e.base + id - e.first];
        let d = ray_dir(gid.x, gid.y);
        let inst = insts[e.instance];
        let to_world = mat3x3<f32>(inst.normal_x.xyz, inst.normal_y.xyz, inst.normal_z.xyz);
        var n = decode_octahedral(a.normal) * to_world;
        n = select(vec3<f32>(0.0), normalize(n), dot(n, n) > 0.0);
        if !(dot(n, n) > 0.5) {
            n = -d;
        }
        if dot(n, d) > 0.0 {
            n = -n;
        }
        let front = bitcast<f32>(~key);
        h.t = front / max(dot(d, frame.forward.xyz), 1e-9);
        h.instance = i32(e.instance);
        h.albedo = a.albedo;
        h.material = a.normal;
        h.emission = a.emission;
        h.voxel = e.voxel;
        h.nx = n.x; h.ny = n.y; h.nz = n.z;
        h.fx = n.x; h.fy = n.y; h.fz = n.z;
    }
    hits[idx] = h;
}

// The quads' colour target (RenderOptions::splat_draw Quads), read by splat_copy_main.
@group(3) @binding(B_SPLAT_RASTER) var splat_raster: texture_2d<u32>;

struct SplatQuad {
    @builtin(position) position: vec4<f32>,
    // The compute passes' depth key and complemented splat number, the same for every corner.
    @location(0) @interpolate(flat) word: vec2<u32>,
}

// A depth in [0, 1) that orders as the key and is as injective: the bits of a positive float
// order as its value, so the front's bits less the near plane's, moved past the subnormals
// (a depth buffer may flush them), are a float in [2^-126, 1) for fronts up to 2^126 times
// the near plane; farther ones (none in a scene of finite size) share the largest depth.
fn splat_quad_depth(key: u32) -> f32 {
    let offset = ~key - bitcast<u32>(splat_frame.near);
    return bitcast<f32>(min(offset, 0x3F000000u - 1u) + 0x00800000u);
}

// Instance `id` is splat number `id`; its six corners (two triangles) span the pixel edges
// around the covered pixel centres, so the rasterizer covers exactly those pixels (their
// centres lie half a pixel inside, whatever its fill rule). A splat that draws nothing gets a
// triangle outside the clip volume.
@vertex
fn splat_quad_vertex(@builtin(vertex_index) v: u32, @builtin(instance_index) id: u32) -> SplatQuad {
    var out: SplatQuad;
    out.word = vec2<u32>(0u, 0u);
    out.position = vec4<f32>(2.0, 2.0, 2.0, 1.0);
    if id >= splat_frame.total {
        return out;
    }
    let s = splat_square(id);
    if !s.ok {
        return out;
    }
    // Corners 0 1 2 / 2 1 3 of the rectangle, bit 0 right, bit 1 down.
    let corner = array<u32, 6>(0u, 1u, 2u, 2u, 1u, 3u)[v % 6u];
    let x = select(f32(s.x0), f32(s.x1 + 1u), (corner & 1u) != 0u);
    let y = select(f32(s.y0), f32(s.y1 + 1u), (corner & 2u) != 0u);
    let w = f32(splat_frame.width);
    let h = f32(splat_frame.height);
    out.position = vec4<f32>(2.0 * x / w - 1.0, 1.0 - 2.0 * y / h, splat_quad_depth(s.key), 1.0);
    out.word = vec2<u32>(s.key, ~id);
    return out;
}

@fragment
fn splat_quad_fragment(in: SplatQuad) -> @location(0) vec2<u32> {
    return in.word;
}

// The quads' winners into the compute passes' buffers (zero where nothing was drawn: the
// target is cleared to zero), so splat_resolve_main reads either the same way.
@compute @workgroup_size(8, 8, 1)
fn splat_copy_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= splat_frame.width || gid.y >= splat_frame.height {
        return;
    }
    let word = textureLoad(splat_raster, vec2<i32>(gid.xy), 0).xy;
    let k = gid.y * splat_frame.width + gid.x;
    atomicStore(&splat_depth[k], word.x);
    atomicStore(&splat_ids[k], word.y);
}
