// Traces an arbitrary list of rays through one SVO (parts[0]), in its unit cube: the GPU side
// of the stability suite. Needs layout.wgsl and traverse.wgsl.

@group(0) @binding(0) var<storage, read> nodes: array<u32>;
@group(0) @binding(1) var<storage, read> attrs: array<Attr>;
@group(0) @binding(2) var<storage, read> parts: array<Part>;
@group(0) @binding(3) var<storage, read> rays_in: array<RayIn>;
@group(0) @binding(4) var<storage, read_write> rays_out: array<RayOut>;
// One SVO: a single binding each; the `_hi` halves are unused placeholders.
@group(0) @binding(5) var<storage, read> nodes_hi: array<u32>;
@group(0) @binding(6) var<storage, read> attrs_hi: array<Attr>;

@compute @workgroup_size(64, 1, 1)
fn rays_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if i >= arrayLength(&rays_in) {
        return;
    }
    let q = rays_in[i];
    var out: RayOut;
    out.hit = 0u;
    let r = unit_ray(q.origin.xyz, q.dir.xyz);
    if r.ok {
        let tr = trace_unit(parts[0], r, q.t_min, q.t_max, q.max_level);
        out.steps = tr.steps;
        if tr.hit {
            out.hit = 1u;
            out.t = tr.t;
            out.level = tr.level;
            out.coord = vec4<u32>(tr.coord, 0u);
        }
    }
    rays_out[i] = out;
}
