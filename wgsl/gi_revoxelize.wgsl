// The re-voxelization baseline (the WGSL twin of voxelize::voxelize_in + Volume::write_grid):
// every frame each instance's triangles are moved by its job's matrix into volume grid
// coordinates (cell c spans [c, c + 1)) and voxelized into the volume again, one thread per
// triangle: the cells of its bounding box that pass the exact triangle/box test (separating
// axes) get the clipped area as weight, with weight x albedo, normal and emission, in fixed
// point (tri_main); then every touched cell becomes one unit of occupancy with the weighted
// mean attributes (finish_main), the layout gi_trace.wgsl's injection reads.
// Needs layout.wgsl, gi_fixed.wgsl and gi_splat.wgsl.

@group(0) @binding(0) var<storage, read> tris: array<GiTri>;
@group(0) @binding(1) var<storage, read> jobs: array<GiJob>;
@group(0) @binding(2) var<storage, read_write> accum: array<atomic<u32>>;
@group(0) @binding(3) var<uniform> splat: GiSplat;

// voxelize::separated
fn separated(axis: vec3<f32>, v0: vec3<f32>, v1: vec3<f32>, v2: vec3<f32>, half: f32) -> bool {
    let p = vec3<f32>(dot(axis, v0), dot(axis, v1), dot(axis, v2));
    let r = half * (abs(axis.x) + abs(axis.y) + abs(axis.z));
    return min(p.x, min(p.y, p.z)) > r || max(p.x, max(p.y, p.z)) < -r;
}

// voxelize::tri_box_overlap for the unit cell with corner c.
fn overlaps(c: vec3<f32>, a: vec3<f32>, b: vec3<f32>, d: vec3<f32>) -> bool {
    let centre = c + 0.5;
    let v0 = a - centre;
    let v1 = b - centre;
    let v2 = d - centre;
    let e = array<vec3<f32>, 3>(v1 - v0, v2 - v1, v0 - v2);
    for (var i = 0u; i < 3u; i++) {
        var ax = vec3<f32>(0.0);
        ax[i] = 1.0;
        for (var k = 0u; k < 3u; k++) {
            if separated(cross(ax, e[k]), v0, v1, v2, 0.5) {
                return false;
            }
        }
    }
    let mn = min(v0, min(v1, v2));
    let mx = max(v0, max(v1, v2));
    if any(mn > vec3<f32>(0.5)) || any(mx < vec3<f32>(-0.5)) {
        return false;
    }
    return !separated(cross(e[0], e[1]), v0, v1, v2, 0.5);
}

// voxelize::clip_area: area of the triangle inside the unit cell at c (Sutherland-Hodgman).
fn clipped_area(c: vec3<f32>, a: vec3<f32>, b: vec3<f32>, d: vec3<f32>) -> f32 {
    var poly: array<vec3<f32>, 10>;
    var next: array<vec3<f32>, 10>;
    poly[0] = a;
    poly[1] = b;
    poly[2] = d;
    var n = 3u;
    for (var plane = 0u; plane < 6u; plane++) {
        let axis = plane / 2u;
        let above = (plane & 1u) == 0u;
        let bound = c[axis] + select(1.0, 0.0, above);
        var m = 0u;
        for (var i = 0u; i < n; i++) {
            let p = poly[i];
            let q = poly[(i + 1u) % n];
            let ip = select(p[axis] <= bound, p[axis] >= bound, above);
            let iq = select(q[axis] <= bound, q[axis] >= bound, above);
            if ip && m < 10u {
                next[m] = p;
                m++;
            }
            if ip != iq && m < 10u {
                let t = (bound - p[axis]) / (q[axis] - p[axis]);
                var r = p + (q - p) * t;
                r[axis] = bound;
                next[m] = r;
                m++;
            }
        }
        n = m;
        if n < 3u {
            return 0.0;
        }
        for (var i = 0u; i < n; i++) {
            poly[i] = next[i];
        }
    }
    var area = 0.0;
    for (var i = 1u; i + 1u < n; i++) {
        area += length(cross(poly[i] - poly[0], poly[i + 1u] - poly[0])) * 0.5;
    }
    return area;
}

@compute @workgroup_size(64, 1, 1)
fn tri_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = thread_index(gid);
    if t >= splat.threads {
        return;
    }
    let job = job_of(t);
    let tri = tris[job.voxel_base + (t - job.first_thread)];
    let pa = vec4<f32>(tri.a.xyz, 1.0);
    let pb = vec4<f32>(tri.b.xyz, 1.0);
    let pc = vec4<f32>(tri.c.xyz, 1.0);
    let a = vec3<f32>(dot(job.grid_x, pa), dot(job.grid_y, pa), dot(job.grid_z, pa));
    let b = vec3<f32>(dot(job.grid_x, pb), dot(job.grid_y, pb), dot(job.grid_z, pb));
    let d = vec3<f32>(dot(job.grid_x, pc), dot(job.grid_y, pc), dot(job.grid_z, pc));
    let nrm = cross(b - a, d - a);
    if !(dot(nrm, nrm) > 0.0) {
        return;
    }
    let normal = normalize(nrm);
    let albedo = vec3<f32>(tri.a.w, tri.b.w, tri.c.w);
    let r = i32(splat.res);
    let c0 = clamp(vec3<i32>(floor(min(a, min(b, d)))), vec3<i32>(0), vec3<i32>(r - 1));
    let c1 = clamp(vec3<i32>(floor(max(a, max(b, d)))), vec3<i32>(0), vec3<i32>(r - 1));
    // Entirely outside the volume: nothing to write.
    if any(max(a, max(b, d)) < vec3<f32>(0.0)) || any(min(a, min(b, d)) > vec3<f32>(f32(r))) {
        return;
    }
    for (var z = c0.z; z <= c1.z; z++) {
        for (var y = c0.y; y <= c1.y; y++) {
            for (var x = c0.x; x <= c1.x; x++) {
                let c = vec3<f32>(f32(x), f32(y), f32(z));
                if !overlaps(c, a, b, d) {
                    continue;
                }
                // A triangle only touching the cell keeps it, with the smallest weight.
                let w = max(clipped_area(c, a, b, d), 1.0 / FIX);
                let i = (u32(x) + splat.res * (u32(y) + splat.res * u32(z))) * STRIDE;
                add_to_cell(i, w, albedo, normal, tri.emission.xyz);
            }
        }
    }
}

// One unit of occupancy per touched cell, with its weighted mean albedo, unit normal and mean
// emission (as Volume::write_grid adds a voxel).
@compute @workgroup_size(4, 4, 4)
fn finish_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = splat.res;
    if any(gid >= vec3<u32>(r)) {
        return;
    }
    let i = (gid.x + r * (gid.y + r * gid.z)) * STRIDE;
    let w = f32(atomicLoad(&accum[i]));
    if w <= 0.0 {
        return;
    }
    var v: array<f32, 10>;
    for (var k = 1u; k < 10u; k++) {
        v[k] = f32(bitcast<i32>(atomicLoad(&accum[i + k])));
    }
    let n = vec3<f32>(v[4], v[5], v[6]);
    let nn = select(vec3<f32>(0.0), normalize(n), dot(n, n) > 0.0);
    atomicStore(&accum[i], fixed(1.0, FIX));
    for (var k = 1u; k < 4u; k++) {
        atomicStore(&accum[i + k], fixed(v[k] / w, FIX));
    }
    for (var k = 0u; k < 3u; k++) {
        atomicStore(&accum[i + 4u + k], fixed(nn[k], FIX));
    }
    for (var k = 7u; k < 10u; k++) {
        // v[k] / EMIT_FIX over w / FIX, stored at EMIT_FIX.
        atomicStore(&accum[i + k], fixed(v[k] * FIX / (EMIT_FIX * w), EMIT_FIX));
    }
}
