// Square splats (render::splat): every surface voxel of every drawn instance projected
// through its centre and drawn as a screen-aligned square, the nearest kept per pixel. The
// CPU keeps a 64-bit word (depth bits above, splat number below) with one atomic minimum;
// WGSL has no 64-bit atomics, so the same order is kept in two passes: the nearest depth
// first (splat_depth_main), then the lowest splat number among the squares at that depth
// (splat_id_main). Both store complements with atomicMax, so a buffer cleared to zero is
// empty. splat_resolve_main turns each pixel's winner into the hit record the shading reads.

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
    let w = f32(frame.width);
    let h = f32(frame.height);
    let tan_half = frame.forward.w;
    let aspect_half = tan_half * frame.right.w;
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
