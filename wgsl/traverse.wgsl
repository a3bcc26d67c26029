// Revelles' parametric octree traversal: the WGSL twin of src/traverse.rs and of
// UnitRay::from_unit in src/ray.rs. Same function names, same order of steps; comments
// point at the differences (f32 only: no f64 rebasing or f64 hit t on the GPU).
//
// Needs: layout.wgsl, and the bindings `nodes`, `nodes_hi` (array<Node>) and `attrs`,
// `attrs_hi` (array<Attr>): a pool larger than one binding continues in its `_hi` half.

// First pool index held by the `_hi` bindings (u32::MAX: everything in the first binding).
override NODE_SPLIT: u32 = 4294967295u;
override ATTR_SPLIT: u32 = 4294967295u;

fn pool_node(i: u32) -> Node {
    if i < NODE_SPLIT {
        return nodes[i];
    }
    return nodes_hi[i - NODE_SPLIT];
}

fn pool_attr(i: u32) -> Attr {
    if i < ATTR_SPLIT {
        return attrs[i];
    }
    return attrs_hi[i - ATTR_SPLIT];
}

const MAX_DEPTH: u32 = 20u;
// Direction components below this fraction of the largest are parallel (Revelles §3.3).
const PARALLEL_RATIO: f32 = 9.094947e-13; // 2^-40
// Stands in for ±infinity (WGSL has no infinity literal); only compared, never summed.
const BIG: f32 = 3.0e38;
const MAX_UNIT_ORIGIN: f32 = 1099511627776.0; // 2^40

struct UnitRay {
    origin: vec3<f32>,
    inv_dir: vec3<f32>,
    dir: vec3<f32>,
    mirror: u32,
    parallel: u32,
    t_scale: f32,
    t_offset: f32,
    ok: bool,
}

fn is_finite3(v: vec3<f32>) -> bool {
    return all(v == v) && all(abs(v) <= vec3<f32>(3.4028235e38));
}

// ray::parallel_axes
fn parallel_axes(d: vec3<f32>) -> u32 {
    let m = max(abs(d.x), max(abs(d.y), abs(d.z)));
    var mask = 0u;
    for (var i = 0u; i < 3u; i++) {
        if abs(d[i]) < PARALLEL_RATIO * m {
            mask |= 1u << i;
        }
    }
    return mask;
}

// UnitRay::from_unit: move the origin to the cube entry, rescale by a power of two,
// mirror by the sign bit.
fn unit_ray(origin_in: vec3<f32>, dir: vec3<f32>) -> UnitRay {
    var r: UnitRay;
    r.ok = false;
    if !is_finite3(origin_in) || !is_finite3(dir) {
        return r;
    }
    let m = max(abs(dir.x), max(abs(dir.y), abs(dir.z)));
    if !(m >= 1e-30) {
        return r;
    }
    let parallel = parallel_axes(dir);
    var t_enter = -BIG;
    var t_exit = BIG;
    for (var i = 0u; i < 3u; i++) {
        if (parallel & (1u << i)) != 0u {
            if !(origin_in[i] >= 0.0 && origin_in[i] < 1.0) {
                return r;
            }
        } else {
            let a = -origin_in[i] / dir[i];
            let b = (1.0 - origin_in[i]) / dir[i];
            t_enter = max(t_enter, min(a, b));
            t_exit = min(t_exit, max(a, b));
        }
    }
    if !(t_enter <= t_exit) {
        return r;
    }
    var t_offset = 0.0;
    if t_enter > 0.0 || t_exit < 0.0 {
        t_offset = t_enter;
    }
    var origin = origin_in;
    for (var i = 0u; i < 3u; i++) {
        if (parallel & (1u << i)) == 0u {
            origin[i] = origin_in[i] + t_offset * dir[i];
        }
    }
    // m = fract * 2^exp with fract in [0.5, 1): scale by 2^(1 - exp) puts m in [1, 2).
    let e = frexp(m).exp;
    let t_scale = ldexp(1.0, 1 - e);
    let d = dir * t_scale;
    r.t_scale = t_scale;
    r.t_offset = t_offset;
    r.parallel = parallel;
    r.mirror = 0u;
    for (var i = 0u; i < 3u; i++) {
        let o = origin[i];
        if !(abs(o) <= MAX_UNIT_ORIGIN) {
            return r;
        }
        if (parallel & (1u << i)) != 0u {
            r.origin[i] = o;
            r.inv_dir[i] = 0.0;
            r.dir[i] = 0.0;
        } else if (bitcast<u32>(d[i]) & 0x80000000u) != 0u {
            r.mirror |= 1u << i;
            r.origin[i] = 1.0 - o;
            r.inv_dir[i] = 1.0 / -d[i];
            r.dir[i] = -d[i];
        } else {
            r.origin[i] = o;
            r.inv_dir[i] = 1.0 / d[i];
            r.dir[i] = d[i];
        }
    }
    r.ok = true;
    return r;
}

// The direction was multiplied by t_scale: internal t = (world t - t_offset) / t_scale.
fn to_internal(r: UnitRay, t: f32) -> f32 {
    return (t - r.t_offset) / r.t_scale;
}

fn to_world(r: UnitRay, t: f32) -> f32 {
    return r.t_offset + t * r.t_scale;
}

struct Frame_ {
    slot: u32,
    child: u32,
    coord: vec3<u32>,
    t0: vec3<f32>,
    t1: vec3<f32>,
    tm: vec3<f32>,
}

struct Traced {
    hit: bool,
    t: f32,
    level: u32,
    coord: vec3<u32>,
    attr: Attr,
    face_normal: vec3<f32>,
    steps: u32,
}

fn max3(v: vec3<f32>) -> f32 { return max(v.x, max(v.y, v.z)); }
fn min3(v: vec3<f32>) -> f32 { return min(v.x, min(v.y, v.z)); }

fn argmin3(v: vec3<f32>) -> u32 {
    if v.x <= v.y && v.x <= v.z { return 0u; }
    if v.y <= v.z { return 1u; }
    return 2u;
}

fn argmax3(v: vec3<f32>) -> u32 {
    if v.x >= v.y && v.x >= v.z { return 0u; }
    if v.y >= v.z { return 1u; }
    return 2u;
}

// traverse::midpoints (Revelles §3.3 for parallel axes)
fn midpoints(r: UnitRay, t0: vec3<f32>, t1: vec3<f32>, level: u32, coord: vec3<u32>) -> vec3<f32> {
    var tm: vec3<f32>;
    for (var i = 0u; i < 3u; i++) {
        if (r.parallel & (1u << i)) != 0u {
            let mid = f32(2u * coord[i] + 1u) / f32(1u << (level + 1u));
            tm[i] = select(BIG, -BIG, r.origin[i] >= mid);
        } else {
            tm[i] = 0.5 * (t0[i] + t1[i]);
        }
    }
    return tm;
}

// traverse::first_node (Revelles §3.2)
fn first_node(tm: vec3<f32>, t_entry: f32) -> u32 {
    return u32(tm.x < t_entry) | (u32(tm.y < t_entry) << 1u) | (u32(tm.z < t_entry) << 2u);
}

fn node_at(part: Part, slot: u32) -> Node {
    return pool_node(part.node_base + slot);
}

// Svo::child_slot (with far pointers)
fn child_slot(part: Part, slot: u32, octant: u32) -> u32 {
    let n = node_at(part, slot);
    let ptr = n.desc >> 17u;
    var group = slot + ptr;
    if ((n.desc >> 16u) & 1u) == 1u {
        group = group + node_at(part, group).desc;
    }
    let valid = (n.desc >> 8u) & 0xFFu;
    let inner = valid & ~(n.desc & 0xFFu);
    return group + countOneBits(inner & ((1u << octant) - 1u));
}

// Svo::child_attr
fn child_attr(part: Part, slot: u32, octant: u32) -> Attr {
    let n = node_at(part, slot);
    let valid = (n.desc >> 8u) & 0xFFu;
    return pool_attr(part.attr_base + n.attr_base + countOneBits(valid & ((1u << octant) - 1u)));
}

fn step_bound(depth: u32) -> u32 {
    let d = min(depth, MAX_DEPTH);
    return 5u * (3u * ((1u << d) - 1u) + d) + 1u;
}

// traverse::finish: back to unmirrored coordinates; t from the voxel's entry planes (in f32
// here: the CPU uses its f64 ray).
fn finish(r: UnitRay, te: f32, t_min: f32, level: u32, coord: vec3<u32>, attr: Attr, ct0: vec3<f32>) -> Traced {
    var out: Traced;
    let inv_size = 1.0 / f32(1u << level);
    var t_entry = -BIG;
    for (var i = 0u; i < 3u; i++) {
        if (r.parallel & (1u << i)) == 0u {
            t_entry = max(t_entry, (f32(coord[i]) * inv_size - r.origin[i]) / r.dir[i]);
        }
    }
    let entered = te >= t_min;
    var t_internal = t_min;
    if entered {
        t_internal = max(t_entry, t_min);
    }
    out.t = to_world(r, t_internal);
    out.hit = abs(out.t) <= 3.4e38;
    let top = (1u << level) - 1u;
    var real = coord;
    for (var i = 0u; i < 3u; i++) {
        if (r.mirror & (1u << i)) != 0u {
            real[i] = top - real[i];
        }
    }
    out.coord = real;
    out.level = level;
    out.attr = attr;
    out.face_normal = vec3<f32>(0.0);
    if entered {
        let axis = argmax3(ct0);
        out.face_normal[axis] = select(-1.0, 1.0, (r.mirror & (1u << axis)) != 0u);
    }
    return out;
}

// traverse::trace_unit
fn trace_unit(part: Part, r: UnitRay, t_min_w: f32, t_max_w: f32, max_level_in: u32) -> Traced {
    var miss: Traced;
    miss.hit = false;
    miss.steps = 0u;
    let t_min = to_internal(r, max(t_min_w, -3.0e38));
    let t_max = to_internal(r, t_max_w);
    if !(t_min <= t_max) {
        return miss;
    }
    let max_level = min(max_level_in, part.depth);
    var t0: vec3<f32>;
    var t1: vec3<f32>;
    for (var i = 0u; i < 3u; i++) {
        if (r.parallel & (1u << i)) != 0u {
            if !(r.origin[i] >= 0.0 && r.origin[i] < 1.0) {
                return miss;
            }
            t0[i] = -BIG;
            t1[i] = BIG;
        } else {
            t0[i] = -r.origin[i] * r.inv_dir[i];
            t1[i] = (1.0 - r.origin[i]) * r.inv_dir[i];
        }
    }
    let t_enter = max3(t0);
    let t_exit = min3(t1);
    if t_enter > t_exit || t_exit < t_min || t_enter > t_max {
        return miss;
    }
    if max_level == 0u {
        var h = finish(r, t_enter, t_min, 0u, vec3<u32>(0u), pool_attr(part.attr_base), t0);
        h.steps = 1u;
        return h;
    }
    var stack: array<Frame_, 20>;
    let tm0 = midpoints(r, t0, t1, 0u, vec3<u32>(0u));
    stack[0] = Frame_(0u, first_node(tm0, max(t_enter, t_min)), vec3<u32>(0u), t0, t1, tm0);
    var sp = 1u;
    let bound = step_bound(part.depth);
    var steps = 0u;
    loop {
        steps += 1u;
        if steps > bound {
            miss.steps = steps;
            return miss;
        }
        let level = sp - 1u;
        let f = stack[sp - 1u];
        if f.child >= 8u {
            sp -= 1u;
            if sp == 0u {
                miss.steps = steps;
                return miss;
            }
            continue;
        }
        let c = f.child;
        var ct0: vec3<f32>;
        var ct1: vec3<f32>;
        for (var i = 0u; i < 3u; i++) {
            if (c & (1u << i)) != 0u {
                ct0[i] = f.tm[i];
                ct1[i] = f.t1[i];
            } else {
                ct0[i] = f.t0[i];
                ct1[i] = f.tm[i];
            }
        }
        // Revelles Table 2: leave through the exit plane; leaving the parent if that bit is set.
        let exit_bit = 1u << argmin3(ct1);
        stack[sp - 1u].child = select(c | exit_bit, 8u, (c & exit_bit) != 0u);

        let te = max3(ct0);
        let tx = min3(ct1);
        if te > t_max {
            miss.steps = steps;
            return miss;
        }
        if tx < t_min {
            continue;
        }
        let octant = c ^ r.mirror;
        let node = node_at(part, f.slot);
        if (((node.desc >> 8u) & 0xFFu) & (1u << octant)) == 0u {
            continue;
        }
        let child_level = level + 1u;
        let coord = vec3<u32>(2u * f.coord.x + (c & 1u), 2u * f.coord.y + ((c >> 1u) & 1u), 2u * f.coord.z + ((c >> 2u) & 1u));
        if ((node.desc & 0xFFu) & (1u << octant)) != 0u || child_level >= max_level {
            var h = finish(r, te, t_min, child_level, coord, child_attr(part, f.slot, octant), ct0);
            h.steps = steps;
            return h;
        }
        let slot = child_slot(part, f.slot, octant);
        let tm = midpoints(r, ct0, ct1, child_level, coord);
        stack[sp] = Frame_(slot, first_node(tm, max(te, t_min)), coord, ct0, ct1, tm);
        sp += 1u;
    }
    return miss;
}
