// Voxel transformation (the WGSL twin of Volume::splat): one thread per cached voxel of every
// instance, moved by its job's matrix into volume grid coordinates and added to the nearest
// cell or split over the 8 cells around it by trilinear weights. Sums accumulate in fixed point
// with atomicAdd (WGSL has no float atomics; layout in gi_fixed.wgsl).
// Needs layout.wgsl, attr.wgsl, gi_fixed.wgsl and gi_splat.wgsl.

@group(0) @binding(0) var<storage, read> voxels: array<CacheVoxel>;
@group(0) @binding(1) var<storage, read> jobs: array<GiJob>;
@group(0) @binding(2) var<storage, read_write> accum: array<atomic<u32>>;
@group(0) @binding(3) var<uniform> splat: GiSplat;

fn add_cell(c: vec3<i32>, w: f32, albedo: vec3<f32>, n: vec3<f32>, e: vec3<f32>) {
    if w <= 0.0 {
        return;
    }
    let r = i32(splat.res);
    if any(c < vec3<i32>(0)) || any(c >= vec3<i32>(r)) {
        atomicAdd(&accum[splat.res * splat.res * splat.res * STRIDE], u32(round(w * OUT_FIX)));
        return;
    }
    let i = (u32(c.x) + splat.res * (u32(c.y) + splat.res * u32(c.z))) * STRIDE;
    add_to_cell(i, w, albedo, n, e);
}

@compute @workgroup_size(64, 1, 1)
fn splat_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = thread_index(gid);
    if t >= splat.threads {
        return;
    }
    let job = job_of(t);
    let v = voxels[job.voxel_base + (t - job.first_thread)];
    let m = 1023u;
    let c = vec4<f32>(f32(v.coord & m), f32((v.coord >> 10u) & m), f32((v.coord >> 20u) & m), 1.0);
    let g = vec3<f32>(dot(job.grid_x, c), dot(job.grid_y, c), dot(job.grid_z, c));
    let albedo = albedo_of(v.albedo);
    let e = emission_of(v.albedo);
    let on = decode_normal(v.normal);
    var n = vec3<f32>(dot(job.normal_x.xyz, on), dot(job.normal_y.xyz, on), dot(job.normal_z.xyz, on));
    n = select(vec3<f32>(0.0), normalize(n), dot(n, n) > 0.0);
    if splat.nearest != 0u {
        add_cell(vec3<i32>(floor(g + 0.5)), 1.0, albedo, n, e);
        return;
    }
    let base = floor(g);
    let f = g - base;
    let b = vec3<i32>(base);
    for (var k = 0u; k < 8u; k++) {
        let d = vec3<u32>(k & 1u, (k >> 1u) & 1u, k >> 2u);
        let w3 = select(1.0 - f, f, d == vec3<u32>(1u));
        add_cell(b + vec3<i32>(d), w3.x * w3.y * w3.z, albedo, n, e);
    }
}
