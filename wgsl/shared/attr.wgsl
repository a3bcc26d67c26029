// Decoding the packed attributes (voxray::svo::Attr): octahedral normals, sRGB albedo, the
// RGB9E5 emission and the specular lobe. Shared by the tracer and the GI passes. Each function
// is named after its Rust twin (a method of Attr becomes a function of the packed word).

// svo::format::decode_octahedral (Attr::normal).
fn decode_octahedral(v: u32) -> vec3<f32> {
    // Two 12-bit signed fields (Attr::normal); the top byte is the specular lobe.
    let x = max(f32(bitcast<i32>(v << 20u) >> 20u) / 2047.0, -1.0);
    let y = max(f32(bitcast<i32>(v << 8u) >> 20u) / 2047.0, -1.0);
    let z = 1.0 - abs(x) - abs(y);
    var n = vec3<f32>(x, y, z);
    if z < 0.0 {
        n.x = (1.0 - abs(y)) * select(-1.0, 1.0, x >= 0.0);
        n.y = (1.0 - abs(x)) * select(-1.0, 1.0, y >= 0.0);
    }
    let l = length(n);
    return select(vec3<f32>(0.0, 0.0, 1.0), n / l, l > 0.0);
}

// svo::srgb8_to_linear.
fn srgb8_to_linear(c: u32) -> f32 {
    let s = f32(c) / 255.0;
    return select(pow((s + 0.055) / 1.055, 2.4), s / 12.92, s <= 0.04045);
}

// Attr::albedo_linear.
fn albedo_linear(a: u32) -> vec3<f32> {
    return vec3<f32>(srgb8_to_linear(a & 0xFFu), srgb8_to_linear((a >> 8u) & 0xFFu), srgb8_to_linear((a >> 16u) & 0xFFu));
}

// svo::format::decode_rgb9e5 (Attr::emission): three 9-bit mantissas times 2^(E - 24),
// exact in f32 on both sides.
fn decode_rgb9e5(v: u32) -> vec3<f32> {
    let scale = bitcast<f32>((((v >> 27u) + 103u) & 0xFFu) << 23u);
    return vec3<f32>(f32(v & 511u), f32((v >> 9u) & 511u), f32((v >> 18u) & 511u)) * scale;
}

// Attr::emission.
fn emission(emission_word: u32) -> vec3<f32> {
    return decode_rgb9e5(emission_word);
}

// Attr::specular: reflectance (S/15)^2 from the normal word's bits 24-27.
fn specular(normal_word: u32) -> f32 {
    let s = f32((normal_word >> 24u) & 15u) / 15.0;
    return s * s;
}

// brdf::shininess_of_gloss of Attr::gloss: the Phong exponent 2^(10 G/15).
fn shininess_of(normal_word: u32) -> f32 {
    return exp2(10.0 * f32(normal_word >> 28u) / 15.0);
}
