//! Bottom-up SVO construction from sparse voxels: levels are formed by grouping Morton codes,
//! attributes are averaged into every interior node, and the levels are laid out one after
//! the other, which is already the node order of [`Svo`].

use super::format::{Attr, Cube, Svo, MAX_DEPTH};
use crate::voxelize::VoxelGrid;
use glam::Vec3;

/// Why an SVO could not be built.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum BuildError {
    /// The voxel grid holds no voxel.
    #[error("the voxel grid is empty: nothing to build")]
    Empty,
    /// Depth outside 1..=MAX_DEPTH.
    #[error("depth {0} is outside the supported range 1..={MAX_DEPTH}")]
    Depth(u32),
    /// Codes are not strictly increasing or lie outside the grid.
    #[error("voxel {index} has Morton code {code:#x}, which is out of order or outside a 2^{depth} grid")]
    BadCode {
        /// Position in the voxel list.
        index: usize,
        /// The offending code.
        code: u64,
        /// Grid depth.
        depth: u32,
    },
    /// More nodes and voxels than 32-bit links can number.
    #[error("{0} nodes and voxels exceed the format's 2^32 − 1 limit; use a coarser voxel size")]
    TooLarge(u64),
    /// Bounds not finite or size not positive.
    #[error("invalid bounds: min {min:?}, size {size}")]
    Bounds {
        /// Cube minimum.
        min: Vec3,
        /// Cube size.
        size: f32,
    },
}

/// One node of one level while building.
#[derive(Clone, Copy)]
struct LevelNode {
    code: u64,
    valid: u8,
    first_child: u32,
    albedo_sum: Vec3,
    normal_sum: Vec3,
    emission_sum: Vec3,
    specular_sum: f32,
    gloss_sum: f32,
    weight: f32,
}

impl LevelNode {
    fn attr(&self) -> Attr {
        let w = self.weight.max(f32::MIN_POSITIVE);
        Attr::pack_glossy(
            self.albedo_sum / w,
            self.normal_sum,
            self.emission_sum / w,
            self.specular_sum / w,
            self.gloss_sum / w,
        )
    }
}

/// Builds the octree of a voxel grid. Voxels must be sorted by strictly increasing Morton
/// code, as [`crate::voxelize::voxelize`] returns them.
pub fn build(grid: &VoxelGrid) -> Result<Svo, BuildError> {
    let depth = grid.depth;
    if depth == 0 || depth > MAX_DEPTH {
        return Err(BuildError::Depth(depth));
    }
    if !(grid.bounds.min.is_finite() && grid.bounds.size.is_finite() && grid.bounds.size > 0.0) {
        return Err(BuildError::Bounds { min: grid.bounds.min, size: grid.bounds.size });
    }
    if grid.voxels.is_empty() {
        return Err(BuildError::Empty);
    }
    let limit = 1u64 << (3 * depth);
    let mut leaves = Vec::with_capacity(grid.voxels.len());
    let mut prev: Option<u64> = None;
    for (index, v) in grid.voxels.iter().enumerate() {
        if v.code >= limit || prev.is_some_and(|p| p >= v.code) {
            return Err(BuildError::BadCode { index, code: v.code, depth });
        }
        prev = Some(v.code);
        let w = if v.weight.is_finite() && v.weight > 0.0 { v.weight } else { f32::MIN_POSITIVE };
        let albedo = if v.albedo.is_finite() { v.albedo } else { Vec3::splat(0.5) };
        let normal = if v.normal.is_finite() { v.normal } else { Vec3::ZERO };
        let emission = if v.emission.is_finite() { v.emission.max(Vec3::ZERO) } else { Vec3::ZERO };
        let unit = |x: f32| if x.is_finite() { x.clamp(0.0, 1.0) } else { 0.0 };
        leaves.push(LevelNode {
            code: v.code,
            valid: 0,
            first_child: 0,
            albedo_sum: albedo * w,
            normal_sum: normal.normalize_or_zero() * w,
            emission_sum: emission * w,
            specular_sum: unit(v.specular) * w,
            gloss_sum: unit(v.gloss) * w,
            weight: w,
        });
    }

    // levels[l] holds the nodes of level l (0 = root, depth = leaves).
    let mut levels: Vec<Vec<LevelNode>> = vec![Vec::new(); depth as usize + 1];
    levels[depth as usize] = leaves;
    for l in (0..depth as usize).rev() {
        let children = &levels[l + 1];
        let mut parents: Vec<LevelNode> = Vec::with_capacity(children.len() / 3 + 1);
        for (i, c) in children.iter().enumerate() {
            let pc = c.code >> 3;
            let octant = (c.code & 7) as u8;
            match parents.last_mut() {
                Some(p) if p.code == pc => {
                    p.valid |= 1 << octant;
                    p.albedo_sum += c.albedo_sum;
                    p.normal_sum += c.normal_sum;
                    p.emission_sum += c.emission_sum;
                    p.specular_sum += c.specular_sum;
                    p.gloss_sum += c.gloss_sum;
                    p.weight += c.weight;
                }
                _ => parents.push(LevelNode {
                    code: pc,
                    valid: 1 << octant,
                    first_child: i as u32,
                    albedo_sum: c.albedo_sum,
                    normal_sum: c.normal_sum,
                    emission_sum: c.emission_sum,
                    specular_sum: c.specular_sum,
                    gloss_sum: c.gloss_sum,
                    weight: c.weight,
                }),
            }
        }
        // Opposite faces of a thin wall cancel in the normal sum; fall back to the heaviest
        // child's normal so coarse levels still shade sensibly.
        for p in parents.iter_mut() {
            if p.normal_sum.length_squared() < 1e-12 * p.weight * p.weight {
                let n = p.valid.count_ones() as usize;
                let kids = &children[p.first_child as usize..p.first_child as usize + n];
                if let Some(best) = kids.iter().max_by(|a, b| a.weight.total_cmp(&b.weight)) {
                    p.normal_sum = best.normal_sum;
                }
            }
        }
        levels[l] = parents;
    }
    debug_assert_eq!(levels[0].len(), 1);

    // Node numbers: level by level, each level in Morton order (as grouped above).
    let mut level_start = Vec::with_capacity(depth as usize + 1);
    let mut count = 0u64;
    for level in &levels[..depth as usize] {
        level_start.push(count as u32);
        count += level.len() as u64;
    }
    let total = count + levels[depth as usize].len() as u64;
    if total > u32::MAX as u64 {
        return Err(BuildError::TooLarge(total));
    }
    level_start.push(count as u32);
    let nodes = count as usize;
    let mut masks = Vec::with_capacity(nodes);
    let mut links = Vec::with_capacity(nodes);
    let mut attrs = Vec::with_capacity(total as usize);
    for (l, level) in levels.iter().enumerate() {
        // The children of level l are numbered from the start of level l + 1; voxels, the
        // children of the deepest level, from the end of the nodes in the attribute array.
        let next = if l + 1 < depth as usize { level_start[l + 1] } else { nodes as u32 };
        for node in level {
            if l < depth as usize {
                masks.push(node.valid);
                links.push(next + node.first_child);
            }
            attrs.push(node.attr());
        }
    }
    Ok(Svo {
        bounds: Cube { min: grid.bounds.min, size: grid.bounds.size },
        depth,
        masks,
        links,
        level_start,
        attrs,
        voxel_count: grid.voxels.len() as u64,
        emitters: grid.emitters.clone(),
        occupied: Default::default(),
    })
}
