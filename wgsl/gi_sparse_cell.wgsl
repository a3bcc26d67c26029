// The sparse volume's cells for the voxel transformation (gi_transform.wgsl), the GPU twin of
// gi::sparse::SparseVolume::build: a top table of 8³-cell bricks (res / 8 per side). Three
// dispatches, lock-free: splat_main with splat.mark = 1 marks every top cell a voxel writes,
// alloc_main gives each marked cell the next brick from a counter, splat_main with
// splat.mark = 0 adds each voxel into its brick's cells. The host sizes the brick pool from a
// bound on the bricks (gpu::gi::sparse) and the counter is copied into the uniforms of the passes
// over bricks (the bound keeps every brick handed out within the pool).

@group(0) @binding(0) var<storage, read> voxels: array<CacheVoxel>;
@group(0) @binding(1) var<storage, read> jobs: array<GiJob>;
// STRIDE words per cell, 512 cells per brick (x fastest within a brick), in brick order.
@group(0) @binding(2) var<storage, read_write> accum: array<atomic<u32>>;
@group(0) @binding(3) var<uniform> splat: GiSplat;
// Per top cell: 0 unwritten / 1 marked (mark pass), then its brick or GI_EMPTY (alloc pass).
@group(0) @binding(4) var<storage, read_write> top: array<atomic<u32>>;
// [0]: bricks allocated; [1]: weight outside the volume (OUT_FIX).
@group(0) @binding(5) var<storage, read_write> counters: array<atomic<u32>>;
// The top cell of each brick.
@group(0) @binding(6) var<storage, read_write> brick_top: array<u32>;
// Indirect workgroups (x, y, z) of the passes over bricks: the cell passes (one thread per
// cell), then the brick steps to 4³, 2³ and the top level (one thread per coarser cell).
@group(0) @binding(7) var<storage, read_write> dispatch_args: array<u32>;

// GI_BRICK and GI_EMPTY come from the prelude (src/gpu/prelude.rs).

fn top_index(c: vec3<u32>) -> u32 {
    let tr = splat.res / GI_BRICK;
    let t = c / GI_BRICK;
    return t.x + tr * (t.y + tr * t.z);
}

fn add_cell(c: vec3<i32>, w: f32, albedo: vec3<f32>, n: vec3<f32>, e: vec3<f32>) {
    if w <= 0.0 {
        return;
    }
    let r = i32(splat.res);
    if any(c < vec3<i32>(0)) || any(c >= vec3<i32>(r)) {
        if splat.mark == 0u {
            atomicAdd(&counters[1], u32(round(w * OUT_FIX)));
        }
        return;
    }
    let cu = vec3<u32>(c);
    let t = top_index(cu);
    if splat.mark != 0u {
        // Most voxels land in a brick already marked: read before writing.
        if atomicLoad(&top[t]) == 0u {
            atomicStore(&top[t], 1u);
        }
        return;
    }
    let b = atomicLoad(&top[t]);
    if b == GI_EMPTY {
        return; // unreachable: the mark pass saw this cell
    }
    let l = cu % GI_BRICK;
    let i = (b * GI_BRICK * GI_BRICK * GI_BRICK + l.x + GI_BRICK * (l.y + GI_BRICK * l.z)) * STRIDE;
    add_to_cell(i, w, albedo, n, e);
}

// One thread per top cell: marked cells take the next brick.
@compute @workgroup_size(4, 4, 4)
fn alloc_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let tr = splat.res / GI_BRICK;
    if any(gid >= vec3<u32>(tr)) {
        return;
    }
    let t = gid.x + tr * (gid.y + tr * gid.z);
    if atomicLoad(&top[t]) == 0u {
        atomicStore(&top[t], GI_EMPTY);
        return;
    }
    let b = atomicAdd(&counters[0], 1u);
    atomicStore(&top[t], b);
    brick_top[b] = t;
}

// Workgroups of 64 threads for `threads` threads, spread over y past 65 535 groups: the rule
// of gpu::gi::flat_groups, so a dispatch row holds the row_threads the host wrote whenever
// the count needs more than one row (the pool is at least as large as the count).
fn write_flat_args(k: u32, threads: u32) {
    let groups = (threads + 63u) / 64u;
    dispatch_args[3u * k] = min(groups, 65535u);
    dispatch_args[3u * k + 1u] = (groups + 65534u) / 65535u;
    dispatch_args[3u * k + 2u] = 1u;
}

// One thread, after alloc_main: the passes over bricks get workgroups for the bricks allocated.
@compute @workgroup_size(1, 1, 1)
fn dispatch_main() {
    let bricks = atomicLoad(&counters[0]);
    write_flat_args(0u, bricks * GI_BRICK * GI_BRICK * GI_BRICK);
    for (var l = 1u; l <= GI_BRICK_LEVELS; l++) {
        let side = GI_BRICK >> l;
        write_flat_args(l, bricks * side * side * side);
    }
}
