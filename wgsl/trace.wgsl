// Per-pixel passes: trace_main finds each pixel's primary hit (or keeps last frame's under the
// exact hit-buffer rule), shade_main lights it. The WGSL twin of src/render/visibility.rs,
// src/render/hitbuffer.rs and src/render/cpu.rs. Needs layout.wgsl, traverse.wgsl and
// search.wgsl (the instance searches).

// Which instance search (render::visibility::Search): 0 plain, 1 cull, 2 cull + sort, 3 BVH.
override SEARCH: u32 = 0u;
// Reuse last frame's hits where the rule allows (plan.hit_buffer).
override REUSE: bool = false;
// Shadow rays (plan.shadows).
override SHADOWS: bool = true;

@group(0) @binding(B_HITS) var<storage, read_write> hits: array<Hit>;
@group(0) @binding(B_MOVED) var<storage, read> moved: array<MovedSphere>;
@group(0) @binding(B_RADIANCE) var<storage, read_write> radiance: array<vec4<f32>>;
// The frame's statistics (GpuStats), added up when frame.count is 1.
@group(0) @binding(B_STATS) var<storage, read_write> stats: array<atomic<u32>>;
// The frame's emissive triangles (render::emitters), frame.emitters rows.
@group(0) @binding(B_EMITTERS) var<storage, read> emitters: array<Emitter>;
// The suns, points and spots besides the frame's sun, frame.lights rows.
@group(0) @binding(B_LIGHTS) var<storage, read> lights: array<Light>;
// hitbuffer::Reuse::tile_bins: per TILE × TILE tile (frame.moved_tiles_x to a row) the
// moved spheres whose rectangles reach it, moved_bins[moved_bins[t] .. moved_bins[t + 1]].
@group(0) @binding(B_MOVED_BINS) var<storage, read> moved_bins: array<u32>;
// hitbuffer::Reuse::moved_bvh over `moved` (frame.moved_bvh_nodes nodes), its boxes around
// the spheres as tested here.
@group(0) @binding(B_MOVED_BVH) var<storage, read> moved_bvh: array<BvhNode>;
@group(0) @binding(B_MOVED_BVH_ITEMS) var<storage, read> moved_bvh_items: array<u32>;

fn ray_dir(x: u32, y: u32) -> vec3<f32> {
    let w = f32(frame.width);
    let h = f32(frame.height);
    let sx = (2.0 * (f32(x) + 0.5) / w - 1.0) * frame.forward.w * frame.right.w;
    let sy = (1.0 - 2.0 * (f32(y) + 0.5) / h) * frame.forward.w;
    return normalize(frame.forward.xyz + sx * frame.right.xyz + sy * frame.up.xyz);
}

// MOVED_SEARCH_MAX (hitbuffer::MOVED_SEARCH_MAX, from the prelude): above this many moved
// instances, a pixel that a moved sphere crosses searches every instance.

// primary::Todo
const TODO_KEEP: u32 = 0u;
const TODO_ALL: u32 = 1u;
const TODO_MOVED: u32 = 2u;
// Flags of Hit::reused above how the record was found (its low two bits): the record is
// last frame's (kept, or a moved-only search found nothing nearer), and then shade_main
// kept its colour too.
const RECORD_KEPT: u32 = 4u;
const COLOUR_KEPT: u32 = 8u;

// hitbuffer::Reuse::todo
fn reuse_todo(old: Hit, d: vec3<f32>, x: u32, y: u32) -> u32 {
    if old.instance >= 0 && insts[u32(old.instance)].moved != 0u {
        return TODO_ALL;
    }
    // Without bins, every moved sphere is in the pixel's list.
    var first = 0u;
    var end = frame.moved;
    if frame.moved_tiles_x > 0u {
        let tile = (y / TILE) * frame.moved_tiles_x + x / TILE;
        first = moved_bins[tile];
        end = moved_bins[tile + 1u];
    }
    for (var j = first; j < end; j++) {
        // (A branch, not select(): without bins, moved_bins holds one padding word.)
        var k = j;
        if frame.moved_tiles_x > 0u {
            k = moved_bins[j];
        }
        let m = moved[k];
        if x >= m.rect.x && x <= m.rect.z && y >= m.rect.y && y <= m.rect.w {
            let s = sphere_interval(m.sphere.xyz, m.sphere.w, vec3<f32>(0.0), d);
            if s.x <= s.y && s.x <= old.t {
                return select(TODO_ALL, TODO_MOVED, frame.moved <= 2u * MOVED_SEARCH_MAX);
            }
        }
    }
    return TODO_KEEP;
}

// visibility::nearest_moved: the nearest hit among the moved instances that beats (t,
// instance), the nearest among all the others.
fn nearest_moved(o: vec3<f32>, d: vec3<f32>, t: f32, instance: i32) -> Nearest {
    var best: Nearest;
    best.found = false;
    var best_t = t;
    var best_i = select(0xFFFFFFFFu, u32(instance), instance >= 0);
    // The spheres come in pairs (old, new) per moved instance.
    for (var k = 0u; k < frame.moved; k += 2u) {
        let i = moved[k].instance;
        let s = inst_sphere(i, o, d);
        if s.x > s.y {
            work_culled += 1u;
            continue;
        }
        if s.x > best_t {
            continue;
        }
        work_traced += 1u;
        let tr = trace_one(i, o, d, widen(best_t));
        if tr.hit && (tr.t < best_t || (tr.t == best_t && i < best_i)) {
            best_t = tr.t;
            best_i = i;
            best.found = true;
            best.inst = i;
            best.tr = tr;
        }
    }
    return best;
}

// cpu::record: a hit record from the nearest hit found.
fn hit_record(best: Nearest, d: vec3<f32>, how: u32) -> Hit {
    var h: Hit;
    h.t = BIG;
    h.instance = -1;
    h.reused = how;
    h.work = min(work_traced, 0xFFFFu) | (min(work_culled, 0xFFFFu) << 16u);
    if best.found {
        let inst = insts[best.inst];
        let to_world = mat3x3<f32>(inst.normal_x.xyz, inst.normal_y.xyz, inst.normal_z.xyz);
        // The rows were uploaded as columns of the transpose: n_world = M^-T n.
        var n = normalize(decode_octahedral(best.tr.attr.normal) * to_world);
        var f = best.tr.face_normal * to_world;
        f = select(vec3<f32>(0.0), normalize(f), dot(f, f) > 0.0);
        if !(dot(n, n) > 0.5) {
            n = select(-d, f, dot(f, f) > 0.0);
        }
        if dot(n, d) > 0.0 {
            n = -n;
        }
        h.t = best.tr.t;
        h.instance = i32(best.inst);
        h.albedo = best.tr.attr.albedo;
        h.material = best.tr.attr.normal;
        h.emission = best.tr.attr.emission;
        h.voxel = inst.stretch_size / f32(1u << best.tr.level);
        h.nx = n.x; h.ny = n.y; h.nz = n.z;
        h.fx = f.x; h.fy = f.y; h.fz = f.z;
    }
    return h;
}

@compute @workgroup_size(8, 8, 1)
fn trace_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= frame.width || gid.y >= frame.height {
        return;
    }
    let idx = gid.y * frame.width + gid.x;
    trace_pixel(idx, gid);
    count_pixel(idx);
}

fn trace_pixel(idx: u32, gid: vec3<u32>) {
    let d = ray_dir(gid.x, gid.y);
    if REUSE {
        let old = hits[idx];
        let todo = reuse_todo(old, d, gid.x, gid.y);
        if todo == TODO_KEEP {
            hits[idx].reused = 1u | RECORD_KEPT;
            hits[idx].work = 0u;
            return;
        }
        if todo == TODO_MOVED {
            let best = nearest_moved(vec3<f32>(0.0), d, old.t, old.instance);
            if best.found {
                hits[idx] = hit_record(best, d, TODO_MOVED);
            } else {
                hits[idx].reused = TODO_MOVED | RECORD_KEPT;
                hits[idx].work = min(work_traced, 0xFFFFu) | (min(work_culled, 0xFFFFu) << 16u);
            }
            return;
        }
    }
    hits[idx] = hit_record(nearest(vec3<f32>(0.0), d), d, 0u);
}

// Adds a pixel's primary ray to the frame's statistics (what the host sums from the hit
// records when it reads them back: kept, moved-only, octrees traversed, spheres culled).
fn count_pixel(idx: u32) {
    if frame.count == 0u {
        return;
    }
    let h = hits[idx];
    if (h.reused & 3u) == 1u {
        atomicAdd(&stats[STAT_REUSED], 1u);
    }
    if (h.reused & 3u) == TODO_MOVED {
        atomicAdd(&stats[STAT_MOVED_ONLY], 1u);
    }
    let traced = h.work & 0xFFFFu;
    let culled = h.work >> 16u;
    if traced > 0u {
        atomicAdd(&stats[STAT_INSTANCES_TRACED], traced);
    }
    if culled > 0u {
        atomicAdd(&stats[STAT_SPHERES_CULLED], culled);
    }
}

// brdf::sun_response: the diffuse and Phong lobes lit by the sun, per unit irradiance.
fn sun_response(albedo: vec3<f32>, h: Hit, x: u32, y: u32) -> vec3<f32> {
    let n = vec3<f32>(h.nx, h.ny, h.nz);
    let cosv = dot(n, frame.sun_dir.xyz);
    var f = albedo * (cosv / 3.14159265);
    let ks = specular(h.material);
    if ks > 0.0 {
        let e = shininess_of(h.material);
        let r = reflect(ray_dir(x, y), n);
        let cos_a = min(dot(r, frame.sun_dir.xyz), 1.0);
        if cos_a > 0.0 {
            f += vec3<f32>(ks * (e + 2.0) / 6.28318530718 * pow(cos_a, e) * cosv);
        }
    }
    return f;
}

// scene::lights::spot_falloff: 1 within the inner cone, smoothstep of the cosine to 0 at the
// outer one.
fn spot_falloff(li: Light, out: vec3<f32>) -> f32 {
    let c = dot(li.c.xyz, out);
    let ci = li.b.w;
    let co = li.c.w;
    if c >= ci {
        return 1.0;
    }
    if c <= co || ci <= co {
        return 0.0;
    }
    let x = (c - co) / (ci - co);
    return x * x * (3.0 - 2.0 * x);
}

// scene::lights::Incident.
struct Incident {
    to_light: vec3<f32>,
    distance: f32,
    irradiance: vec3<f32>,
}

// scene::lights::Lights::incident_extra for light k at camera-relative `at` (a light that
// gives nothing there has zero irradiance).
fn incident(k: u32, at: vec3<f32>) -> Incident {
    let li = lights[k];
    var inc: Incident;
    inc.to_light = vec3<f32>(0.0, 0.0, 1.0);
    inc.distance = 0.0;
    inc.irradiance = vec3<f32>(0.0);
    if li.a.w == 0.0 {
        inc.to_light = li.a.xyz;
        inc.distance = BIG;
        inc.irradiance = li.b.xyz;
        return inc;
    }
    let to = li.a.xyz - at;
    let d2 = dot(to, to);
    if !(d2 > 0.0) {
        return inc;
    }
    inc.distance = sqrt(d2);
    inc.to_light = to / inc.distance;
    inc.irradiance = li.b.xyz / d2;
    if li.a.w == 2.0 {
        inc.irradiance *= spot_falloff(li, -inc.to_light);
    }
    return inc;
}

// render::emitters::pcg_hash.
fn pcg_hash(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// render::emitters::light_random.
fn light_random(key: u32, sample: u32) -> vec3<f32> {
    var h = pcg_hash(key ^ pcg_hash(sample + 0x51ED270Bu));
    var u = vec3<f32>(0.0);
    for (var k = 0u; k < 3u; k++) {
        h = pcg_hash(h);
        u[k] = f32(h >> 8u) / 16777216.0;
    }
    return u;
}

// brdf::sun_response for light arriving from unit direction l, the lobe from the normal
// word `material` (0: diffuse only).
fn light_response(albedo: vec3<f32>, material: u32, n: vec3<f32>, d: vec3<f32>, l: vec3<f32>) -> vec3<f32> {
    let cosv = dot(n, l);
    if cosv <= 0.0 {
        return vec3<f32>(0.0);
    }
    var f = albedo * (cosv / 3.14159265);
    let ks = specular(material);
    if ks > 0.0 {
        let e = shininess_of(material);
        let cos_a = min(dot(reflect(d, n), l), 1.0);
        if cos_a > 0.0 {
            f += vec3<f32>(ks * (e + 2.0) / 6.28318530718 * pow(cos_a, e) * cosv);
        }
    }
    return f;
}

// EmitterTable::sample: the point that sample `s` of pixel (or cell) `key` picks on the
// emitters (by power, then uniform by area) and the row it lies on.
struct EmitterPick {
    index: u32,
    p: vec3<f32>,
}

fn emitter_pick(key: u32, s: u32) -> EmitterPick {
    let count = frame.emitters;
    let u = light_random(key, s);
    // The first row whose cumulative fraction exceeds u.x.
    var lo = 0u;
    var hi = count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if emitters[mid].e2.w <= u.x {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    let index = min(lo, count - 1u);
    let e = emitters[index];
    let su = sqrt(u.y);
    return EmitterPick(index, e.a.xyz + e.e1.xyz * (su * (1.0 - u.z)) + e.e2.xyz * (su * u.z));
}

// One sample of render::emitters::emitter_light before its shadow test: the row it picked
// (NO_EMITTER when the sample adds nothing), the point a shadow ray ends at (short of the
// emitter's own voxels) and the light it brings unshadowed.
const NO_EMITTER: u32 = 0xFFFFFFFFu;

struct EmitterSample {
    index: u32,
    end: vec3<f32>,
    light: vec3<f32>,
}

fn emitter_sample(key: u32, s: u32, at: vec3<f32>, n: vec3<f32>, d: vec3<f32>, albedo: vec3<f32>, material: u32) -> EmitterSample {
    let none = EmitterSample(NO_EMITTER, vec3<f32>(0.0), vec3<f32>(0.0));
    let pick = emitter_pick(key, s);
    let e = emitters[pick.index];
    let to = pick.p - at;
    let dist2 = dot(to, to);
    if !(dist2 > 0.0) {
        return none;
    }
    let wi = to / sqrt(dist2);
    let cos_light = -dot(e.normal.xyz, wi);
    if cos_light <= 0.0 || dot(n, wi) <= 0.0 {
        return none;
    }
    let response = light_response(albedo, material, n, d, wi);
    if all(response == vec3<f32>(0.0)) {
        return none;
    }
    let pdf_area = e.normal.w / e.e1.w;
    return EmitterSample(pick.index, pick.p + e.normal.xyz * e.a.w, response * e.emission.xyz * (cos_light / (dist2 * pdf_area)));
}

// render::emitters::emitter_light: the emitters' light reflected towards the viewer at `at`
// (camera-relative), from `samples` points picked by power and area, each with a shadow ray
// from `start` that ends short of the emitter's own voxels. (With GI's cone shadows,
// gi_emitter_light in gi_trace.wgsl instead.)
fn emitter_light(key: u32, samples: u32, at: vec3<f32>, start: vec3<f32>, n: vec3<f32>, d: vec3<f32>, albedo: vec3<f32>, material: u32) -> vec3<f32> {
    if frame.emitters == 0u || samples == 0u {
        return vec3<f32>(0.0);
    }
    var sum = vec3<f32>(0.0);
    for (var s = 0u; s < samples; s++) {
        let l = emitter_sample(key, s, at, n, d, albedo, material);
        if l.index == NO_EMITTER {
            continue;
        }
        let ray = l.end - start;
        let len = length(ray);
        if !(len > 0.0) {
            continue;
        }
        if SHADOWS {
            if frame.count != 0u {
                atomicAdd(&stats[STAT_SHADOW_RAYS], 1u);
            }
            if occluded(start, ray / len, len) {
                continue;
            }
        }
        sum += l.light;
    }
    return sum / f32(samples);
}

// cpu::leave: where a hit's shadow rays start, off the surface along its normals.
fn shadow_start(h: Hit, d: vec3<f32>) -> vec3<f32> {
    let n = vec3<f32>(h.nx, h.ny, h.nz);
    return d * h.t + n * h.voxel + vec3<f32>(h.fx, h.fy, h.fz) * (0.1 * h.voxel);
}

// hitbuffer::Reuse::shadow_valid: whether a kept hit's colour is last frame's, its sun
// shadow ray (when it has one) meeting no moved sphere, old or new. The sphere test is
// occluded()'s own, on the same spheres from the same start, so an instance this misses is
// one occluded() never traces, last frame or this one.
fn shadow_valid(h: Hit, x: u32, y: u32) -> bool {
    let n = vec3<f32>(h.nx, h.ny, h.nz);
    if !SHADOWS || h.instance < 0 || frame.sun_dir.w <= 0.0 || !(dot(n, frame.sun_dir.xyz) > 0.0) {
        return true;
    }
    let start = shadow_start(h, ray_dir(x, y));
    let to_sun = frame.sun_dir.xyz;
    if frame.moved_bvh_nodes > 0u {
        // Any order will do: a box the ray misses holds no sphere it meets. A full stack
        // falls through to testing every sphere, which gives the same answer.
        var stack: array<u32, 32>;
        var sp = 0u;
        var overflow = false;
        if box_entry(moved_bvh[0].lo.xyz, moved_bvh[0].hi.xyz, start, to_sun, BIG) < BIG {
            stack[0] = 0u;
            sp = 1u;
        }
        while sp > 0u && !overflow {
            sp -= 1u;
            let node = moved_bvh[stack[sp]];
            let first = bitcast<u32>(node.lo.w);
            let count = bitcast<u32>(node.hi.w);
            if count > 0u {
                for (var j = first; j < first + count; j++) {
                    let m = moved[moved_bvh_items[j]];
                    let s = sphere_interval(m.sphere.xyz, m.sphere.w, start, to_sun);
                    if s.x <= s.y {
                        return false;
                    }
                }
            } else {
                for (var c = first; c < first + 2u; c++) {
                    if box_entry(moved_bvh[c].lo.xyz, moved_bvh[c].hi.xyz, start, to_sun, BIG) < BIG {
                        if sp == 32u {
                            overflow = true;
                        } else {
                            stack[sp] = c;
                            sp += 1u;
                        }
                    }
                }
            }
        }
        if !overflow {
            return true;
        }
    }
    for (var k = 0u; k < frame.moved; k++) {
        let s = sphere_interval(moved[k].sphere.xyz, moved[k].sphere.w, start, to_sun);
        if s.x <= s.y {
            return false;
        }
    }
    return true;
}

// The light a hit receives besides the ambient term: the sun (with its shadow ray), the
// emitters' light (emitter_light) and the hit's own emission.
fn direct_light(h: Hit, x: u32, y: u32, albedo: vec3<f32>) -> vec3<f32> {
    var c = vec3<f32>(0.0);
    let n = vec3<f32>(h.nx, h.ny, h.nz);
    if frame.sun_dir.w > 0.0 {
        let cosv = dot(n, frame.sun_dir.xyz);
        if cosv > 0.0 {
            var visible = true;
            if SHADOWS {
                if frame.count != 0u {
                    atomicAdd(&stats[STAT_SHADOW_RAYS], 1u);
                }
                visible = !occluded(shadow_start(h, ray_dir(x, y)), frame.sun_dir.xyz, BIG);
            }
            if visible {
                c += sun_response(albedo, h, x, y) * frame.sun_irradiance.xyz;
            }
        }
    }
    for (var k = 0u; k < frame.lights; k++) {
        let d = ray_dir(x, y);
        let inc = incident(k, d * h.t);
        if !(max(inc.irradiance.x, max(inc.irradiance.y, inc.irradiance.z)) > 0.0) || dot(n, inc.to_light) <= 0.0 {
            continue;
        }
        var visible = true;
        if SHADOWS {
            if frame.count != 0u {
                atomicAdd(&stats[STAT_SHADOW_RAYS], 1u);
            }
            visible = !occluded(shadow_start(h, d), inc.to_light, inc.distance);
        }
        if visible {
            c += light_response(albedo, h.material, n, d, inc.to_light) * inc.irradiance;
        }
    }
    // With GI's cone shadows (and shadows on) shade_gi_main adds the emitters' light.
    if frame.emitter_samples > 0u && !(GI_CONE_SHADOWS && SHADOWS) {
        let d = ray_dir(x, y);
        let at = d * h.t;
        let start = shadow_start(h, d);
        c += emitter_light(y * frame.width + x, frame.emitter_samples, at, start, n, d, albedo, h.material);
    }
    if frame.sky.w > 0.0 {
        c += emission(h.emission);
    }
    return c;
}

// What both shading entry points do first: the pixel's index in the hit buffer, or NO_PIXEL
// when there is nothing left to shade (outside the image, or a miss, which gets the sky).
const NO_PIXEL: u32 = 0xFFFFFFFFu;

fn pixel_to_shade(gid: vec3<u32>) -> u32 {
    if gid.x >= frame.width || gid.y >= frame.height {
        return NO_PIXEL;
    }
    let idx = gid.y * frame.width + gid.x;
    if hits[idx].instance < 0 {
        radiance[idx] = vec4<f32>(frame.sky.xyz, 1.0);
        return NO_PIXEL;
    }
    return idx;
}

// Without GI the ambient term is the flat sky: albedo * sky.
@compute @workgroup_size(8, 8, 1)
fn shade_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if frame.keep_colours != 0u && gid.x < frame.width && gid.y < frame.height {
        let k = gid.y * frame.width + gid.x;
        if (hits[k].reused & RECORD_KEPT) != 0u && shadow_valid(hits[k], gid.x, gid.y) {
            // Every input of the colour (a miss's too: the sky) is last frame's, which
            // radiance[k] holds.
            hits[k].reused |= COLOUR_KEPT;
            if frame.count != 0u {
                atomicAdd(&stats[STAT_SHADE_REUSED], 1u);
            }
            return;
        }
    }
    let idx = pixel_to_shade(gid);
    if idx == NO_PIXEL {
        return;
    }
    let h = hits[idx];
    let albedo = albedo_linear(h.albedo);
    // The sky is uniform: either lobe's ambient term is its reflectance times the sky.
    let ambient = (albedo + vec3<f32>(specular(h.material))) * frame.sky.xyz;
    radiance[idx] = vec4<f32>(ambient + direct_light(h, gid.x, gid.y, albedo), 1.0);
}
