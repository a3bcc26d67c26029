// Draws a frame over the window (in the viewport right of the panel): a full-screen triangle.
// `fs_main` samples a CPU frame uploaded as a texture; `fs_radiance` reads a GPU frame's
// linear radiance where the renderer left it (no copy through the host) and encodes it as
// the CPU's `output::srgb8` does: clamped to [0, 1], sRGB transfer function.

@group(0) @binding(0) var frame_tex: texture_2d<f32>;
@group(0) @binding(1) var frame_sampler: sampler;

// The radiance buffer's image and where it lies in the window.
struct PresentInfo {
    // Window pixel of the image's top-left corner.
    origin: vec2<u32>,
    // Image width and height (the buffer's row length is the width).
    size: vec2<u32>,
    // 1: the target is a linear format, so this shader applies the sRGB transfer function;
    // 0: the target is an sRGB format and the hardware encodes.
    encode: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(2) var<storage, read> radiance: array<vec4<f32>>;
@group(0) @binding(3) var<uniform> present_info: PresentInfo;

struct VsOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) uv: vec2<f32>,
}

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> VsOut {
    // (-1,-1), (3,-1), (-1,3): one triangle covering the screen.
    let p = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u)) * 2.0 - 1.0;
    var out: VsOut;
    out.pos = vec4<f32>(p, 0.0, 1.0);
    out.uv = vec2<f32>(p.x * 0.5 + 0.5, 0.5 - p.y * 0.5);
    return out;
}

@fragment
fn fs_main(v: VsOut) -> @location(0) vec4<f32> {
    return textureSample(frame_tex, frame_sampler, v.uv);
}

// The sRGB transfer function of `linear_to_srgb8`, without the 8-bit rounding.
fn linear_to_srgb(x: f32) -> f32 {
    if x <= 0.0031308 {
        return 12.92 * x;
    }
    return 1.055 * pow(x, 1.0 / 2.4) - 0.055;
}

@fragment
fn fs_radiance(v: VsOut) -> @location(0) vec4<f32> {
    let size = max(present_info.size, vec2<u32>(1u));
    let p = vec2<i32>(floor(v.pos.xy)) - vec2<i32>(present_info.origin);
    let q = vec2<u32>(clamp(p, vec2<i32>(0), vec2<i32>(size) - 1));
    let c = radiance[q.y * size.x + q.x].xyz;
    // Non-finite values show black, as on the CPU (x != x is NaN; beyond f32's range is ∞).
    let finite = (c == c) & (abs(c) <= vec3<f32>(3.4e38));
    let l = select(vec3<f32>(0.0), clamp(c, vec3<f32>(0.0), vec3<f32>(1.0)), finite);
    if present_info.encode != 0u {
        return vec4<f32>(linear_to_srgb(l.x), linear_to_srgb(l.y), linear_to_srgb(l.z), 1.0);
    }
    return vec4<f32>(l, 1.0);
}
