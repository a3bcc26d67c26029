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
// GiSettings::anisotropic (dense buffer store): levels 1 and coarser hold six faces each
// (gi::levels::FaceLevel), face f of level l at gi_levels[offset_l + f * res_l³ + cell].
override GI_ANISO: bool = false;
// GiSettings::cone_shadows: the emitters' shadows in shade_gi_main are cones through the
// level chain (gi_emitter_light), not shadow rays (direct_light leaves the emitters out).
override GI_CONE_SHADOWS: bool = false;

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

// Radiance caches (render::radiance_cache): two vec4 per slot (tile × per_tile slots): the
// camera-relative point and 1 when placed, then the unit normal and the pixel (x | y << 16, as
// bits). Their maps, gi.cache_stride vec4 per slot: the res² texels, the mips down to 1², the
// irradiance map. One-element placeholders unless gi.caches.
@group(1) @binding(B_GI_CACHE_POINTS) var<storage, read_write> gi_cache_points: array<vec4<f32>>;
@group(1) @binding(B_GI_CACHE_MAPS) var<storage, read_write> gi_cache_maps: array<vec4<f32>>;

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
        radiance += emitter_light(c.x + gi.res * (c.y + gi.res * c.z), gi.cell_samples, at, at + nn * cell, nn, -nn, albedo, 0u);
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

// gi::levels::face_weights: the faces a cone along unit dir reads (+x, -x, +y, -y, +z, -z
// order) and their weights, the direction's components to the eighth power, normalized.
fn gi_face_weights(dir: vec3<f32>) -> array<vec2<f32>, 3> {
    let d2 = dir * dir;
    let d4 = d2 * d2;
    let e = d4 * d4;
    let sum = e.x + e.y + e.z;
    return array<vec2<f32>, 3>(
        vec2<f32>(select(1.0, 0.0, dir.x >= 0.0), e.x / sum),
        vec2<f32>(select(3.0, 2.0, dir.y >= 0.0), e.y / sum),
        vec2<f32>(select(5.0, 4.0, dir.z >= 0.0), e.z / sum),
    );
}

// cone::sample_level (Chain::trilinear_dir): trilinear, cell centres hold the values, outside
// is empty; with GI_ANISO a coarse level blends the faces fw (gi_face_weights, one per cone).
fn gi_sample_level(l: u32, p: vec3<f32>, fw: array<vec2<f32>, 3>) -> vec4<f32> {
    let cell = gi.min_cell.w * f32(1u << l);
    let g = (p - gi.min_cell.xyz) / cell - 0.5;
    let base = floor(g);
    let f = g - base;
    let b = vec3<i32>(base);
    let r = i32(gi_per_level(gi.res_a, gi.res_b, gi.res_c, l));
    let off = gi_per_level(gi.offsets_a, gi.offsets_b, gi.offsets_c, l);
    // An anisotropic coarse level: the three faces' offsets from a cell's first face.
    let faced = GI_ANISO && l > 0u;
    let n = u32(r) * u32(r) * u32(r);
    let face0 = u32(fw[0].x) * n;
    let face1 = u32(fw[1].x) * n;
    let face2 = u32(fw[2].x) * n;
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
        var v: vec4<f32>;
        if faced {
            v = gi_levels[idx + face0] * fw[0].y + gi_levels[idx + face1] * fw[1].y + gi_levels[idx + face2] * fw[2].y;
        } else {
            v = gi_levels[idx];
        }
        out += v * (w3.x * w3.y * w3.z);
    }
    return out;
}

// cone::sample_dir: quadrilinear, as a cone with the face weights fw sees it.
fn gi_sample(p: vec3<f32>, level: f32, fw: array<vec2<f32>, 3>) -> vec4<f32> {
    let top = f32(gi.levels - 1u);
    let l = clamp(level, 0.0, top);
    if GI_TEXTURE {
        let uvw = (p - gi.min_cell.xyz) / (gi.min_cell.w * f32(gi.tex_size));
        return textureSampleLevel(gi_tex, gi_sampler, uvw, l);
    }
    let lo = u32(floor(l));
    let hi = min(lo + 1u, gi.levels - 1u);
    let f = l - f32(lo);
    let a = gi_sample_level(lo, p, fw);
    if f == 0.0 || hi == lo {
        return a;
    }
    return a * (1.0 - f) + gi_sample_level(hi, p, fw) * f;
}

// cone::trace: one cone from a surface point; (radiance, opacity).
fn gi_trace(origin: vec3<f32>, normal: vec3<f32>, dir: vec3<f32>, spread: f32) -> vec4<f32> {
    return gi_march(origin, normal, dir, spread, gi.max_distance, -1.0);
}

// cone::march: with end_cos > 0 each sample keeps clear of the surface the cone ends on,
// `end` along it (cone::ConeEnd), as it keeps clear of the one it starts from.
fn gi_march(origin: vec3<f32>, normal: vec3<f32>, dir: vec3<f32>, spread: f32, max_distance: f32, end_cos: f32) -> vec4<f32> {
    let cell0 = gi.min_cell.w;
    let end = min(max_distance, cell0 * f32(gi.res) * 1.75);
    let max_level = f32(max(i32(gi.levels) - 3, 0));
    let lift = cell0;
    let o = origin + normal * lift;
    let cosv = max(dot(dir, normal), 0.05);
    // The faces an anisotropic chain shows this cone: one direction, found once.
    let fw = gi_face_weights(dir);
    var c = vec3<f32>(0.0);
    var a = 0.0;
    var t = max((GI_CLEARANCE * (cell0 + cell0) - lift) / cosv, cell0);
    // Every step is at least half a cell and the march ends at the volume's diagonal; the
    // count bound only guards against a non-finite input.
    for (var steps = 0u; t < end && a < 0.99 && steps < 8192u; steps++) {
        var clear_size = (lift + t * cosv - GI_CLEARANCE * cell0) / GI_CLEARANCE;
        if end_cos > 0.0 {
            let room = ((max_distance - t) * max(end_cos, 0.05) - GI_CLEARANCE * cell0) / GI_CLEARANCE;
            if room < cell0 {
                break;
            }
            clear_size = min(clear_size, room);
        }
        let diameter = max(spread * t, cell0);
        let clear_level = floor(log2(max(clear_size / cell0, 1.0)));
        let level = min(min(log2(diameter / cell0), clear_level), max_level);
        let s = gi_sample(o + dir * t, level, fw);
        let sa = clamp(s.w, 0.0, 1.0);
        if sa > 0.0 {
            c += (1.0 - a) * s.xyz * (sa / s.w);
            a += (1.0 - a) * sa;
        }
        t += cell0 * exp2(level) * 0.5;
    }
    return vec4<f32>(c, a);
}

// emitters::shadow_cone_of with cone::visibility: what of emitter row `e` reaches the
// camera-relative surface point `at` (unit normal n) through the level chain, by one cone to
// its centroid as wide as a disc of its projected solid angle (at most MAX_SHADOW_CONE).
fn shadow_cone_of(e: Emitter, at: vec3<f32>, n: vec3<f32>) -> f32 {
    let to = e.a.xyz + (e.e1.xyz + e.e2.xyz) / 3.0 - at;
    let dist = length(to);
    if !(dist > 0.0) {
        return 0.0;
    }
    let dir = to / dist;
    let cosv = -dot(e.normal.xyz, dir);
    if !(cosv > 0.0) {
        return 0.0;
    }
    let omega = min(e.e1.w * cosv / (dist * dist), 6.28318530718);
    let aperture = max(min(2.0 * acos(clamp(1.0 - omega / 6.28318530718, -1.0, 1.0)), MAX_SHADOW_CONE), 1e-4);
    return 1.0 - gi_march(at, n, dir, 2.0 * tan(aperture * 0.5), dist, cosv).w;
}

const MAX_SHADOW_CONE: f32 = 2.09439510239;

// emitters::emitter_light with EmitterShadows::Cones: the samples as emitter_light draws them,
// each dimmed by its triangle's shadow cone (traced once per triangle for up to eight).
fn gi_emitter_light(key: u32, at: vec3<f32>, n: vec3<f32>, d: vec3<f32>, albedo: vec3<f32>, material: u32) -> vec3<f32> {
    let samples = frame.emitter_samples;
    if frame.emitters == 0u || samples == 0u {
        return vec3<f32>(0.0);
    }
    var memo_row: array<u32, 8>;
    var memo_through: array<f32, 8>;
    var memo_len = 0u;
    var sum = vec3<f32>(0.0);
    for (var s = 0u; s < samples; s++) {
        let l = emitter_sample(key, s, at, n, d, albedo, material);
        if l.index == NO_EMITTER {
            continue;
        }
        var through = -1.0;
        for (var m = 0u; m < memo_len; m++) {
            if memo_row[m] == l.index {
                through = memo_through[m];
                break;
            }
        }
        if through < 0.0 {
            through = shadow_cone_of(emitters[l.index], at, n);
            if memo_len < 8u {
                memo_row[memo_len] = l.index;
                memo_through[memo_len] = through;
                memo_len++;
            }
        }
        sum += l.light * through;
    }
    return sum / f32(samples);
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
    if gi.caches != 0u {
        let c = gi_cache_blend(x, y, p, n, h.t, vec3<f32>(0.0), -1.0);
        if c.weight > 0.0 {
            return c.value;
        }
        gi_count_gather();
        return gi_gather(p, n);
    }
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
    var glossy = GiCacheBlend(vec4<f32>(0.0), 0.0);
    if ks > 0.0 && gi.specular_cone != 0u && gi.caches != 0u {
        // The caches' lobe-sized level along the mirror direction (render::gather).
        let e = shininess_of(h.material);
        let omega = 6.28318530718 * (1.0 - pow(0.5, 1.0 / max(e, 1.0)));
        let r = normalize(reflect(ray_dir(gid.x, gid.y), n));
        glossy = gi_cache_blend(gid.x, gid.y, p, n, h.t, r, omega);
    }
    if ks > 0.0 && gi.specular_cone == 0u {
        ambient += ks * frame.sky.xyz;
    } else if glossy.weight > 0.0 {
        ambient += ks * glossy.value.xyz;
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
    var direct = direct_light(h, gid.x, gid.y, albedo);
    if GI_CONE_SHADOWS && SHADOWS {
        direct += gi_emitter_light(idx, p, n, ray_dir(gid.x, gid.y), albedo, h.material);
    }
    radiance[idx] = vec4<f32>(ambient + direct, diffuse.w);
}

// shade::bounce: every occupied cell gathers the previous chain's light over its hemisphere
// (the pixels' cones, from the cell centre along its mean normal) and sends out its albedo
// times that on top of its direct light, into gi_next. With gi.tail, each workgroup also sums
// what shade::TailSums sums over its cells (the added light, that light times the share of
// the cones that met the scene, albedo times opacity, opacity) into its slot past the cells
// of gi_next (gi_tail_slot); the last bounce's are what shade::bounce_tail reads.
var<workgroup> gi_tail_wg: array<array<vec4<f32>, 3>, 64>;

// Slot k of the tail's sums in gi_next: slot 0 holds the factor, slot 1 + 3 w + j the sum j
// of workgroup w.
fn gi_tail_slot(k: u32) -> u32 {
    return gi.cells + k;
}

// Sums the three vec4 of each thread of the workgroup into gi_tail_wg[0].
fn gi_tail_reduce(lid: u32) {
    for (var half = 32u; half > 0u; half = half >> 1u) {
        workgroupBarrier();
        if lid < half {
            for (var j = 0u; j < 3u; j++) {
                gi_tail_wg[lid][j] += gi_tail_wg[lid + half][j];
            }
        }
    }
    workgroupBarrier();
}

@compute @workgroup_size(64, 1, 1)
fn bounce_main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let i = gi_thread_cell(gid);
    var sums = array<vec4<f32>, 3>(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    if i != GI_EMPTY {
        let cell = gi_cell(i);
        var out = gi_direct[i];
        if cell.occ > 0.0 && dot(cell.n, cell.n) > 1e-6 {
            let centre = gi.min_cell.xyz + (vec3<f32>(gi_cell_coord(i)) + 0.5) * gi.min_cell.w;
            let g = gi_gather(centre, normalize(cell.n));
            let a = min(cell.occ, 1.0);
            out += vec4<f32>(cell.albedo * g.xyz * a, 0.0);
            let added = max(out.xyz - gi_levels[i].xyz, vec3<f32>(0.0));
            sums[0] = vec4<f32>(added, 0.0);
            sums[1] = vec4<f32>(added * (1.0 - clamp(g.w, 0.0, 1.0)), 0.0);
            sums[2] = vec4<f32>(cell.albedo * a, a);
        }
        gi_next[i] = out;
    }
    if gi.tail != 0u {
        gi_tail_wg[lid] = sums;
        gi_tail_reduce(lid);
        let w = (gid.x + gid.y * gi.row_threads) / 64u;
        if lid == 0u && w * 64u < gi.cells {
            for (var j = 0u; j < 3u; j++) {
                gi_next[gi_tail_slot(1u + 3u * w + j)] = gi_tail_wg[0][j];
            }
        }
    }
}

// shade::bounce_tail: one workgroup sums the workgroups' slots and writes the factor
// r / (1 - r) per channel into slot 0.
@compute @workgroup_size(64, 1, 1)
fn bounce_tail_main(@builtin(local_invocation_index) lid: u32) {
    let slots = (gi.cells + 63u) / 64u;
    var sums = array<vec4<f32>, 3>(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    for (var w = lid; w < slots; w += 64u) {
        for (var j = 0u; j < 3u; j++) {
            sums[j] += gi_next[gi_tail_slot(1u + 3u * w + j)];
        }
    }
    gi_tail_wg[lid] = sums;
    gi_tail_reduce(lid);
    if lid == 0u {
        let added = gi_tail_wg[0][0].xyz;
        let met = gi_tail_wg[0][1].xyz;
        let albedo = gi_tail_wg[0][2];
        var f = vec3<f32>(0.0);
        if albedo.w > 0.0 {
            let mean_albedo = albedo.xyz / albedo.w;
            for (var c = 0; c < 3; c++) {
                if added[c] > 0.0 {
                    let r = clamp(met[c] / added[c] * mean_albedo[c], 0.0, GI_MAX_TAIL_RATIO);
                    f[c] = r / (1.0 - r);
                }
            }
        }
        gi_next[gi_tail_slot(0u)] = vec4<f32>(f, 0.0);
    }
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

// The last bounce's commit with the tail: the light it added, scaled by the factor, stands
// for the bounces after it.
@compute @workgroup_size(64, 1, 1)
fn bounce_tail_commit_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gi_thread_cell(gid);
    if i == GI_EMPTY {
        return;
    }
    let next = gi_next[i];
    let added = max(next.xyz - gi_levels[i].xyz, vec3<f32>(0.0));
    let f = gi_next[gi_tail_slot(0u)].xyz;
    gi_levels[i] = next + vec4<f32>(added * f, 0.0);
}

// ---- Radiance caches (render::radiance_cache) ----

// radiance_cache::square_to_disk then map_direction: map point (u, v) → local direction.
fn gi_map_direction(u: f32, v: f32) -> vec3<f32> {
    let a = 2.0 * u - 1.0;
    let b = 2.0 * v - 1.0;
    var x = 0.0;
    var y = 0.0;
    if a != 0.0 || b != 0.0 {
        var r = b;
        var phi = 1.57079632679 - 0.78539816340 * (a / b);
        if abs(a) > abs(b) {
            r = a;
            phi = 0.78539816340 * (b / a);
        }
        x = r * cos(phi);
        y = r * sin(phi);
    }
    let rho2 = min(x * x + y * y, 1.0);
    let s = sqrt(2.0 - rho2);
    return vec3<f32>(x * s, y * s, 1.0 - rho2);
}

// radiance_cache::map_point: local unit direction → map point.
fn gi_map_point(d: vec3<f32>) -> vec2<f32> {
    let z = clamp(d.z, 0.0, 1.0);
    let horizontal = sqrt(d.x * d.x + d.y * d.y);
    let rho = sqrt(1.0 - z);
    var x = 0.0;
    var y = 0.0;
    if horizontal > 0.0 {
        x = d.x / horizontal * rho;
        y = d.y / horizontal * rho;
    }
    let r = sqrt(x * x + y * y);
    if r == 0.0 {
        return vec2<f32>(0.5);
    }
    var phi = atan2(y, x);
    if phi < -0.78539816340 {
        phi += 6.28318530718;
    }
    var ab: vec2<f32>;
    if phi < 0.78539816340 {
        ab = vec2<f32>(r, phi * r / 0.78539816340);
    } else if phi < 2.35619449019 {
        ab = vec2<f32>(-(phi - 1.57079632679) * r / 0.78539816340, r);
    } else if phi < 3.92699081699 {
        ab = vec2<f32>(-r, -(phi - 3.14159265359) * r / 0.78539816340);
    } else {
        ab = vec2<f32>((phi - 4.71238898038) * r / 0.78539816340, -r);
    }
    return (ab + 1.0) * 0.5;
}

// glam's any_orthonormal_pair, as gi_gather uses: the cache's tangent frame.
fn gi_tangents(n: vec3<f32>) -> mat2x3<f32> {
    let sign = select(-1.0, 1.0, (bitcast<u32>(n.z) & 0x80000000u) == 0u);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    return mat2x3<f32>(vec3<f32>(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x), vec3<f32>(b, sign + n.y * n.y * a, -n.y));
}

// First element of mip level k (level 0: the res² texels) within a slot's maps.
fn gi_mip_offset(k: u32) -> u32 {
    var off = 0u;
    var n = gi.cache_res;
    for (var j = 0u; j < k; j++) {
        off += n * n;
        n = n / 2u;
    }
    return off;
}

// Levels of the pyramid (res² down to 1²).
fn gi_mip_count() -> u32 {
    return firstTrailingBit(gi.cache_res) + 1u;
}

// The irradiance map's texels per side.
fn gi_irr_res() -> u32 {
    return max(gi.cache_res / 2u, 2u);
}

// MapLevel::lookup: bilinear at map point m of the n×n level starting at element `base`.
fn gi_map_lookup(base: u32, n: u32, m: vec2<f32>) -> vec4<f32> {
    let fx = clamp(m.x * f32(n) - 0.5, 0.0, f32(n - 1u));
    let fy = clamp(m.y * f32(n) - 0.5, 0.0, f32(n - 1u));
    let x0 = u32(floor(fx));
    let y0 = u32(floor(fy));
    let x1 = min(x0 + 1u, n - 1u);
    let y1 = min(y0 + 1u, n - 1u);
    let tx = fx - f32(x0);
    let ty = fy - f32(y0);
    let top = gi_cache_maps[base + y0 * n + x0] * (1.0 - tx) + gi_cache_maps[base + y0 * n + x1] * tx;
    let bottom = gi_cache_maps[base + y1 * n + x0] * (1.0 - tx) + gi_cache_maps[base + y1 * n + x1] * tx;
    return top * (1.0 - ty) + bottom * ty;
}

// Placement scratch of one tile's workgroup.
var<workgroup> gi_hist: array<atomic<u32>, 64>;
var<workgroup> gi_picks: array<vec3<f32>, 16>;
var<workgroup> gi_pick_count: u32;
var<workgroup> gi_sum_n: array<atomic<i32>, 48>;
var<workgroup> gi_sum_xy: array<atomic<u32>, 32>;
var<workgroup> gi_members: array<atomic<u32>, 16>;
var<workgroup> gi_best: array<atomic<u32>, 16>;

// Fixed point of the placement's sums (histogram weights and normals).
const GI_PLACE_FIX: f32 = 4096.0;

// radiance_cache::histogram_directions: a Fibonacci sphere of 64 directions.
fn gi_hist_dir(i: u32) -> vec3<f32> {
    let z = 1.0 - 2.0 * (f32(i) + 0.5) / 64.0;
    let r = sqrt(1.0 - z * z);
    let phi = 2.39996322973 * f32(i);
    return vec3<f32>(r * cos(phi), r * sin(phi), z);
}

// The tile's pixel k (row by row) and whether it is a hit.
fn gi_tile_pixel(tile: u32, k: u32) -> vec3<u32> {
    let t = gi.cache_tile;
    let tx = tile % gi.cache_tiles_x;
    let ty = tile / gi.cache_tiles_x;
    let x0 = tx * t;
    let y0 = ty * t;
    let w = min(x0 + t, frame.width) - x0;
    let x = x0 + k % w;
    let y = y0 + k / w;
    let inside = k < w * (min(y0 + t, frame.height) - y0);
    return vec3<u32>(x, y, select(0u, 1u, inside && hits[y * frame.width + x].instance >= 0));
}

// The unit normal of pixel px's hit.
fn gi_hit_normal(px: vec3<u32>) -> vec3<f32> {
    let h = hits[px.y * frame.width + px.x];
    return normalize(vec3<f32>(h.nx, h.ny, h.nz));
}

// place_tile's cluster membership: normal n is nearest pick c among the first `picks` (and
// within 60° of it).
fn gi_in_cluster(n: vec3<f32>, c: u32, picks: u32) -> bool {
    let own = dot(n, gi_picks[c]);
    var nearest = own > 0.5;
    for (var o = 0u; o < picks; o++) {
        if o != c && dot(n, gi_picks[o]) > own {
            nearest = false;
        }
    }
    return nearest;
}

// radiance_cache::place_tile, clustered or even, one workgroup per tile: up to per_tile
// caches into the tile's slots (unplaced slots are marked empty).
@compute @workgroup_size(64, 1, 1)
fn cache_place_main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let tile = wid.x + wid.y * 65535u;
    let tiles = gi.cache_tiles_x * ((frame.height + gi.cache_tile - 1u) / gi.cache_tile);
    if tile >= tiles {
        return;
    }
    let per = gi.cache_per_tile;
    let tx = tile % gi.cache_tiles_x;
    let ty = tile / gi.cache_tiles_x;
    let x0 = tx * gi.cache_tile;
    let y0 = ty * gi.cache_tile;
    let tw = min(x0 + gi.cache_tile, frame.width) - x0;
    let th = min(y0 + gi.cache_tile, frame.height) - y0;
    let count = tw * th;
    for (var i = li; i < 64u; i += 64u) {
        atomicStore(&gi_hist[i], 0u);
    }
    for (var i = li; i < 48u; i += 64u) {
        atomicStore(&gi_sum_n[i], 0);
    }
    for (var i = li; i < 32u; i += 64u) {
        atomicStore(&gi_sum_xy[i], 0u);
    }
    for (var i = li; i < 16u; i += 64u) {
        atomicStore(&gi_members[i], 0u);
        atomicStore(&gi_best[i], 0u);
    }
    workgroupBarrier();
    if gi.cache_placement == 0u {
        for (var k = li; k < count; k += 64u) {
            let px = gi_tile_pixel(tile, k);
            if px.z == 0u {
                continue;
            }
            let n = gi_hit_normal(px);
            for (var b = 0u; b < 64u; b++) {
                let w = exp(-(1.0 - dot(n, gi_hist_dir(b))) / 0.1);
                atomicAdd(&gi_hist[b], u32(w * GI_PLACE_FIX + 0.5));
            }
        }
    }
    workgroupBarrier();
    if li == 0u {
        var picks = 0u;
        if gi.cache_placement == 0u {
            // dominant_normals: the best direction, the others damped by 1 − |d·d_best|⁸.
            var w: array<f32, 64>;
            for (var b = 0u; b < 64u; b++) {
                w[b] = f32(atomicLoad(&gi_hist[b]));
            }
            var first = 0.0;
            for (var k = 0u; k < per; k++) {
                var bi = 0u;
                for (var b = 1u; b < 64u; b++) {
                    if w[b] >= w[bi] {
                        bi = b;
                    }
                }
                let best = w[bi];
                if k == 0u {
                    first = best;
                }
                if !(best > 0.0) || best < 0.1 * first {
                    break;
                }
                let d = gi_hist_dir(bi);
                gi_picks[picks] = d;
                picks += 1u;
                for (var b = 0u; b < 64u; b++) {
                    w[b] *= 1.0 - pow(abs(dot(gi_hist_dir(b), d)), 8.0);
                }
            }
        }
        gi_pick_count = picks;
    }
    workgroupBarrier();
    let picks = workgroupUniformLoad(&gi_pick_count);
    let k_even = u32(ceil(sqrt(f32(per))));
    let cell = max((tw + k_even - 1u) / k_even, 1u);
    // Clusters: sums of their members' normals and pixel positions.
    for (var k = li; k < count; k += 64u) {
        let px = gi_tile_pixel(tile, k);
        if px.z == 0u {
            continue;
        }
        let n = gi_hit_normal(px);
        if gi.cache_placement == 0u {
            for (var c = 0u; c < picks; c++) {
                if gi_in_cluster(n, c, picks) {
                    atomicAdd(&gi_members[c], 1u);
                    atomicAdd(&gi_sum_n[3u * c], i32(round(n.x * GI_PLACE_FIX)));
                    atomicAdd(&gi_sum_n[3u * c + 1u], i32(round(n.y * GI_PLACE_FIX)));
                    atomicAdd(&gi_sum_n[3u * c + 2u], i32(round(n.z * GI_PLACE_FIX)));
                    atomicAdd(&gi_sum_xy[2u * c], px.x);
                    atomicAdd(&gi_sum_xy[2u * c + 1u], px.y);
                }
            }
        }
    }
    workgroupBarrier();
    // The representative of each cluster (or grid cell): the highest score, ties to the last
    // pixel, as Iterator::max_by keeps.
    for (var k = li; k < count; k += 64u) {
        let px = gi_tile_pixel(tile, k);
        if px.z == 0u {
            continue;
        }
        let n = gi_hit_normal(px);
        if gi.cache_placement == 0u {
            for (var c = 0u; c < picks; c++) {
                if !gi_in_cluster(n, c, picks) {
                    continue;
                }
                let m = f32(atomicLoad(&gi_members[c]));
                let sn = vec3<f32>(
                    f32(atomicLoad(&gi_sum_n[3u * c])),
                    f32(atomicLoad(&gi_sum_n[3u * c + 1u])),
                    f32(atomicLoad(&gi_sum_n[3u * c + 2u])),
                );
                let mean = select(gi_picks[c], normalize(sn), dot(sn, sn) > 0.0);
                let centre = vec2<f32>(f32(atomicLoad(&gi_sum_xy[2u * c])), f32(atomicLoad(&gi_sum_xy[2u * c + 1u]))) / m;
                let dist = length(vec2<f32>(f32(px.x), f32(px.y)) - centre);
                let score = dot(n, mean) - 0.5 * dist / f32(tw);
                let q = u32(clamp((score + 2.0) * 16383.0, 0.0, 65535.0));
                atomicMax(&gi_best[c], (q << 16u) | (k + 1u));
            }
        } else {
            // The grid cell of this pixel; its cache is the hit nearest the cell's centre.
            let i = (px.x - x0) / cell;
            let j = min(px.y - y0, th - 1u) / cell;
            let c = j * k_even + i;
            if i < k_even && j < k_even && c < per {
                let cx = f32(x0) + (f32(i) + 0.5) * f32(cell);
                let cy = f32(y0) + (f32(j) + 0.5) * f32(cell);
                let d2 = (f32(px.x) - cx) * (f32(px.x) - cx) + (f32(px.y) - cy) * (f32(px.y) - cy);
                // Nearest first, ties to the first pixel (min_by keeps the first).
                let q = 65535u - u32(clamp(d2, 0.0, 65535.0));
                atomicMax(&gi_best[c], (q << 16u) | (65535u - k));
            }
        }
    }
    workgroupBarrier();
    if li < per {
        let slot = tile * per + li;
        let key = atomicLoad(&gi_best[li]);
        var k = 0u;
        var placed = key != 0u;
        if gi.cache_placement == 0u {
            placed = placed && li < picks;
            k = (key & 0xFFFFu) - 1u;
        } else {
            k = 65535u - (key & 0xFFFFu);
        }
        if placed {
            let px = gi_tile_pixel(tile, k);
            let h = hits[px.y * frame.width + px.x];
            let p = ray_dir(px.x, px.y) * h.t;
            gi_cache_points[2u * slot] = vec4<f32>(p, 1.0);
            gi_cache_points[2u * slot + 1u] =
                vec4<f32>(normalize(vec3<f32>(h.nx, h.ny, h.nz)), bitcast<f32>(px.x | (px.y << 16u)));
        } else {
            gi_cache_points[2u * slot] = vec4<f32>(0.0);
        }
    }
}

// radiance_cache::trace_texels: one cone per texel of every placed cache, as wide as the
// texel's solid angle.
@compute @workgroup_size(64, 1, 1)
fn cache_trace_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * gi.cache_row_threads;
    let texels = gi.cache_res * gi.cache_res;
    let slot = i / texels;
    if slot >= gi.cache_slots || gi_cache_points[2u * slot].w == 0.0 {
        return;
    }
    let t = i % texels;
    let p = gi_cache_points[2u * slot].xyz;
    let n = gi_cache_points[2u * slot + 1u].xyz;
    let tb = gi_tangents(n);
    let res = f32(gi.cache_res);
    let l = gi_map_direction((f32(t % gi.cache_res) + 0.5) / res, (f32(t / gi.cache_res) + 0.5) / res);
    let d = tb[0] * l.x + tb[1] * l.y + n * l.z;
    let c = gi_trace(p, n, d, gi.cache_spread);
    gi_cache_maps[slot * gi.cache_stride + t] = vec4<f32>(c.xyz + frame.sky.xyz * (1.0 - c.w), 1.0 - c.w);
}

// The level-0 texel directions of the slot a convolution workgroup works on.
var<workgroup> gi_texel_dirs: array<vec3<f32>, 1024>;

// radiance_cache::convolve, one workgroup per cache: the mips (each texel the mean of its
// block of level 0, as the 2×2 averages make it) and the irradiance map (the cosine-weighted
// mean about each texel's direction); the level-0 directions are made once per workgroup.
@compute @workgroup_size(64, 1, 1)
fn cache_convolve_main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let slot = wid.x + wid.y * 65535u;
    if slot >= gi.cache_slots || gi_cache_points[2u * slot].w == 0.0 {
        return;
    }
    let texels = gi.cache_res * gi.cache_res;
    let res = f32(gi.cache_res);
    for (var t = li; t < texels; t += 64u) {
        gi_texel_dirs[t] = gi_map_direction((f32(t % gi.cache_res) + 0.5) / res, (f32(t / gi.cache_res) + 0.5) / res);
    }
    workgroupBarrier();
    let base = slot * gi.cache_stride;
    let mips = gi_mip_count();
    let irr = gi_mip_offset(mips);
    let ni = gi_irr_res();
    for (var j = texels + li; j < gi.cache_stride; j += 64u) {
        if j < irr {
            var k = 1u;
            while gi_mip_offset(k + 1u) <= j {
                k += 1u;
            }
            let n = gi.cache_res >> k;
            let e = j - gi_mip_offset(k);
            let block = 1u << k;
            let x0 = (e % n) * block;
            let y0 = (e / n) * block;
            var sum = vec4<f32>(0.0);
            for (var y = y0; y < y0 + block; y++) {
                for (var x = x0; x < x0 + block; x++) {
                    sum += gi_cache_maps[base + y * gi.cache_res + x];
                }
            }
            gi_cache_maps[base + j] = sum / f32(block * block);
            continue;
        }
        let e = j - irr;
        let nd = gi_map_direction((f32(e % ni) + 0.5) / f32(ni), (f32(e / ni) + 0.5) / f32(ni));
        var sum = vec4<f32>(0.0);
        var weight = 0.0;
        for (var t = 0u; t < texels; t++) {
            let c = dot(nd, gi_texel_dirs[t]);
            if c > 0.0 {
                sum += gi_cache_maps[base + t] * c;
                weight += c;
            }
        }
        gi_cache_maps[base + j] = select(vec4<f32>(0.0), sum / weight, weight > 0.0);
    }
}

// A blend of the caches near a pixel and its total weight (0: none applies).
struct GiCacheBlend {
    value: vec4<f32>,
    weight: f32,
}

// FrameCaches::blend (omega < 0: the irradiance and open fraction at normal n) and
// FrameCaches::glossy (the radiance along unit d over a lobe of omega steradians), at pixel
// (x, y) with camera-relative point p, unit normal n and ray parameter t: the caches within
// the radius, or within one tile more where none applies there.
fn gi_cache_blend(x: u32, y: u32, p: vec3<f32>, n: vec3<f32>, t: f32, d: vec3<f32>, omega: f32) -> GiCacheBlend {
    let near = gi_cache_blend_within(gi.cache_radius, x, y, p, n, t, d, omega);
    if near.weight > 0.0 {
        return near;
    }
    return gi_cache_blend_within(gi.cache_radius + 1u, x, y, p, n, t, d, omega);
}

// gi_cache_blend over the caches within r tiles alone (FrameCaches::blend_within and
// glossy_within).
fn gi_cache_blend_within(r: u32, x: u32, y: u32, p: vec3<f32>, n: vec3<f32>, t: f32, d: vec3<f32>, omega: f32) -> GiCacheBlend {
    let tx = x / gi.cache_tile;
    let ty = y / gi.cache_tile;
    let tiles_y = (frame.height + gi.cache_tile - 1u) / gi.cache_tile;
    // radiance_cache::footprint.
    let footprint = t * 2.0 * frame.forward.w / f32(frame.height);
    let reach = f32(r) * f32(gi.cache_tile) * footprint;
    var sum = vec4<f32>(0.0);
    var weight = 0.0;
    let texel = 6.28318530718 / f32(gi.cache_res * gi.cache_res);
    let mips = gi_mip_count();
    for (var jy = select(0u, ty - r, ty >= r); jy < min(ty + r + 1u, tiles_y); jy++) {
        for (var jx = select(0u, tx - r, tx >= r); jx < min(tx + r + 1u, gi.cache_tiles_x); jx++) {
            let tile = jy * gi.cache_tiles_x + jx;
            for (var c = 0u; c < gi.cache_per_tile; c++) {
                let slot = tile * gi.cache_per_tile + c;
                let a = gi_cache_points[2u * slot];
                if a.w == 0.0 {
                    continue;
                }
                let cn = gi_cache_points[2u * slot + 1u].xyz;
                if omega >= 0.0 && dot(d, cn) <= 0.0 {
                    continue;
                }
                let wn = clamp((dot(n, cn) - 0.9) / (1.0 - 0.9), 0.0, 1.0);
                let wd = clamp(1.0 - length(a.xyz - p) / reach, 0.0, 1.0);
                let wc = min(wn, wd);
                if wc <= 0.0 {
                    continue;
                }
                let tb = gi_tangents(cn);
                let base = slot * gi.cache_stride;
                if omega < 0.0 {
                    let m = gi_map_point(vec3<f32>(dot(n, tb[0]), dot(n, tb[1]), dot(n, cn)));
                    sum += gi_map_lookup(base + gi_mip_offset(mips), gi_irr_res(), m) * wc;
                } else {
                    let level = min(0.5 * log2(max(omega / texel, 1.0)), f32(mips - 1u));
                    let m = gi_map_point(vec3<f32>(dot(d, tb[0]), dot(d, tb[1]), dot(d, cn)));
                    let lo = u32(floor(level));
                    let hi = min(lo + 1u, mips - 1u);
                    let f = level - f32(lo);
                    var v = gi_map_lookup(base + gi_mip_offset(lo), gi.cache_res >> lo, m);
                    if hi != lo && f > 0.0 {
                        v = v * (1.0 - f) + gi_map_lookup(base + gi_mip_offset(hi), gi.cache_res >> hi, m) * f;
                    }
                    sum += v * wc;
                }
                weight += wc;
            }
        }
    }
    return GiCacheBlend(select(vec4<f32>(0.0), sum / weight, weight > 0.0), weight);
}
