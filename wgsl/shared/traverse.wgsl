// Revelles' parametric octree traversal: the WGSL twin of src/traverse/mod.rs and of
// UnitRay::from_unit in src/ray.rs. Same function names, same order of steps; comments
// point at the differences (f32 only: no f64 rebasing or f64 hit t on the GPU).
//
// Needs: layout.wgsl, and the bindings `nodes`, `nodes_hi` (array<u32>: every part's links
// and child masks, voxray::gpu::layout::part_words) and `attrs`, `attrs_hi` (array<Attr>):
// a pool larger than one binding continues in its `_hi` half.

// First pool index held by the `_hi` bindings (u32::MAX: everything in the first binding).
override NODE_SPLIT: u32 = 4294967295u;
override ATTR_SPLIT: u32 = 4294967295u;

fn pool_word(i: u32) -> u32 {
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

// MAX_DEPTH, PARALLEL_RATIO (direction components below this fraction of the largest are
// parallel, Revelles §3.3) and MAX_UNIT_ORIGIN come from the prelude (src/gpu/prelude.rs).
// Stands in for ±infinity (WGSL has no infinity literal); only compared, never summed.
const BIG: f32 = 3.0e38;

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

fn argmax3(v: vec3<f32>) -> u32 {
    if v.x >= v.y && v.x >= v.z { return 0u; }
    if v.y >= v.z { return 1u; }
    return 2u;
}

// traverse::Planes::at: t at the planes k * size of each axis (exact positions), as
// (p - o) * inv; on a parallel axis -BIG below the origin and BIG on or above it (§3.3).
fn planes_at(r: UnitRay, k: vec3<u32>, size: f32) -> vec3<f32> {
    let p = vec3<f32>(k) * size;
    var t = (p - r.origin) * r.inv_dir;
    for (var i = 0u; i < 3u; i++) {
        if (r.parallel & (1u << i)) != 0u {
            t[i] = select(BIG, -BIG, r.origin[i] >= p[i]);
        }
    }
    return t;
}

// traverse::Cell: entry planes, midplanes and exit planes of a node (Revelles §3.1).
struct Cell {
    t0: vec3<f32>,
    tm: vec3<f32>,
    t1: vec3<f32>,
}

// traverse::cell_size: 2^-level.
fn cell_size(level: u32) -> f32 {
    return bitcast<f32>((127u - level) << 23u);
}

// traverse::Cell::new: parallel axes are open on both sides.
fn cell_new(r: UnitRay, c: vec3<u32>, size: f32) -> Cell {
    var out = Cell(planes_at(r, c, size), planes_at(r, 2u * c + vec3<u32>(1u), 0.5 * size), planes_at(r, c + vec3<u32>(1u), size));
    for (var i = 0u; i < 3u; i++) {
        if (r.parallel & (1u << i)) != 0u {
            out.t0[i] = -BIG;
            out.t1[i] = BIG;
        }
    }
    return out;
}

// traverse::UPPER: lane i set when child k is the upper half on axis i.
fn upper(k: u32) -> vec3<bool> {
    return vec3<bool>((k & 1u) != 0u, (k & 2u) != 0u, (k & 4u) != 0u);
}

// traverse::first_node (Revelles §3.2; on parallel axes tm is already -BIG or BIG).
fn first_node(tm: vec3<f32>, t_entry: f32) -> u32 {
    return u32(tm.x < t_entry) | (u32(tm.y < t_entry) << 1u) | (u32(tm.z < t_entry) << 2u);
}

// traverse::exit_plane (Revelles Table 2): the bit of the smallest exit t, ties to the lowest axis.
fn exit_plane(t1: vec3<f32>) -> u32 {
    let m = min3(t1);
    if t1.x == m { return 1u; }
    if t1.y == m { return 2u; }
    return 4u;
}

// Svo::masks[node]: four masks to a word.
fn node_mask(part: Part, node: u32) -> u32 {
    return (pool_word(part.mask_base + (node >> 2u)) >> ((node & 3u) * 8u)) & 0xFFu;
}

// svo::rank
fn rank(mask: u32, octant: u32) -> u32 {
    return countOneBits(mask & ((1u << octant) - 1u));
}

// Svo::child_node: the link plus the child's rank.
fn child_node(part: Part, node: u32, mask: u32, octant: u32) -> u32 {
    return pool_word(part.node_base + node) + rank(mask, octant);
}

// Svo::child_attr: the same sum, into the attribute pool.
fn child_attr(part: Part, node: u32, mask: u32, octant: u32) -> Attr {
    return pool_attr(part.attr_base + child_node(part, node, mask, octant));
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
    for (var i = 0u; i < 3u; i++) {
        if (r.parallel & (1u << i)) != 0u && !(r.origin[i] >= 0.0 && r.origin[i] < 1.0) {
            return miss;
        }
    }
    var cell = cell_new(r, vec3<u32>(0u), 1.0);
    let t_enter = max3(cell.t0);
    let t_exit = min3(cell.t1);
    if t_enter > t_exit || t_exit < t_min || t_enter > t_max {
        return miss;
    }
    if max_level == 0u {
        var h = finish(r, t_enter, t_min, 0u, vec3<u32>(0u), pool_attr(part.attr_base), cell.t0);
        h.steps = 1u;
        return h;
    }
    // Frames of the levels above the current node: its number, which of its children is
    // being visited, and per axis the one t-value of it that the child's do not repeat.
    var stack_node: array<u32, 20>;
    var stack_child: array<u32, 20>;
    var stack_keep: array<vec3<f32>, 20>;
    var level = 0u;
    var node = 0u;
    var coord = vec3<u32>(0u);
    var child = first_node(cell.tm, max(t_enter, t_min));
    let bound = step_bound(part.depth);
    var steps = 0u;
    loop {
        steps += 1u;
        if steps > bound {
            miss.steps = steps;
            return miss;
        }
        let up = upper(child);
        let ct0 = select(cell.t0, cell.tm, up);
        let ct1 = select(cell.tm, cell.t1, up);
        let te = max3(ct0);
        if te > t_max {
            miss.steps = steps;
            return miss;
        }
        let octant = child ^ r.mirror;
        let mask = node_mask(part, node);
        if (mask & (1u << octant)) != 0u && min3(ct1) >= t_min {
            let child_level = level + 1u;
            let c = 2u * coord + vec3<u32>(child & 1u, (child >> 1u) & 1u, (child >> 2u) & 1u);
            if child_level >= max_level {
                var h = finish(r, te, t_min, child_level, c, child_attr(part, node, mask, octant), ct0);
                h.steps = steps;
                return h;
            }
            stack_node[level] = node;
            stack_child[level] = child;
            stack_keep[level] = select(cell.t1, cell.t0, up);
            node = child_node(part, node, mask, octant);
            coord = c;
            level = child_level;
            // Revelles §3.1: the midplanes halfway in t; §3.3 on parallel axes.
            var tm = (ct0 + ct1) * 0.5;
            if r.parallel != 0u {
                let side = planes_at(r, 2u * c + vec3<u32>(1u), cell_size(level + 1u));
                for (var i = 0u; i < 3u; i++) {
                    if (r.parallel & (1u << i)) != 0u {
                        tm[i] = side[i];
                    }
                }
            }
            cell = Cell(ct0, tm, ct1);
            child = first_node(tm, max(te, t_min));
            continue;
        }
        // Revelles Table 2: leave through the exit plane; leaving the parent if that bit is set.
        var exit_bit = exit_plane(ct1);
        while (child & exit_bit) != 0u {
            if level == 0u {
                miss.steps = steps;
                return miss;
            }
            steps += 1u;
            level -= 1u;
            // The parent's t-values from this node's and the kept ones.
            let k = stack_child[level];
            let kup = upper(k);
            let keep = stack_keep[level];
            let t1 = cell.t1;
            cell = Cell(select(cell.t0, keep, kup), select(cell.t1, cell.t0, kup), select(keep, cell.t1, kup));
            node = stack_node[level];
            coord = coord >> vec3<u32>(1u);
            child = k;
            exit_bit = exit_plane(t1);
        }
        child |= exit_bit;
    }
    return miss;
}
