// Structs shared between the CPU and the GPU. Each mirrors a #[repr(C)] bytemuck::Pod
// struct in src/ (named above it); tests/layout.rs checks that sizes and offsets agree.

// Mirrors voxray::svo::Attr: attributes of one node or voxel.
struct Attr {
    // R, G, B sRGB-encoded albedo; the top byte is zero.
    albedo: u32,
    // Octahedral unit normal, x in bits 0-11, y in bits 12-23 (12-bit signed, /2047), then
    // the specular reflectance (S/15)^2 in bits 24-27 and the glossiness G/15 in bits 28-31.
    normal: u32,
    // Emitted radiance, RGB9E5 (svo::format::encode_rgb9e5).
    emission: u32,
}

// Mirrors voxray::gpu::layout::GpuPart: where one part's SVO lives in the pools.
// Its words in the node pool (voxray::gpu::layout::part_words): the links of its nodes from
// node_base, their 8-bit child masks four to a word from mask_base.
struct Part {
    node_base: u32,
    mask_base: u32,
    attr_base: u32,
    depth: u32,
}

// Mirrors voxray::gpu::layout::GpuInstance: one instance for this frame, camera-relative.
struct Inst {
    // Rows of the map camera-relative world -> unit cube: unit_i = dot(row.xyz, p) + row.w.
    to_unit_x: vec4<f32>,
    to_unit_y: vec4<f32>,
    to_unit_z: vec4<f32>,
    // Rows of the inverse transpose (object normals -> world normals).
    normal_x: vec4<f32>,
    normal_y: vec4<f32>,
    normal_z: vec4<f32>,
    // Bounding sphere: camera-relative centre and radius.
    sphere: vec4<f32>,
    part: u32,
    // Largest stretch of the world transform times the cube size (object -> world voxel size).
    stretch_size: f32,
    // 1 when the instance moved since the frame in the hit buffer.
    moved: u32,
    // The sphere's radius before it was grown for the f32 test (the BVH's boxes fit it).
    radius: f32,
}

// Mirrors voxray::gpu::layout::GpuFrame: per-frame uniforms.
struct Frame {
    // Camera basis; forward.w = tan(vfov/2), right.w = width / height.
    forward: vec4<f32>,
    right: vec4<f32>,
    up: vec4<f32>,
    // Direction towards the sun (w = 1 with a sun), its irradiance, the sky radiance
    // (w = 1 when MTL emitters are on).
    sun_dir: vec4<f32>,
    sun_irradiance: vec4<f32>,
    sky: vec4<f32>,
    width: u32,
    height: u32,
    instances: u32,
    max_level: u32,
    moved: u32,
    bvh_nodes: u32,
    // 1: the passes add up the frame's statistics in `stats`.
    count: u32,
    // Tiles to a row of `moved_bins` (0: no bins).
    moved_tiles_x: u32,
    // Rows of `emitters`, and light samples per shaded point on them.
    emitters: u32,
    emitter_samples: u32,
    // Rows of `lights` (suns, points and spots besides the sun).
    lights: u32,
    // 1: kept hits keep their colours where their shadow rays meet no moved sphere.
    keep_colours: u32,
    // Nodes of `moved_bvh` (0: none).
    moved_bvh_nodes: u32,
    pad4a: u32,
    pad4b: u32,
    pad4c: u32,
}

// Mirrors voxray::gpu::layout::GpuLight: a sun (a.w = 0), point (1) or spot (2).
struct Light {
    // Direction towards a sun, or a camera-relative position.
    a: vec4<f32>,
    // Irradiance or intensity; w: cosine of a spot's inner angle.
    b: vec4<f32>,
    // A spot's direction; w: cosine of its outer angle.
    c: vec4<f32>,
}

// Mirrors voxray::gpu::layout::GpuEmitter: one emissive triangle, camera-relative.
struct Emitter {
    // First corner; w: how far short of a sample shadow rays end.
    a: vec4<f32>,
    // Edges from the first corner; e1.w: area, e2.w: cumulative power fraction.
    e1: vec4<f32>,
    e2: vec4<f32>,
    // Unit normal of the lit side; w: probability of picking this row.
    normal: vec4<f32>,
    emission: vec4<f32>,
}

// Mirrors voxray::gpu::layout::GpuBvhNode: lo.w / hi.w hold first / count as bits.
struct BvhNode {
    lo: vec4<f32>,
    hi: vec4<f32>,
}

// Mirrors voxray::gpu::layout::GpuHit: one pixel's primary hit (the hit buffer).
struct Hit {
    t: f32,
    instance: i32,
    albedo: u32,
    voxel: f32,
    nx: f32,
    ny: f32,
    nz: f32,
    fx: f32,
    fy: f32,
    fz: f32,
    // Instances traversed (low 16 bits) and sphere-culled (high 16 bits) finding this hit.
    work: u32,
    // How this frame found the record (low two bits): 0 searched among all instances, 1 kept
    // (no ray), 2 searched among the moved instances only (HitBuffer's Todo); 4: the record
    // is last frame's; 8: so is its colour (trace.wgsl's RECORD_KEPT, COLOUR_KEPT).
    reused: u32,
    // Normal word of the voxel's attributes (Attr::normal: the top byte is the specular lobe).
    material: u32,
    // Emission word of the voxel's attributes (Attr::emission, RGB9E5).
    emission: u32,
}

// Mirrors voxray::gpu::layout::GpuSphere: a moved instance's old or new sphere and the
// pixel rectangle outside which it cannot meet a ray.
struct MovedSphere {
    sphere: vec4<f32>,
    rect: vec4<u32>,
    // The moved instance (spheres come in pairs, old then new, in ascending instance order).
    instance: u32,
}

// Mirrors voxray::gpu::layout::GpuRay: one ray of a ray list, in a part's unit cube.
struct RayIn {
    origin: vec4<f32>,
    dir: vec4<f32>,
    t_min: f32,
    t_max: f32,
    max_level: u32,
    pad: u32,
}

// Mirrors voxray::gpu::layout::GpuRayHit: what a ray-list trace returns.
struct RayOut {
    t: f32,
    level: u32,
    hit: u32,
    steps: u32,
    coord: vec4<u32>,
}

// Mirrors voxray::gpu::layout::GpuCastHit: what a caller's ray found (gpu::cast).
struct CastOut {
    // The instance hit (0xFFFFFFFF: none); for occlusion, 0 when blocked.
    instance: u32,
    t: f32,
    level: u32,
    pad: u32,
    coord: vec4<u32>,
    // The voxel's Attr words: albedo, normal, emission (w unused).
    attr: vec4<u32>,
    face_normal: vec4<f32>,
}

// Mirrors voxray::gi::CacheVoxel: one voxel of a part's GI cache.
struct CacheVoxel {
    // x | y << 10 | z << 20, relative to the cache's corner.
    coord: u32,
    albedo: u32,
    normal: u32,
    emission: u32,
}

// Mirrors voxray::gpu::layout::GpuGiJob: one instance's cache moved into the GI volume.
struct GiJob {
    // Rows of integer cache coordinate -> volume grid coordinate (cell c's centre at c).
    grid_x: vec4<f32>,
    grid_y: vec4<f32>,
    grid_z: vec4<f32>,
    // Rows of the inverse transpose (object normals -> world normals).
    normal_x: vec4<f32>,
    normal_y: vec4<f32>,
    normal_z: vec4<f32>,
    voxel_base: u32,
    voxel_count: u32,
    first_thread: u32,
    pad: u32,
}

// Mirrors voxray::gpu::layout::GpuGiSplat: uniforms of the voxel transformation.
struct GiSplat {
    res: u32,
    jobs: u32,
    threads: u32,
    row_threads: u32,
    nearest: u32,
    // Sparse volume: 1 in the pass that marks bricks, 0 in the one that accumulates.
    mark: u32,
    pad1: u32,
    pad2: u32,
}

// Mirrors voxray::gpu::layout::GpuGiFrame: the GI volume's placement and the cone knobs.
struct GiFrame {
    // xyz: volume corner minus the camera eye; w: finest cell edge.
    min_cell: vec4<f32>,
    // First element of each level (0-3, 4-7, 8-11) in the level buffer, and its cells per side.
    offsets_a: vec4<u32>,
    offsets_b: vec4<u32>,
    offsets_c: vec4<u32>,
    res_a: vec4<u32>,
    res_b: vec4<u32>,
    res_c: vec4<u32>,
    res: u32,
    levels: u32,
    cones: u32,
    bounces: u32,
    // 2 tan(aperture / 2).
    spread: f32,
    // Angle of the cone ring from the normal.
    tilt: f32,
    max_distance: f32,
    // Stored finest cells (res³ dense; the pool's bricks x 512 sparse), the cell passes'
    // threads.
    cells: u32,
    // Threads per dispatch row of the cell passes (spread over y past 65 535 groups).
    row_threads: u32,
    // Sparse: top-table cells per side (res / 8).
    top_res: u32,
    // Texture levels: the texture's cells per side (res rounded up to a power of two).
    tex_size: u32,
    // 1: glossy hits trace the specular cone; 0: their specular ambient is the flat sky's.
    specular_cone: u32,
    // Sparse: bricks allocated (copied in by the GPU); threads past bricks x 512 stop.
    bricks: u32,
    // 1: the diffuse cones are gathered at half resolution (render::Gather::Half).
    half: u32,
    // Samples per row of the half-resolution gather (the width halved, rounded up).
    half_width: u32,
    // 1: the diffuse light comes from radiance caches (render::Gather::Caches), with their
    // knobs (radiance_cache::CacheSettings; placement 0 clustered, 1 even).
    caches: u32,
    cache_tile: u32,
    cache_res: u32,
    cache_radius: u32,
    cache_per_tile: u32,
    // Tiles per row, slots (tiles x per_tile) and vec4 per slot in the map buffer.
    cache_tiles_x: u32,
    cache_slots: u32,
    cache_stride: u32,
    cache_placement: u32,
    // 2 tan(aperture / 2) of a texel's cone.
    cache_spread: f32,
    // Threads per dispatch row of the cache tracing and convolution passes.
    cache_row_threads: u32,
    cell_samples: u32,
    // GiSettings::bounce_tail past one bounce: the bounce pass sums its workgroups' light.
    tail: u32,
}

// Mirrors voxray::gpu::layout::GpuGiLevelStep: one step down the level chain.
struct GiLevelStep {
    src_offset: u32,
    src_res: u32,
    dst_offset: u32,
    dst_res: u32,
    // Brick steps: bricks, and threads per dispatch row.
    bricks: u32,
    row_threads: u32,
    // Anisotropic steps: whether the finer level holds six faces.
    src_faces: u32,
    pad1: u32,
}

// Mirrors voxray::gpu::layout::GpuGiTri: one object-space triangle for the re-voxelization
// baseline; the w components of a, b, c hold its linear albedo.
struct GiTri {
    a: vec4<f32>,
    b: vec4<f32>,
    c: vec4<f32>,
    emission: vec4<f32>,
}

// Mirrors voxray::gpu::layout::GpuSplatEntry: one drawn instance of the splat renderer
// (render::splat::InstanceView) and where its splats lie.
struct SplatEntry {
    // Rows of the map object space -> camera coordinates (right, up, forward), camera-relative.
    view_x: vec4<f32>,
    view_y: vec4<f32>,
    view_z: vec4<f32>,
    // Splat number of its first splat (numbers run over the drawn instances in order).
    first: u32,
    // Its first splat in the centre and attribute pools.
    base: u32,
    count: u32,
    instance: u32,
    // Half the square's side in pixels at view depth 1 (factor · world voxel edge · focal / 2).
    half_px: f32,
    // How far a voxel's nearest corner lies in front of its centre along the view axis.
    half_depth: f32,
    // World voxel edge.
    voxel: f32,
    pad: u32,
}

// Mirrors voxray::gpu::layout::GpuSplatFrame: the splat passes' uniforms.
struct SplatFrame {
    // Drawn instances (rows of splat_entries) and their splats.
    entries: u32,
    total: u32,
    // Threads per dispatch row (splats spread over y past 65 535 groups).
    row_threads: u32,
    // The near plane's view depth.
    near: f32,
    // The frame's width, height, forward.w and right.w (the rasterizer's vertex stage
    // cannot see group 0).
    width: u32,
    height: u32,
    tan_half: f32,
    aspect: f32,
}

// Mirrors voxray::gpu::layout::GpuCrowdCar: one car of a crowd posed on the GPU.
struct CrowdCar {
    // The figure-eight's centre as two f32 (hi + lo); hi.w: the time offset within a lap,
    // lo.w: within a door cycle.
    origin_hi: vec4<f32>,
    origin_lo: vec4<f32>,
    // The offset's whole laps of distance, wrapped to a wheel turn.
    spin: f32,
    // 1: the body drives the figure-eight.
    travel: u32,
    pad0: u32,
    pad1: u32,
    // Instances: body, four wheels | two doors, steering wheel; then their parts.
    inst_a: vec4<u32>,
    inst_b: vec4<u32>,
    part_a: vec4<u32>,
    part_b: vec4<u32>,
}

// Mirrors voxray::gpu::layout::GpuCrowdPart: a part's occupied box and cube.
struct CrowdPart {
    // Occupied box centre at the frame's level; w: cube size.
    box_centre: vec4<f32>,
    // Half extents; w: the farthest occupied cell's reach from the centre.
    box_half: vec4<f32>,
    cube_min: vec4<f32>,
}

// Mirrors voxray::gpu::layout::GpuCrowdFrame: the crowd's posing uniforms.
struct CrowdFrame {
    // The eye as two f32 (hi + lo); hi.w: the time within a lap, lo.w: within a door cycle.
    eye_hi: vec4<f32>,
    eye_lo: vec4<f32>,
    // The time's whole laps of distance and one lap's, wrapped to a wheel turn.
    spin: f32,
    lap_spin: f32,
    cars: u32,
    pad: u32,
}

// Mirrors voxray::gpu::layout::GpuRefitLevel: one level of the BVH refitted on the GPU, a
// stretch of `refit_order` (wgsl/refit.wgsl).
struct RefitLevel {
    first: u32,
    count: u32,
    pad0: u32,
    pad1: u32,
}
