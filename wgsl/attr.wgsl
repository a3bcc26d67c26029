// Decoding the packed attributes (voxray::svo::Attr): octahedral normals, sRGB albedo and
// the emission scale. Shared by the tracer and the GI passes.

fn decode_normal(v: u32) -> vec3<f32> {
    let x = max(f32(bitcast<i32>(v << 16u) >> 16u) / 32767.0, -1.0);
    let y = max(f32(bitcast<i32>(v) >> 16u) / 32767.0, -1.0);
    let z = 1.0 - abs(x) - abs(y);
    var n = vec3<f32>(x, y, z);
    if z < 0.0 {
        n.x = (1.0 - abs(y)) * select(-1.0, 1.0, x >= 0.0);
        n.y = (1.0 - abs(x)) * select(-1.0, 1.0, y >= 0.0);
    }
    let l = length(n);
    return select(vec3<f32>(0.0, 0.0, 1.0), n / l, l > 0.0);
}

fn srgb_to_linear(c: u32) -> f32 {
    let s = f32(c) / 255.0;
    return select(pow((s + 0.055) / 1.055, 2.4), s / 12.92, s <= 0.04045);
}

fn albedo_of(a: u32) -> vec3<f32> {
    return vec3<f32>(srgb_to_linear(a & 0xFFu), srgb_to_linear((a >> 8u) & 0xFFu), srgb_to_linear((a >> 16u) & 0xFFu));
}

// Attr::emission: emitted radiance = albedo * E / 16.
fn emission_of(a: u32) -> vec3<f32> {
    return albedo_of(a) * (f32(a >> 24u) / 16.0);
}
