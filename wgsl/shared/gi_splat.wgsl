// What the two passes that write the GI volume share (gi_transform.wgsl, gi_revoxelize.wgsl,
// which declare `jobs`, `splat` and the atomic `accum`): thread -> job (jobs hold consecutive
// thread ranges from first_thread) and the fixed-point add into one cell.

// The thread's index in the flattened dispatch (spread over y past 65 535 groups).
fn thread_index(gid: vec3<u32>) -> u32 {
    return gid.x + gid.y * splat.row_threads;
}

// The job holding thread t: the last whose first thread is at most t.
fn job_of(t: u32) -> GiJob {
    var lo = 0u;
    var hi = splat.jobs;
    while hi - lo > 1u {
        let mid = (lo + hi) / 2u;
        if jobs[mid].first_thread <= t {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    return jobs[lo];
}

// Adds weight w with its albedo, normal and emission to the cell whose first word is i.
fn add_to_cell(i: u32, w: f32, albedo: vec3<f32>, n: vec3<f32>, e: vec3<f32>) {
    atomicAdd(&accum[i], fixed(w, FIX));
    atomicAdd(&accum[i + 1u], fixed(w * albedo.x, FIX));
    atomicAdd(&accum[i + 2u], fixed(w * albedo.y, FIX));
    atomicAdd(&accum[i + 3u], fixed(w * albedo.z, FIX));
    atomicAdd(&accum[i + 4u], fixed(w * n.x, FIX));
    atomicAdd(&accum[i + 5u], fixed(w * n.y, FIX));
    atomicAdd(&accum[i + 6u], fixed(w * n.z, FIX));
    if any(e > vec3<f32>(0.0)) {
        atomicAdd(&accum[i + 7u], fixed(w * e.x, EMIT_FIX));
        atomicAdd(&accum[i + 8u], fixed(w * e.y, EMIT_FIX));
        atomicAdd(&accum[i + 9u], fixed(w * e.z, EMIT_FIX));
    }
}
