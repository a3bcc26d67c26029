// Structs shared between the CPU and the GPU. Each mirrors a #[repr(C)] bytemuck::Pod
// struct in src/ (named above it); tests/layout.rs checks that sizes and offsets agree.

// Mirrors voxray::svo::Node: one 64-bit slot of an SVO's node array.
struct Node {
    // Child descriptor: ptr:15 | far:1 | valid:8 | leaf:8 (high bits first).
    desc: u32,
    // Index of the attributes of the first valid child.
    attr_base: u32,
}

// Mirrors voxray::svo::Attr: attributes of one node or voxel.
struct Attr {
    // R, G, B sRGB-encoded albedo, then E: emitted radiance = albedo * E / 16.
    albedo: u32,
    // Octahedral unit normal, snorm16 x in the low half, y in the high half.
    normal: u32,
}
