//! Structs shared with WGSL. Each is `#[repr(C)]` + Pod and must be kept in sync with the
//! struct of the same role in `wgsl/layout.wgsl` (named in its doc line); `tests/layout.rs`
//! compares sizes and offsets. All vec4 fields come first so Rust's packing equals WGSL's.

use bytemuck::{Pod, Zeroable};

/// Where one part's SVO lives in the pools. WGSL: `Part`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuPart {
    /// First node slot of the part in the node pool.
    pub node_base: u32,
    /// First attribute of the part in the attribute pool.
    pub attr_base: u32,
    /// Tree depth.
    pub depth: u32,
    /// Padding.
    pub pad: u32,
}

/// One instance for this frame, camera-relative. WGSL: `Inst`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuInstance {
    /// Rows of camera-relative world → unit cube (xyz: linear, w: translation).
    pub to_unit_x: [f32; 4],
    /// Second row.
    pub to_unit_y: [f32; 4],
    /// Third row.
    pub to_unit_z: [f32; 4],
    /// Rows of the inverse transpose of the world linear part.
    pub normal_x: [f32; 4],
    /// Second row.
    pub normal_y: [f32; 4],
    /// Third row.
    pub normal_z: [f32; 4],
    /// Bounding sphere: camera-relative centre, radius.
    pub sphere: [f32; 4],
    /// Part index.
    pub part: u32,
    /// Largest stretch of the world transform times the part's cube size.
    pub stretch_size: f32,
    /// 1 if the instance moved since the hit buffer's frame.
    pub moved: u32,
    /// Padding.
    pub pad: u32,
}

/// Per-frame uniforms. WGSL: `Frame`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuFrame {
    /// Camera forward; w = tan(vfov / 2).
    pub forward: [f32; 4],
    /// Camera right; w = width / height.
    pub right: [f32; 4],
    /// Camera up.
    pub up: [f32; 4],
    /// Towards the sun; w = 1 with a sun.
    pub sun_dir: [f32; 4],
    /// Sun irradiance.
    pub sun_irradiance: [f32; 4],
    /// Sky radiance; w = 1 when MTL emitters are on.
    pub sky: [f32; 4],
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Instance count.
    pub instances: u32,
    /// Level-of-detail limit.
    pub max_level: u32,
    /// Moved spheres in the moved-sphere buffer.
    pub moved: u32,
    /// BVH nodes (0: no BVH).
    pub bvh_nodes: u32,
    /// Padding.
    pub pad0: u32,
    /// Padding.
    pub pad1: u32,
}

/// One BVH node; `lo[3]`/`hi[3]` hold `first`/`count` as bits. WGSL: `BvhNode`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuBvhNode {
    /// Box minimum, then `first` (bits).
    pub lo: [f32; 4],
    /// Box maximum, then `count` (bits).
    pub hi: [f32; 4],
}

/// One pixel's primary hit. WGSL: `Hit`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuHit {
    /// Ray parameter (huge for a miss).
    pub t: f32,
    /// Instance, −1 for a miss.
    pub instance: i32,
    /// Albedo word of the voxel's attributes.
    pub albedo: u32,
    /// Voxel size in world units.
    pub voxel: f32,
    /// World normal facing the camera.
    pub nx: f32,
    /// y.
    pub ny: f32,
    /// z.
    pub nz: f32,
    /// Face normal (world).
    pub fx: f32,
    /// y.
    pub fy: f32,
    /// z.
    pub fz: f32,
    /// What finding the hit cost: instances traversed (low 16 bits) and instances whose
    /// sphere the ray missed (high 16 bits), each saturating; 0 when reused.
    pub work: u32,
    /// 1 when reused this frame.
    pub reused: u32,
}

/// A moved instance's sphere and pixel rectangle. WGSL: `MovedSphere`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuSphere {
    /// Camera-relative centre, radius.
    pub sphere: [f32; 4],
    /// x0, y0, x1, y1 (inclusive).
    pub rect: [u32; 4],
}

/// One ray of a ray list, in a part's unit cube. WGSL: `RayIn`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuRay {
    /// Origin (w unused).
    pub origin: [f32; 4],
    /// Direction (w unused).
    pub dir: [f32; 4],
    /// Interval start.
    pub t_min: f32,
    /// Interval end.
    pub t_max: f32,
    /// Level-of-detail limit.
    pub max_level: u32,
    /// Padding.
    pub pad: u32,
}

/// A ray-list result. WGSL: `RayOut`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuRayHit {
    /// Hit t.
    pub t: f32,
    /// Level of the voxel.
    pub level: u32,
    /// 1 for a hit.
    pub hit: u32,
    /// Loop iterations.
    pub steps: u32,
    /// Voxel coordinates (w unused).
    pub coord: [u32; 4],
}
