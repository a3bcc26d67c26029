// Voxel transformation (the WGSL twin of gi::volume::for_each_target): one thread per cached
// voxel of every instance, moved by its job's matrix into volume grid coordinates and handed to
// the nearest cell or split over the 8 cells around it by trilinear weights. What a cell does
// with it is the layout's add_cell (gi_dense_cell.wgsl: fixed-point atomicAdd, WGSL has no
// float atomics; gi_sparse_cell.wgsl: mark the brick, or add into it), which also declares the
// bindings. Needs layout.wgsl, attr.wgsl, gi_fixed.wgsl, gi_splat.wgsl and one of those.

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
    let albedo = albedo_linear(v.albedo);
    let e = min(emission(v.emission), vec3<f32>(GI_MAX_EMISSION));
    let on = decode_octahedral(v.normal);
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
