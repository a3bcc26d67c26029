// The GI passes that need the tracer: light injection (gi::inject: one thread per stored
// volume cell, with a shadow ray through the SVO instances) and shading with voxel cone tracing
// (gi::cone and gi::shade::apply). Appended to trace.wgsl; its bindings are group 1.
// Positions are camera-relative, as everywhere in trace.wgsl. Needs gi_fixed.wgsl.
// Both layouts of the world volume: dense (cell i at its grid position) and, with GI_SPARSE,
// the sparse one (gi::sparse: cells stored in 8³ bricks found through a top table; levels 0-2
// per brick, the top table's level and coarser ones dense).

override GI_SPARSE: bool = false;
// LevelStore::Texture: cones read the chain from gi_tex with the sampler's quadrilinear
// filtering (border: transparent black, as outside the volume is empty).
override GI_TEXTURE: bool = false;

@group(1) @binding(B_GI_ACCUM) var<storage, read> gi_accum: array<u32>;
@group(1) @binding(B_GI_LEVELS) var<storage, read_write> gi_levels: array<vec4<f32>>;
@group(1) @binding(B_GI_FRAME) var<uniform> gi: GiFrame;
// With more than one bounce: the injected (direct) level 0, kept across bounces, and the next
// bounce's level 0 (written apart from the chain its cones read). One-element placeholders
// otherwise.
@group(1) @binding(B_GI_DIRECT) var<storage, read_write> gi_direct: array<vec4<f32>>;
@group(1) @binding(B_GI_NEXT) var<storage, read_write> gi_next: array<vec4<f32>>;
// Sparse: the brick of each top cell (GI_EMPTY for none) and the top cell of each brick.
// One-element placeholders when dense.
@group(1) @binding(B_GI_TOP) var<storage, read> gi_top: array<u32>;
@group(1) @binding(B_GI_BRICK_TOP) var<storage, read> gi_brick_top: array<u32>;

// The half-resolution gather's samples (render::gather): the diffuse light of pixel (2i, 2j)
// in xyz, its open fraction in w where it is a hit (−1: no sample). A one-element placeholder
// unless gi.half.
@group(1) @binding(B_GI_SAMPLES) var<storage, read_write> gi_samples: array<vec4<f32>>;

// The level chain as a 3D texture with mips (a 1³ placeholder unless GI_TEXTURE).
@group(1) @binding(B_GI_TEX) var gi_tex: texture_3d<f32>;
@group(1) @binding(B_GI_SAMPLER) var gi_sampler: sampler;

// GI_EMPTY (a top cell without a brick) and GI_BRICK_LEVELS (8³, 4³, 2³) come from the
// prelude (src/gpu/prelude.rs).

// The stored cell of this thread of a cell pass, or GI_EMPTY past the last.
fn gi_thread_cell(gid: vec3<u32>) -> u32 {
    let i = gid.x + gid.y * gi.row_threads;
    // A sparse pool is dispatched whole; only its allocated bricks hold cells.
    let n = select(gi.cells, min(gi.cells, gi.bricks * 512u), GI_SPARSE);
    return select(GI_EMPTY, i, i < n);
}

// Grid coordinates of stored cell i.
fn gi_cell_coord(i: u32) -> vec3<u32> {
    if GI_SPARSE {
        let t = gi_brick_top[i / 512u];
        let k = i % 512u;
        let tc = vec3<u32>(t % gi.top_res, (t / gi.top_res) % gi.top_res, t / (gi.top_res * gi.top_res));
        return tc * 8u + vec3<u32>(k % 8u, (k / 8u) % 8u, k / 64u);
    }
    let r = gi.res;
    return vec3<u32>(i % r, (i / r) % r, i / (r * r));
}

fn gi_put_injected(i: u32, v: vec4<f32>) {
    gi_levels[i] = v;
    if gi.bounces > 1u {
        gi_direct[i] = v;
    }
}

// GI_CLEARANCE (gi::cone::CLEARANCE) comes from the prelude.

// One cell of the accumulation volume, decoded: occupancy, mean albedo, summed normal.
struct GiCell {
    occ: f32,
    albedo: vec3<f32>,
    n: vec3<f32>,
}

fn gi_cell(i: u32) -> GiCell {
    let base = i * STRIDE;
    var c: GiCell;
    c.occ = f32(gi_accum[base]) / FIX;
    let a = vec3<f32>(f32(gi_accum[base + 1u]), f32(gi_accum[base + 2u]), f32(gi_accum[base + 3u]));
    c.albedo = select(vec3<f32>(0.0), a / (FIX * c.occ), c.occ > 0.0);
    c.n = vec3<f32>(
        f32(bitcast<i32>(gi_accum[base + 4u])),
        f32(bitcast<i32>(gi_accum[base + 5u])),
        f32(bitcast<i32>(gi_accum[base + 6u])),
    ) / FIX;
    return c;
}

@compute @workgroup_size(64, 1, 1)
fn inject_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gi_thread_cell(gid);
    if i == GI_EMPTY {
        return;
    }
    let base = i * STRIDE;
    let cell = gi_cell(i);
    let occ = cell.occ;
    if occ <= 0.0 {
        gi_put_injected(i, vec4<f32>(0.0));
        return;
    }
    let albedo = cell.albedo;
    let n = cell.n;
    var radiance = vec3<f32>(0.0);
    if frame.sun_dir.w > 0.0 && dot(n, n) > 1e-6 {
        let nn = normalize(n);
        let cosv = dot(nn, frame.sun_dir.xyz);
        if cosv > 0.0 {
            let cell = gi.min_cell.w;
            // One cell off the surface so the cell's own voxels do not shadow it.
            let start = gi.min_cell.xyz + (vec3<f32>(gi_cell_coord(i)) + 0.5) * cell + nn * cell;
            if !occluded(start, frame.sun_dir.xyz, BIG) {
                radiance += albedo * frame.sun_irradiance.xyz * (cosv / 3.14159265);
            }
        }
    }
    if frame.lights > 0u && dot(n, n) > 1e-6 {
        // gi::inject::inject_cells: the other suns, points and spots.
        let nn = normalize(n);
        let cell = gi.min_cell.w;
        let at = gi.min_cell.xyz + (vec3<f32>(gi_cell_coord(i)) + 0.5) * cell;
        for (var k = 0u; k < frame.lights; k++) {
            let inc = incident(k, at);
            let cosv = dot(nn, inc.to_light);
            if max(inc.irradiance.x, max(inc.irradiance.y, inc.irradiance.z)) > 0.0 && cosv > 0.0 {
                if !occluded(at + nn * cell, inc.to_light, inc.distance) {
                    radiance += albedo * inc.irradiance * (cosv / 3.14159265);
                }
            }
        }
    }
    if frame.emitters > 0u && frame.emitter_samples > 0u && dot(n, n) > 1e-6 {
        // gi::inject::inject_cells: the emitters sampled from the cell, keyed by its place in
        // the grid (gi::inject::cell_key).
        let nn = normalize(n);
        let cell = gi.min_cell.w;
        let c = gi_cell_coord(i);
        let at = gi.min_cell.xyz + (vec3<f32>(c) + 0.5) * cell;
        radiance += emitter_light(c.x + gi.res * (c.y + gi.res * c.z), at, at + nn * cell, nn, -nn, albedo, 0u);
    } else if frame.sky.w > 0.0 && frame.emitter_samples == 0u {
        let e = vec3<f32>(f32(gi_accum[base + 7u]), f32(gi_accum[base + 8u]), f32(gi_accum[base + 9u]));
        radiance += e / (EMIT_FIX * occ);
    }
    let alpha = min(occ, 1.0);
    gi_put_injected(i, vec4<f32>(radiance * alpha, alpha));
}

// Entry l of the 12 per-level values GiFrame packs into three vec4s (offsets, resolutions).
fn gi_per_level(a: vec4<u32>, b: vec4<u32>, c: vec4<u32>, l: u32) -> u32 {
    if l < 4u {
        return a[l];
    }
    if l < 8u {
        return b[l - 4u];
    }
    return c[l - 8u];
}

// Index in gi_levels of cell c (inside) of level l, or GI_EMPTY where a sparse volume
// stores nothing.
fn gi_level_index(l: u32, c: vec3<u32>, r: u32, off: u32) -> u32 {
    if GI_SPARSE && l < GI_BRICK_LEVELS {
        let side = 8u >> l;
        let t = c / side;
        let b = gi_top[t.x + gi.top_res * (t.y + gi.top_res * t.z)];
        if b == GI_EMPTY {
            return GI_EMPTY;
        }
        let k = c % side;
        return off + b * side * side * side + k.x + side * (k.y + side * k.z);
    }
    return off + c.x + r * (c.y + r * c.z);
}

// cone::sample_level: trilinear, cell centres hold the values, outside is empty.
fn gi_sample_level(l: u32, p: vec3<f32>) -> vec4<f32> {
    let cell = gi.min_cell.w * f32(1u << l);
    let g = (p - gi.min_cell.xyz) / cell - 0.5;
    let base = floor(g);
    let f = g - base;
    let b = vec3<i32>(base);
    let r = i32(gi_per_level(gi.res_a, gi.res_b, gi.res_c, l));
    let off = gi_per_level(gi.offsets_a, gi.offsets_b, gi.offsets_c, l);
    var out = vec4<f32>(0.0);
    for (var k = 0u; k < 8u; k++) {
        let d = vec3<u32>(k & 1u, (k >> 1u) & 1u, k >> 2u);
        let c = b + vec3<i32>(d);
        if any(c < vec3<i32>(0)) || any(c >= vec3<i32>(r)) {
            continue;
        }
        let idx = gi_level_index(l, vec3<u32>(c), u32(r), off);
        if idx == GI_EMPTY {
            continue;
        }
        let w3 = select(1.0 - f, f, d == vec3<u32>(1u));
        out += gi_levels[idx] * (w3.x * w3.y * w3.z);
    }
    return out;
}

// cone::sample: quadrilinear.
fn gi_sample(p: vec3<f32>, level: f32) -> vec4<f32> {
    let top = f32(gi.levels - 1u);
    let l = clamp(level, 0.0, top);
    if GI_TEXTURE {
        let uvw = (p - gi.min_cell.xyz) / (gi.min_cell.w * f32(gi.tex_size));
        return textureSampleLevel(gi_tex, gi_sampler, uvw, l);
    }
    let lo = u32(floor(l));
    let hi = min(lo + 1u, gi.levels - 1u);
    let f = l - f32(lo);
    let a = gi_sample_level(lo, p);
    if f == 0.0 || hi == lo {
        return a;
    }
    return a * (1.0 - f) + gi_sample_level(hi, p) * f;
}

// cone::trace: one cone from a surface point; (radiance, opacity).
fn gi_trace(origin: vec3<f32>, normal: vec3<f32>, dir: vec3<f32>, spread: f32) -> vec4<f32> {
    let cell0 = gi.min_cell.w;
    let end = min(gi.max_distance, cell0 * f32(gi.res) * 1.75);
    let max_level = f32(max(i32(gi.levels) - 3, 0));
    let lift = cell0;
    let o = origin + normal * lift;
    let cosv = max(dot(dir, normal), 0.05);
    var c = vec3<f32>(0.0);
    var a = 0.0;
    var t = max((GI_CLEARANCE * (cell0 + cell0) - lift) / cosv, cell0);
    // Every step is at least half a cell and the march ends at the volume's diagonal; the
    // count bound only guards against a non-finite input.
    for (var steps = 0u; t < end && a < 0.99 && steps < 8192u; steps++) {
        let diameter = max(spread * t, cell0);
        let clear_size = (lift + t * cosv - GI_CLEARANCE * cell0) / GI_CLEARANCE;
        let clear_level = floor(log2(max(clear_size / cell0, 1.0)));
        let level = min(min(log2(diameter / cell0), clear_level), max_level);
        let s = gi_sample(o + dir * t, level);
        let sa = clamp(s.w, 0.0, 1.0);
        if sa > 0.0 {
            c += (1.0 - a) * s.xyz * (sa / s.w);
            a += (1.0 - a) * sa;
        }
        t += cell0 * exp2(level) * 0.5;
    }
    return vec4<f32>(c, a);
}

// cone::gather: cosine-weighted cones (one along the normal, a ring around it); the sky fills
// what they do not see. w: the cosine-weighted fraction of the cones that escaped (ambient
// occlusion).
fn gi_gather(p: vec3<f32>, n: vec3<f32>) -> vec4<f32> {
    let sky = frame.sky.xyz;
    let first = gi_trace(p, n, n, gi.spread);
    let ring = gi.cones - 1u;
    if ring == 0u {
        return vec4<f32>(first.xyz + sky * (1.0 - first.w), 1.0 - first.w);
    }
    // glam's any_orthonormal_pair (Duff et al. 2017), as the CPU uses.
    // signum: -0.0 counts as negative, as f64::signum has it.
    let sign = select(-1.0, 1.0, (bitcast<u32>(n.z) & 0x80000000u) == 0u);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let tx = vec3<f32>(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let bx = vec3<f32>(b, sign + n.y * n.y * a, -n.y);
    let ct = cos(gi.tilt);
    let st = sin(gi.tilt);
    var light = first.xyz + sky * (1.0 - first.w);
    var ring_light = vec3<f32>(0.0);
    var ring_open = 0.0;
    for (var k = 0u; k < ring; k++) {
        let phi = 6.28318530718 * f32(k) / f32(ring);
        let d = n * ct + (tx * cos(phi) + bx * sin(phi)) * st;
        let r = gi_trace(p, n, d, gi.spread);
        ring_light += r.xyz + sky * (1.0 - r.w);
        ring_open += 1.0 - r.w;
    }
    let norm = 1.0 + f32(ring) * ct;
    return vec4<f32>((light + ring_light * ct) / norm, ((1.0 - first.w) + ring_open * ct) / norm);
}

// render::gather's samples: pixel (2i, 2j) of each 2×2 block gathers its cones.
@compute @workgroup_size(8, 8, 1)
fn gather_half_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let lw = gi.half_width;
    if gid.x >= lw || gid.y >= (frame.height + 1u) / 2u {
        return;
    }
    let x = 2u * gid.x;
    let y = 2u * gid.y;
    let h = hits[y * frame.width + x];
    var s = vec4<f32>(0.0, 0.0, 0.0, -1.0);
    if h.instance >= 0 {
        s = gi_gather(ray_dir(x, y) * h.t, vec3<f32>(h.nx, h.ny, h.nz));
        gi_count_gather();
    }
    gi_samples[gid.y * lw + gid.x] = s;
}

// The samples of render::gather next to pixel coordinate c: its own (c even) or the two
// around it (c odd; one at the last odd column or row).
fn gi_near_last(c: u32, limit: u32) -> u32 {
    return select(c / 2u, min(c / 2u + 1u, limit - 1u), (c & 1u) == 1u);
}

// The diffuse cones' light at a pixel (render::gather::gather): its own cones, or with the
// half-resolution gather the mean of the nearest samples on its own surface (normal within
// GI_SAME_NORMAL, point within a voxel of its tangent plane), its own cones where none is.
fn gi_diffuse(h: Hit, x: u32, y: u32, p: vec3<f32>, n: vec3<f32>) -> vec4<f32> {
    if gi.half == 0u {
        gi_count_gather();
        return gi_gather(p, n);
    }
    let lw = gi.half_width;
    let lh = (frame.height + 1u) / 2u;
    var light = vec4<f32>(0.0);
    var weight = 0.0;
    for (var j = y / 2u; j <= gi_near_last(y, lh); j++) {
        for (var i = x / 2u; i <= gi_near_last(x, lw); i++) {
            let s = gi_samples[j * lw + i];
            if s.w < 0.0 {
                continue;
            }
            let sh = hits[2u * j * frame.width + 2u * i];
            let q = ray_dir(2u * i, 2u * j) * sh.t;
            if dot(n, vec3<f32>(sh.nx, sh.ny, sh.nz)) >= GI_SAME_NORMAL && abs(dot(n, q - p)) <= h.voxel {
                light += s;
                weight += 1.0;
            }
        }
    }
    if weight > 0.0 {
        return light / weight;
    }
    gi_count_gather();
    return gi_gather(p, n);
}

// Adds one gather point to the frame's statistics (Frame::gathers), when counting.
fn gi_count_gather() {
    if frame.count != 0u {
        atomicAdd(&stats[STAT_GATHERS], 1u);
    }
}

// shade_main with the ambient term from the cones instead of the flat sky.
@compute @workgroup_size(8, 8, 1)
fn shade_gi_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let idx = pixel_to_shade(gid);
    if idx == NO_PIXEL {
        return;
    }
    let h = hits[idx];
    let albedo = albedo_linear(h.albedo);
    let n = vec3<f32>(h.nx, h.ny, h.nz);
    let p = ray_dir(gid.x, gid.y) * h.t;
    let diffuse = gi_diffuse(h, gid.x, gid.y, p, n);
    var ambient = albedo * diffuse.xyz;
    let ks = specular(h.material);
    if ks > 0.0 && gi.specular_cone == 0u {
        ambient += ks * frame.sky.xyz;
    } else if ks > 0.0 {
        // The specular cone (shade.rs): the Phong lobe's light, the sky where it escapes.
        let r = reflect(ray_dir(gid.x, gid.y), n);
        let e = shininess_of(h.material);
        let spread = 2.0 * tan(acos(pow(0.5, 1.0 / max(e, 1.0))));
        let sc = gi_trace(p, n, normalize(r), spread);
        ambient += ks * (sc.xyz + frame.sky.xyz * (1.0 - sc.w));
    }
    ambient = max(ambient, vec3<f32>(0.0));
    // w: the cones' ambient occlusion, read back as the AO AOV (the sky's pixels have 1).
    radiance[idx] = vec4<f32>(ambient + direct_light(h, gid.x, gid.y, albedo), diffuse.w);
}

// shade::bounce: every occupied cell gathers the previous chain's light over its hemisphere
// (the pixels' cones, from the cell centre along its mean normal) and sends out its albedo
// times that on top of its direct light, into gi_next.
@compute @workgroup_size(64, 1, 1)
fn bounce_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gi_thread_cell(gid);
    if i == GI_EMPTY {
        return;
    }
    let cell = gi_cell(i);
    var out = gi_direct[i];
    if cell.occ > 0.0 && dot(cell.n, cell.n) > 1e-6 {
        let centre = gi.min_cell.xyz + (vec3<f32>(gi_cell_coord(i)) + 0.5) * gi.min_cell.w;
        let light = gi_gather(centre, normalize(cell.n)).xyz;
        out += vec4<f32>(cell.albedo * light * min(cell.occ, 1.0), 0.0);
    }
    gi_next[i] = out;
}

// The bounce's level 0 replaces the chain's; the levels are then averaged again.
@compute @workgroup_size(64, 1, 1)
fn bounce_commit_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gi_thread_cell(gid);
    if i == GI_EMPTY {
        return;
    }
    gi_levels[i] = gi_next[i];
}
