// The GI volume's fixed-point accumulation (voxray::gpu::gi::{FIX, EMIT_FIX, OUT_FIX}): 10
// words per cell — occupancy, weight x albedo (3), weight x normal (3, two's complement: a
// wrapping u32 add is the i32 add), weight x emission (3) — then one counter of the weight
// that fell outside. Shared by the transformation, the re-voxelizer and the tracer's GI passes.

// 1/65536 of a voxel's weight for occupancy, albedo and normal; emission (each voxel's at most
// GI_MAX_EMISSION per channel) at 1/4096; the outside counter at 1/256.
// FIX, EMIT_FIX, OUT_FIX and STRIDE (words per cell) come from the prelude (src/gpu/prelude.rs).

fn fixed(v: f32, scale: f32) -> u32 {
    return bitcast<u32>(i32(round(v * scale)));
}
