// Refits the instance BVH's boxes on the GPU from the instances' spheres (`Inst.sphere`'s
// centre, `Inst.radius`: before the growth for the f32 sphere test), a level of the tree per
// dispatch, deepest first: each node's box from its leaf's spheres or its two children's
// boxes, its links kept. The twin of voxray::render::bvh::Bvh::refit followed by
// voxray::gpu::renderer::gpu_bvh_nodes: a leaf widened by the same slack, an inner box the
// union of its children's (which holds the host's, slack and all), for a crowd posed on the
// GPU (wgsl/pose.wgsl). Rust side: src/gpu/refit.rs.

@group(0) @binding(0) var<uniform> refit_level: RefitLevel;
// Node indices, deepest level first.
@group(0) @binding(1) var<storage, read> refit_order: array<u32>;
@group(0) @binding(2) var<storage, read> refit_items: array<u32>;
@group(0) @binding(3) var<storage, read> refit_insts: array<Inst>;
@group(0) @binding(4) var<storage, read_write> refit_nodes: array<BvhNode>;

const REFIT_FAR: f32 = 3.0e38;

@compute @workgroup_size(64)
fn bvh_refit_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = gid.x + gid.y * 65535u * 64u;
    if (k >= refit_level.count) {
        return;
    }
    let n = refit_order[refit_level.first + k];
    let node = refit_nodes[n];
    let first = bitcast<u32>(node.lo.w);
    let count = bitcast<u32>(node.hi.w);
    var lo = vec3<f32>(REFIT_FAR);
    var hi = vec3<f32>(-REFIT_FAR);
    if (count > 0u) {
        for (var j = first; j < first + count; j++) {
            // The sphere before it was grown for the f32 sphere test, as the host fits boxes.
            let inst = refit_insts[refit_items[j]];
            lo = min(lo, inst.sphere.xyz - vec3<f32>(inst.radius));
            hi = max(hi, inst.sphere.xyz + vec3<f32>(inst.radius));
        }
        // As gpu_bvh_nodes widens each box: 10⁻⁶ of its largest coordinate, more than the
        // rounding of the sums above.
        let slack = vec3<f32>(1e-6 * max(max(max(abs(lo.x), abs(lo.y)), abs(lo.z)), max(max(abs(hi.x), abs(hi.y)), abs(hi.z))));
        lo = lo - slack;
        hi = hi + slack;
    } else {
        let a = refit_nodes[first];
        let b = refit_nodes[first + 1u];
        lo = min(a.lo.xyz, b.lo.xyz);
        hi = max(a.hi.xyz, b.hi.xyz);
    }
    refit_nodes[n] = BvhNode(vec4<f32>(lo, node.lo.w), vec4<f32>(hi, node.hi.w));
}
