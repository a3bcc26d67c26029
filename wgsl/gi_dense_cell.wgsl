// The dense volume's cells for the voxel transformation (gi_transform.wgsl): every cell of the
// res³ volume has its STRIDE words in `accum`, then the counter of the weight outside.

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
