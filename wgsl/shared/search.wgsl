// The instance searches (render::visibility): which instance a ray hits first, and whether
// anything blocks it. Shared by trace.wgsl (a frame's rays) and cast.wgsl (a caller's rays).
// Needs layout.wgsl and traverse.wgsl and an override SEARCH (0 plain, 1 cull, 2 cull +
// sort, 3 BVH). The scene's bindings, which both modules bind alike, are declared here.

@group(0) @binding(B_NODES) var<storage, read> nodes: array<u32>;
@group(0) @binding(B_ATTRS) var<storage, read> attrs: array<Attr>;
@group(0) @binding(B_PARTS) var<storage, read> parts: array<Part>;
@group(0) @binding(B_INSTS) var<storage, read> insts: array<Inst>;
@group(0) @binding(B_FRAME) var<uniform> frame: Frame;
@group(0) @binding(B_BVH) var<storage, read> bvh: array<BvhNode>;
@group(0) @binding(B_BVH_ITEMS) var<storage, read> bvh_items: array<u32>;
@group(0) @binding(B_NODES_HI) var<storage, read> nodes_hi: array<u32>;
@group(0) @binding(B_ATTRS_HI) var<storage, read> attrs_hi: array<Attr>;

// Candidates kept per ray for the depth sort; more falls back to culling without sorting.
const MAX_CANDIDATES: u32 = 16u;

// render::instances::sphere_interval: (t0, t1), or (BIG, -BIG) for a miss.
fn sphere_interval(c: vec3<f32>, radius: f32, o: vec3<f32>, d: vec3<f32>) -> vec2<f32> {
    let oc = c - o;
    let b = dot(oc, d);
    let cc = dot(oc, oc) - radius * radius;
    let disc = b * b - cc;
    if !(disc >= 0.0) {
        return vec2<f32>(BIG, -BIG);
    }
    let s = sqrt(disc);
    if b + s < 0.0 {
        return vec2<f32>(BIG, -BIG);
    }
    return vec2<f32>(b - s, b + s);
}

fn inst_sphere(i: u32, o: vec3<f32>, d: vec3<f32>) -> vec2<f32> {
    let s = insts[i].sphere;
    return sphere_interval(s.xyz, s.w, o, d);
}

fn to_unit_point(inst: Inst, p: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(inst.to_unit_x.xyz, p) + inst.to_unit_x.w, dot(inst.to_unit_y.xyz, p) + inst.to_unit_y.w, dot(inst.to_unit_z.xyz, p) + inst.to_unit_z.w);
}

fn to_unit_vector(inst: Inst, d: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(inst.to_unit_x.xyz, d), dot(inst.to_unit_y.xyz, d), dot(inst.to_unit_z.xyz, d));
}

// visibility::trace_one
fn trace_one(i: u32, o: vec3<f32>, d: vec3<f32>, t_max: f32) -> Traced {
    let inst = insts[i];
    let r = unit_ray(to_unit_point(inst, o), to_unit_vector(inst, d));
    if !r.ok {
        var miss: Traced;
        miss.hit = false;
        return miss;
    }
    return trace_unit(parts[inst.part], r, 0.0, t_max, frame.max_level);
}

struct Nearest {
    found: bool,
    inst: u32,
    tr: Traced,
}

// visibility::keep: nearest t, ties to the lower instance index.
fn keep(best: ptr<function, Nearest>, i: u32, tr: Traced) {
    if !tr.hit {
        return;
    }
    if !(*best).found || tr.t < (*best).tr.t || (tr.t == (*best).tr.t && i < (*best).inst) {
        (*best).found = true;
        (*best).inst = i;
        (*best).tr = tr;
    }
}

// The t_max for tracing an instance that must find any hit at or before t, the best so far
// (twin of visibility.rs `widen`): the internal-unit conversion rounds, so four ulps more.
fn widen(t: f32) -> f32 {
    if t >= 0.0 && t < BIG {
        return bitcast<f32>(bitcast<u32>(t) + 4u);
    }
    return t;
}

fn bound(best: Nearest) -> f32 {
    return select(BIG, best.tr.t, best.found);
}

fn box_entry(lo: vec3<f32>, hi: vec3<f32>, o: vec3<f32>, d: vec3<f32>, t_max: f32) -> f32 {
    var t0 = 0.0;
    var t1 = t_max;
    for (var i = 0u; i < 3u; i++) {
        if d[i] == 0.0 {
            if o[i] < lo[i] || o[i] > hi[i] {
                return BIG;
            }
        } else {
            let a = (lo[i] - o[i]) / d[i];
            let b = (hi[i] - o[i]) / d[i];
            t0 = max(t0, min(a, b));
            t1 = min(t1, max(a, b));
        }
    }
    return select(BIG, t0, t0 <= t1);
}

// What the primary search of this invocation cost (visibility::Work).
var<private> work_traced: u32;
var<private> work_culled: u32;

fn nearest_cull(o: vec3<f32>, d: vec3<f32>) -> Nearest {
    var best: Nearest;
    best.found = false;
    for (var i = 0u; i < frame.instances; i++) {
        let s = inst_sphere(i, o, d);
        if s.x <= s.y {
            work_traced += 1u;
            keep(&best, i, trace_one(i, o, d, BIG));
        } else {
            work_culled += 1u;
        }
    }
    return best;
}

// visibility::nearest
fn nearest(o: vec3<f32>, d: vec3<f32>) -> Nearest {
    var best: Nearest;
    best.found = false;
    if SEARCH == 0u {
        for (var i = 0u; i < frame.instances; i++) {
            work_traced += 1u;
            keep(&best, i, trace_one(i, o, d, BIG));
        }
    } else if SEARCH == 1u {
        best = nearest_cull(o, d);
    } else if SEARCH == 2u {
        var entry: array<f32, 16>;
        var index: array<u32, 16>;
        var n = 0u;
        var overflow = false;
        for (var i = 0u; i < frame.instances; i++) {
            let s = inst_sphere(i, o, d);
            if s.x > s.y {
                work_culled += 1u;
                continue;
            }
            if n == MAX_CANDIDATES {
                overflow = true;
                break;
            }
            // Insertion sort by (entry, index).
            var k = n;
            while k > 0u && (entry[k - 1u] > s.x || (entry[k - 1u] == s.x && index[k - 1u] > i)) {
                entry[k] = entry[k - 1u];
                index[k] = index[k - 1u];
                k -= 1u;
            }
            entry[k] = s.x;
            index[k] = i;
            n += 1u;
        }
        if overflow {
            // Counted again by the culling search.
            work_culled = 0u;
            return nearest_cull(o, d);
        }
        for (var k = 0u; k < n; k++) {
            let t_max = bound(best);
            if entry[k] > t_max {
                break;
            }
            work_traced += 1u;
            keep(&best, index[k], trace_one(index[k], o, d, widen(t_max)));
        }
    } else {
        // A pop pushes at most two, so the stack holds at most the tree's depth + 1 entries:
        // the host's median-split trees (render::bvh::Bvh::build_with) stay under 34 levels
        // for any u32 count. A deeper tree would overflow; then the culling search answers
        // instead of losing the children that did not fit.
        var stack_node: array<u32, 64>;
        var stack_t: array<f32, 64>;
        var sp = 0u;
        var overflow = false;
        let root = box_entry(bvh[0].lo.xyz, bvh[0].hi.xyz, o, d, BIG);
        if frame.bvh_nodes > 0u && root < BIG {
            stack_node[0] = 0u;
            stack_t[0] = root;
            sp = 1u;
        }
        while sp > 0u && !overflow {
            sp -= 1u;
            let n = stack_node[sp];
            if stack_t[sp] > bound(best) {
                continue;
            }
            let node = bvh[n];
            let first = bitcast<u32>(node.lo.w);
            let count = bitcast<u32>(node.hi.w);
            if count > 0u {
                for (var k = first; k < first + count; k++) {
                    let i = bvh_items[k];
                    let s = inst_sphere(i, o, d);
                    let t_max = bound(best);
                    if s.x > s.y {
                        work_culled += 1u;
                        continue;
                    }
                    if s.x > t_max {
                        continue;
                    }
                    work_traced += 1u;
                    keep(&best, i, trace_one(i, o, d, widen(t_max)));
                }
            } else {
                let t_max = bound(best);
                let el = box_entry(bvh[first].lo.xyz, bvh[first].hi.xyz, o, d, t_max);
                let er = box_entry(bvh[first + 1u].lo.xyz, bvh[first + 1u].hi.xyz, o, d, t_max);
                // Push the farther child first so the nearer one is popped first.
                let wanted = u32(el < BIG) + u32(er < BIG);
                if sp + wanted > 64u {
                    overflow = true;
                } else if el < BIG && er < BIG {
                    if el <= er {
                        stack_node[sp] = first + 1u; stack_t[sp] = er;
                        stack_node[sp + 1u] = first; stack_t[sp + 1u] = el;
                    } else {
                        stack_node[sp] = first; stack_t[sp] = el;
                        stack_node[sp + 1u] = first + 1u; stack_t[sp + 1u] = er;
                    }
                    sp += 2u;
                } else if el < BIG {
                    stack_node[sp] = first; stack_t[sp] = el;
                    sp += 1u;
                } else if er < BIG {
                    stack_node[sp] = first + 1u; stack_t[sp] = er;
                    sp += 1u;
                }
            }
        }
        if overflow {
            // Counted again by the culling search.
            work_traced = 0u;
            work_culled = 0u;
            return nearest_cull(o, d);
        }
    }
    return best;
}

// visibility::occluded: any hit ends the search.
fn occluded(o: vec3<f32>, d: vec3<f32>, t_max: f32) -> bool {
    // With the instance BVH: walk it (any order will do for an any-hit query). A full stack
    // falls through to the sphere loop below, which gives the same answer.
    if SEARCH == 3u && frame.bvh_nodes > 0u {
        var stack: array<u32, 64>;
        var sp = 0u;
        var overflow = false;
        if box_entry(bvh[0].lo.xyz, bvh[0].hi.xyz, o, d, t_max) < BIG {
            stack[0] = 0u;
            sp = 1u;
        }
        while sp > 0u && !overflow {
            sp -= 1u;
            let node = bvh[stack[sp]];
            let first = bitcast<u32>(node.lo.w);
            let count = bitcast<u32>(node.hi.w);
            if count > 0u {
                for (var k = first; k < first + count; k++) {
                    let i = bvh_items[k];
                    let s = inst_sphere(i, o, d);
                    if s.x <= s.y && s.x <= t_max && trace_one(i, o, d, t_max).hit {
                        return true;
                    }
                }
            } else {
                for (var c = first; c < first + 2u; c++) {
                    if box_entry(bvh[c].lo.xyz, bvh[c].hi.xyz, o, d, t_max) < BIG {
                        if sp == 64u {
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
            return false;
        }
    }
    for (var i = 0u; i < frame.instances; i++) {
        if SEARCH != 0u {
            let s = inst_sphere(i, o, d);
            if s.x > s.y || s.x > t_max {
                continue;
            }
        }
        if trace_one(i, o, d, t_max).hit {
            return true;
        }
    }
    return false;
}
