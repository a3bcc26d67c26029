// One step down the GI level chain (the WGSL twin of gi::levels::build): each coarser cell
// averages its 2x2x2 finer cells; opacity is surface coverage, the children's summed alpha / 4
// clamped to 1, and the premultiplied radiance scales with the same clamp. levels_main steps a
// dense level; brick_levels_main steps the sparse volume's bricks (gi::sparse::SparseLevels):
// 8³ → 4³ → 2³ within each brick, then 2³ → the brick's cell of the dense top level.
// Needs layout.wgsl.

@group(0) @binding(0) var<storage, read_write> levels: array<vec4<f32>>;
@group(0) @binding(1) var<uniform> step: GiLevelStep;

// gi::levels::coarsen: the 8 children's sum into the coarser cell.
fn coarsen(sum: vec4<f32>) -> vec4<f32> {
    let a = sum.w / 4.0;
    if a <= 0.0 {
        return vec4<f32>(0.0);
    }
    let keep = min(a, 1.0) / a;
    return vec4<f32>(sum.xyz / 4.0 * keep, min(a, 1.0));
}

@compute @workgroup_size(4, 4, 4)
fn levels_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if any(gid >= vec3<u32>(step.dst_res)) {
        return;
    }
    var sum = vec4<f32>(0.0);
    for (var k = 0u; k < 8u; k++) {
        let c = 2u * gid + vec3<u32>(k & 1u, (k >> 1u) & 1u, k >> 2u);
        if all(c < vec3<u32>(step.src_res)) {
            sum += levels[step.src_offset + c.x + step.src_res * (c.y + step.src_res * c.z)];
        }
    }
    levels[step.dst_offset + gid.x + step.dst_res * (gid.y + step.dst_res * gid.z)] = coarsen(sum);
}

// gi::levels::build_aniso_from, one step: a thread per coarser cell writes its six faces
// (gi::levels::coarsen_faces: per face, the children composited front to back along its
// direction, column by column, the four columns averaged). Face f of a level starts at
// offset + f * res³; step.src_faces says whether the finer level has faces (level 0 has not).
fn child_face(face: u32, c: vec3<u32>) -> vec4<f32> {
    if any(c >= vec3<u32>(step.src_res)) {
        return vec4<f32>(0.0);
    }
    let i = c.x + step.src_res * (c.y + step.src_res * c.z);
    let n = step.src_res * step.src_res * step.src_res;
    return levels[step.src_offset + select(0u, face * n, step.src_faces != 0u) + i];
}

@compute @workgroup_size(4, 4, 4)
fn levels_aniso_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if any(gid >= vec3<u32>(step.dst_res)) {
        return;
    }
    let n = step.dst_res * step.dst_res * step.dst_res;
    let dst = gid.x + step.dst_res * (gid.y + step.dst_res * gid.z);
    for (var face = 0u; face < 6u; face++) {
        let axis = face / 2u;
        // Travelling +axis, the child at the lower coordinate is in front.
        let front_bit = face % 2u;
        var sum = vec4<f32>(0.0);
        for (var k = 0u; k < 8u; k++) {
            if ((k >> axis) & 1u) != front_bit {
                continue;
            }
            let back = k ^ (1u << axis);
            let front = child_face(face, 2u * gid + vec3<u32>(k & 1u, (k >> 1u) & 1u, k >> 2u));
            let behind = child_face(face, 2u * gid + vec3<u32>(back & 1u, (back >> 1u) & 1u, back >> 2u));
            sum += front + behind * (1.0 - front.w);
        }
        levels[step.dst_offset + face * n + dst] = sum * 0.25;
    }
}

// One mip of the level texture (LevelStore::Texture).
@group(0) @binding(3) var level_tex: texture_storage_3d<rgba16float, write>;

// Copies level src_res³ at src_offset into the mip of dst_res³ texels (a power of two, at
// least src_res: the texels past the level hold nothing, as cells past a level do).
@compute @workgroup_size(4, 4, 4)
fn texture_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if any(gid >= vec3<u32>(step.dst_res)) {
        return;
    }
    var v = vec4<f32>(0.0);
    if all(gid < vec3<u32>(step.src_res)) {
        v = levels[step.src_offset + gid.x + step.src_res * (gid.y + step.src_res * gid.z)];
    }
    textureStore(level_tex, gid, v);
}

// The top cell of each brick (written by gi_sparse_cell.wgsl's alloc_main).
@group(0) @binding(2) var<storage, read> brick_top: array<u32>;

// One thread per cell of the coarser brick level (src_res / dst_res cells per brick side; a
// dst_res of 1 writes the dense top level at the brick's top cell).
@compute @workgroup_size(64, 1, 1)
fn brick_levels_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * step.row_threads;
    let side = step.dst_res;
    let n = side * side * side;
    // The pool is dispatched whole; step.bricks (copied in by the GPU) are allocated.
    if i >= step.bricks * n {
        return;
    }
    let b = i / n;
    let k = i % n;
    let c = vec3<u32>(k % side, (k / side) % side, k / (side * side));
    let fs = step.src_res;
    let src = step.src_offset + b * fs * fs * fs;
    var sum = vec4<f32>(0.0);
    for (var j = 0u; j < 8u; j++) {
        let f = 2u * c + vec3<u32>(j & 1u, (j >> 1u) & 1u, j >> 2u);
        sum += levels[src + f.x + fs * (f.y + fs * f.z)];
    }
    var dst = step.dst_offset + b * n + k;
    if side == 1u {
        dst = step.dst_offset + brick_top[b];
    }
    levels[dst] = coarsen(sum);
}
