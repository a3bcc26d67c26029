// Scatters packed rows into a buffer that holds the rest already: row k of `scatter_src`
// goes to row `scatter_ids[k]` of `scatter_dst`. A crowd's frame rewrites a few thousand of
// its 80 000 instances, scattered through the buffer: one upload and this pass instead of a
// queue write per run of them. Rust twin: src/gpu/scatter.rs.

struct ScatterParams {
    // Rows to copy.
    rows: u32,
    // Words (vec4<u32>) per row.
    row_vec4s: u32,
    // Invocations per row of workgroups (the dispatch is two-dimensional past 65 535 groups).
    stride: u32,
    pad: u32,
}

@group(0) @binding(0) var<uniform> scatter: ScatterParams;
@group(0) @binding(1) var<storage, read> scatter_src: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read> scatter_ids: array<u32>;
@group(0) @binding(3) var<storage, read_write> scatter_dst: array<vec4<u32>>;

@compute @workgroup_size(64)
fn scatter_rows(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * scatter.stride;
    if (i >= scatter.rows * scatter.row_vec4s) {
        return;
    }
    let row = i / scatter.row_vec4s;
    let word = i - row * scatter.row_vec4s;
    scatter_dst[scatter_ids[row] * scatter.row_vec4s + word] = scatter_src[i];
}
