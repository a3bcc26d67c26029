// One step down the GI level chain (the WGSL twin of gi::levels::build): each coarser cell
// averages its 2x2x2 finer cells; opacity is surface coverage, the children's summed alpha / 4
// clamped to 1, and the premultiplied radiance scales with the same clamp. Needs layout.wgsl.

@group(0) @binding(0) var<storage, read_write> levels: array<vec4<f32>>;
@group(0) @binding(1) var<uniform> step: GiLevelStep;

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
    let a = sum.w / 4.0;
    var out = vec4<f32>(0.0);
    if a > 0.0 {
        let keep = min(a, 1.0) / a;
        out = vec4<f32>(sum.xyz / 4.0 * keep, min(a, 1.0));
    }
    levels[step.dst_offset + gid.x + step.dst_res * (gid.y + step.dst_res * gid.z)] = out;
}
