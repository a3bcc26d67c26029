//! Structs shared with WGSL. Each is `#[repr(C)]` + Pod and must be kept in sync with the
//! struct of the same role in `wgsl/shared/layout.wgsl` (named in its doc line); `tests/layout.rs`
//! compares sizes and offsets. All vec4 fields come first so Rust's packing equals WGSL's.

use bytemuck::{Pod, Zeroable};

/// Where one part's SVO lives in the pools. WGSL: `Part`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuPart {
    /// Word of the part's first node link in the node pool ([`part_words`]).
    pub node_base: u32,
    /// Word of the part's first four child masks in the node pool.
    pub mask_base: u32,
    /// First attribute of the part in the attribute pool.
    pub attr_base: u32,
    /// Tree depth.
    pub depth: u32,
}

/// One part's words in the node pool: its links, then its child masks four to a word (node
/// `n`'s mask in byte `n % 4`, little-endian). Returns the words and the offset of the masks.
pub fn part_words(svo: &crate::svo::Svo) -> (Vec<u32>, u32) {
    let mut words = svo.links.clone();
    let masks = words.len() as u32;
    words.extend(svo.masks.chunks(4).map(|c| c.iter().rev().fold(0u32, |w, &m| (w << 8) | m as u32)));
    (words, masks)
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
    /// The bounding sphere's radius before it was grown for the f32 sphere test: what the
    /// instance BVH's boxes are fitted to (a far crowd's grown spheres are tens of times
    /// wider than its wheels).
    pub radius: f32,
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
    /// 1: the passes add up the frame's statistics in the `stats` buffer ([`GpuStats`]).
    pub count: u32,
    /// Tiles to a row of the moved spheres' tile bins (0: no bins, every pixel tests every
    /// moved sphere; [`crate::render::hitbuffer::Reuse::tile_bins`]).
    pub moved_tiles_x: u32,
    /// Rows of the emitter buffer ([`GpuEmitter`]).
    pub emitters: u32,
    /// Light samples per shaded point on the emitters ([`crate::scene::Lights::emitter_sampling`]).
    pub emitter_samples: u32,
    /// Rows of the light buffer ([`GpuLight`]: the suns, points and spots besides the sun).
    pub lights: u32,
    /// 1: a pixel whose hit was kept keeps the colour the radiance buffer holds from the
    /// frame in the hit buffer, unless its shadow ray meets a moved sphere (the twin of the
    /// CPU's kept colours; the renderer says when the buffer holds such colours).
    pub keep_colours: u32,
    /// Nodes of the moved spheres' BVH (0: none; kept pixels' shadow rays then test every
    /// moved sphere).
    pub moved_bvh_nodes: u32,
    /// Padding (three words: a uniform array's stride would be 16 bytes).
    pub pad4a: u32,
    /// Padding.
    pub pad4b: u32,
    /// Padding.
    pub pad4c: u32,
}

/// A sun, point or spot light besides the frame's sun ([`crate::scene::Lights::suns`],
/// `points`, `spots`). WGSL: `Light`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuLight {
    /// Sun: direction towards it; point and spot: camera-relative position. w: 0 sun, 1
    /// point, 2 spot.
    pub a: [f32; 4],
    /// Irradiance (sun) or intensity; w: cosine of a spot's inner angle.
    pub b: [f32; 4],
    /// A spot's unit direction; w: cosine of its outer angle.
    pub c: [f32; 4],
}

/// One emissive triangle of the frame, camera-relative ([`crate::render::emitters::WorldEmitter`]
/// with its place in the power distribution). WGSL: `Emitter`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuEmitter {
    /// First corner; w: how far short of a sample its shadow rays end.
    pub a: [f32; 4],
    /// Second corner minus the first; w: area.
    pub e1: [f32; 4],
    /// Third corner minus the first; w: cumulative power fraction up to this row.
    pub e2: [f32; 4],
    /// Unit normal of the lit side; w: probability of picking this row.
    pub normal: [f32; 4],
    /// Emitted radiance; w unused.
    pub emission: [f32; 4],
}

/// The frame's statistics as the trace and shade passes add them up (atomics), when
/// `GpuFrame::count` is 1. WGSL: `stats`, indexed by the `STAT_*` constants.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct GpuStats {
    /// Pixels whose hit record was kept.
    pub reused: u32,
    /// Pixels searched among the moved instances only.
    pub moved_only: u32,
    /// Instance octrees traversed by the traced primary rays.
    pub instances_traced: u32,
    /// Instances skipped because the traced primary rays missed their spheres.
    pub spheres_culled: u32,
    /// Shadow rays traced.
    pub shadow_rays: u32,
    /// Points where GI's diffuse cones were gathered (every shaded hit, or with the
    /// half-resolution gather its samples and the pixels that gathered their own).
    pub gathers: u32,
    /// Pixels whose colour was kept from the frame before (not shaded).
    pub shade_reused: u32,
    /// Padding.
    pub pad: u32,
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
    /// How this frame found the record (low two bits): 0 searched among all instances, 1
    /// kept, 2 searched among the moved instances only; flag 4: the record is last frame's;
    /// flag 8: so is its colour.
    pub reused: u32,
    /// Normal word of the voxel's attributes (its top byte is the specular lobe).
    pub material: u32,
    /// Emission word of the voxel's attributes (RGB9E5).
    pub emission: u32,
}

/// A moved instance's sphere and pixel rectangle. WGSL: `MovedSphere`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuSphere {
    /// Camera-relative centre, radius.
    pub sphere: [f32; 4],
    /// x0, y0, x1, y1 (inclusive).
    pub rect: [u32; 4],
    /// The moved instance (spheres come in pairs, old then new, in ascending instance order).
    pub instance: u32,
    /// Padding to WGSL's 16-byte struct alignment.
    pub pad: [u32; 3],
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

/// What a caller's ray found on the GPU ([`crate::gpu::cast`]). WGSL: `CastOut`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuCastHit {
    /// The instance hit (`u32::MAX`: none); for occlusion, 0 when blocked.
    pub instance: u32,
    /// Distance to the hit along the unit direction.
    pub t: f32,
    /// Level of the voxel.
    pub level: u32,
    /// Padding.
    pub pad: u32,
    /// Voxel coordinates (w unused).
    pub coord: [u32; 4],
    /// The voxel's attribute words: albedo, normal, emission (w unused).
    pub attr: [u32; 4],
    /// Object-space normal of the face entered (w unused; zero when the ray starts inside).
    pub face_normal: [f32; 4],
}

/// One instance's voxel cache moved into the GI volume this frame. WGSL: `GiJob`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuGiJob {
    /// Rows of the map integer cache coordinate → volume grid coordinate (cell c's centre at
    /// c), composed in f64: cache corner and voxel size, world matrix, volume corner and cell.
    pub grid_x: [f32; 4],
    /// Second row.
    pub grid_y: [f32; 4],
    /// Third row.
    pub grid_z: [f32; 4],
    /// Rows of the inverse transpose of the world linear part (object → world normals).
    pub normal_x: [f32; 4],
    /// Second row.
    pub normal_y: [f32; 4],
    /// Third row.
    pub normal_z: [f32; 4],
    /// First voxel of the cache in the voxel pool.
    pub voxel_base: u32,
    /// Voxels in the cache.
    pub voxel_count: u32,
    /// First thread of the dispatch that moves this cache's voxels.
    pub first_thread: u32,
    /// Padding.
    pub pad: u32,
}

/// Uniforms of the voxel transformation pass. WGSL: `GiSplat`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuGiSplat {
    /// Volume cells per side.
    pub res: u32,
    /// Jobs.
    pub jobs: u32,
    /// Threads with a voxel to move (all jobs' voxels).
    pub threads: u32,
    /// Threads per row of the dispatch (the dispatch spreads over y past 65 535 groups).
    pub row_threads: u32,
    /// 1: nearest filtering, 0: 8-neighbour split.
    pub nearest: u32,
    /// Sparse volume: 1 in the pass that marks bricks, 0 in the one that accumulates.
    pub mark: u32,
    /// Padding.
    pub pad1: u32,
    /// Padding.
    pub pad2: u32,
}

/// The GI volume's placement and the cone knobs, for injection and shading. WGSL: `GiFrame`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuGiFrame {
    /// xyz: the volume's corner minus the camera eye; w: the finest cell's edge.
    pub min_cell: [f32; 4],
    /// First element of levels 0–3 in the level buffer.
    pub offsets_a: [u32; 4],
    /// Levels 4–7.
    pub offsets_b: [u32; 4],
    /// Levels 8–11.
    pub offsets_c: [u32; 4],
    /// Cells per side of levels 0–3.
    pub res_a: [u32; 4],
    /// Levels 4–7.
    pub res_b: [u32; 4],
    /// Levels 8–11.
    pub res_c: [u32; 4],
    /// Finest cells per side.
    pub res: u32,
    /// Levels in the chain.
    pub levels: u32,
    /// Diffuse cones.
    pub cones: u32,
    /// GI bounces (more than one: the bounce passes run and injection keeps the direct light).
    pub bounces: u32,
    /// Cone diameter per unit distance: 2 tan(aperture / 2).
    pub spread: f32,
    /// Angle of the cone ring from the normal (radians).
    pub tilt: f32,
    /// Longest cone (world units; f32::MAX for unbounded).
    pub max_distance: f32,
    /// Stored finest cells (res³ dense; the pool's bricks × 512 sparse): the cell passes'
    /// threads.
    pub cells: u32,
    /// Threads per dispatch row of the cell passes (spread over y past 65 535 groups).
    pub row_threads: u32,
    /// Sparse: top-table cells per side (res / 8).
    pub top_res: u32,
    /// Texture levels: the texture's cells per side (res rounded up to a power of two).
    pub tex_size: u32,
    /// 1: glossy hits trace the specular cone (`ConeSettings::specular_cone`); 0: their
    /// specular ambient term is the flat sky's.
    pub specular_cone: u32,
    /// Sparse: bricks allocated (the cell passes' threads past `bricks` × 512 stop); the GPU
    /// copies its count over what the host wrote.
    pub bricks: u32,
    /// 1: the diffuse cones are gathered at half resolution (`render::Gather::Half`).
    pub half: u32,
    /// Samples per row of the half-resolution gather (the image's width halved, rounded up).
    pub half_width: u32,
    /// 1: the diffuse light comes from radiance caches (`render::Gather::Caches`).
    pub caches: u32,
    /// Their tile edge in pixels.
    pub cache_tile: u32,
    /// Texels per side of a cache's map.
    pub cache_res: u32,
    /// Gathering radius in tiles.
    pub cache_radius: u32,
    /// Most caches per tile (slots per tile).
    pub cache_per_tile: u32,
    /// Tiles per row.
    pub cache_tiles_x: u32,
    /// Slots: tiles × per tile.
    pub cache_slots: u32,
    /// vec4 per slot in the map buffer (texels, mips, irradiance map).
    pub cache_stride: u32,
    /// 0: clustered placement, 1: even.
    pub cache_placement: u32,
    /// 2 tan(aperture / 2) of a texel's cone.
    pub cache_spread: f32,
    /// Threads per dispatch row of the cache tracing and convolution passes.
    pub cache_row_threads: u32,
    /// Emitter samples per lit cell in light injection (`GiSettings::cell_light_samples`).
    pub cell_samples: u32,
    /// 1: the bounces' tail is estimated (`GiSettings::bounce_tail`, past one bounce): the
    /// bounce pass sums its workgroups' light past the cells of `gi_next`.
    pub tail: u32,
}

/// One step down the level chain. WGSL: `GiLevelStep`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuGiLevelStep {
    /// First element of the finer level.
    pub src_offset: u32,
    /// Its cells per side.
    pub src_res: u32,
    /// First element of the coarser level.
    pub dst_offset: u32,
    /// Its cells per side.
    pub dst_res: u32,
    /// Bricks (the sparse volume's brick steps; 0 for a dense step).
    pub bricks: u32,
    /// Threads per dispatch row of a brick step (spread over y past 65 535 groups).
    pub row_threads: u32,
    /// Anisotropic steps: 1 when the finer level holds six faces (every level but level 0).
    pub src_faces: u32,
    /// Padding.
    pub pad1: u32,
}

/// One object-space triangle of the re-voxelization baseline. WGSL: `GiTri`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuGiTri {
    /// First vertex; w: linear albedo red.
    pub a: [f32; 4],
    /// Second vertex; w: green.
    pub b: [f32; 4],
    /// Third vertex; w: blue.
    pub c: [f32; 4],
    /// Emitted radiance (MTL `Ke`); w unused.
    pub emission: [f32; 4],
}

/// One drawn instance of the splat renderer and where its splats lie. WGSL: `SplatEntry`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuSplatEntry {
    /// Rows of the map object space → camera coordinates (right, up, forward), camera-relative.
    pub view_x: [f32; 4],
    /// Second row.
    pub view_y: [f32; 4],
    /// Third row (view depth).
    pub view_z: [f32; 4],
    /// Splat number of its first splat (numbers run over the drawn instances in order).
    pub first: u32,
    /// Its first splat in the centre and attribute pools.
    pub base: u32,
    /// Its splats.
    pub count: u32,
    /// The scene's instance.
    pub instance: u32,
    /// Half the square's side in pixels at view depth 1.
    pub half_px: f32,
    /// How far a voxel's nearest corner lies in front of its centre along the view axis.
    pub half_depth: f32,
    /// World voxel edge.
    pub voxel: f32,
    /// Padding.
    pub pad: u32,
}

/// The splat passes' uniforms. WGSL: `SplatFrame`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuSplatFrame {
    /// Drawn instances (rows of the entry buffer).
    pub entries: u32,
    /// Their splats.
    pub total: u32,
    /// Threads per dispatch row (splats spread over y past 65 535 groups).
    pub row_threads: u32,
    /// The near plane's view depth.
    pub near: f32,
    /// Image width in pixels (the frame's, here for the rasterizer's vertex stage, which
    /// cannot see the tracer's group 0).
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Tangent of half the vertical field of view (the frame's `forward.w`).
    pub tan_half: f32,
    /// Width over height (the frame's `right.w`).
    pub aspect: f32,
}

/// One car of a crowd posed on the GPU ([`crate::gpu::crowd`]). WGSL: `CrowdCar`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuCrowdCar {
    /// The figure-eight's centre, the larger f32 of each coordinate; w: the car's time
    /// offset within one lap (s).
    pub origin_hi: [f32; 4],
    /// What the first f32 left of each coordinate; w: the time offset within one door cycle.
    pub origin_lo: [f32; 4],
    /// The distance of the time offset's whole laps, wrapped to one wheel turn (m).
    pub spin: f32,
    /// 1: the body drives the figure-eight; 0: it stays at the centre.
    pub travel: u32,
    /// Padding.
    pub pad0: u32,
    /// Padding.
    pub pad1: u32,
    /// Instances of the body, the four wheels (front left, front right, rear left, rear right)...
    pub inst_a: [u32; 4],
    /// ...the two doors and the steering wheel.
    pub inst_b: [u32; 4],
    /// The parts of `inst_a`'s instances.
    pub part_a: [u32; 4],
    /// The parts of `inst_b`'s instances.
    pub part_b: [u32; 4],
}

/// One part as the crowd's posing reads it. WGSL: `CrowdPart`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuCrowdPart {
    /// Centre of the occupied box at the frame's level (object space); w: the cube's size.
    pub box_centre: [f32; 4],
    /// Half extents of that box; w: the farthest occupied cell's reach from its centre
    /// ([`crate::svo::Svo::occupied_reach`]).
    pub box_half: [f32; 4],
    /// The cube's minimum corner; w: unused.
    pub cube_min: [f32; 4],
}

/// The crowd's posing uniforms. WGSL: `CrowdFrame`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuCrowdFrame {
    /// The eye, the larger f32 of each coordinate; w: the time within one lap (s).
    pub eye_hi: [f32; 4],
    /// What the first f32 left of each coordinate; w: the time within one door cycle.
    pub eye_lo: [f32; 4],
    /// The distance of the time's whole laps, wrapped to one wheel turn (m).
    pub spin: f32,
    /// One lap's distance wrapped to one wheel turn (m).
    pub lap_spin: f32,
    /// Cars to pose.
    pub cars: u32,
    /// Padding.
    pub pad: u32,
}

/// One level of the instance BVH refitted on the GPU ([`crate::gpu::refit`]): its stretch of
/// the node order. WGSL: `RefitLevel`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuRefitLevel {
    /// First entry of the level in the node order.
    pub first: u32,
    /// Nodes in the level.
    pub count: u32,
    /// Padding.
    pub pad0: u32,
    /// Padding.
    pub pad1: u32,
}
