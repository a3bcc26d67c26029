//! Bottom-up SVO construction from sparse voxels: levels are formed by grouping Morton codes,
//! attributes are averaged into every interior node, and the node array is laid out depth first
//! with far pointers where a child group lies beyond the 15-bit pointer range.

use super::format::{Attr, Cube, Node, Svo, MAX_DEPTH, MAX_NEAR_POINTER};
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

    let layout = Layout::plan(&levels, depth);
    let mut out = Emitter {
        levels: &levels,
        layout: &layout,
        depth,
        nodes: vec![Node::default()],
        attrs: vec![levels[0][0].attr()],
    };
    out.emit(0, 0, 0, None);
    Ok(Svo {
        bounds: Cube { min: grid.bounds.min, size: grid.bounds.size },
        depth,
        nodes: out.nodes,
        attrs: out.attrs,
        voxel_count: grid.voxels.len() as u64,
    })
}

/// Sizes of every subtree and which child pointers need far slots, computed bottom-up so
/// that the depth-first emission can reserve far slots next to each child group.
struct Layout {
    /// Per level and node: slots taken by all descendants' descriptors and far slots.
    subtree: Vec<Vec<u64>>,
    /// Per level and node: bit k set when inner child k needs a far pointer.
    far_flags: Vec<Vec<u8>>,
    /// Per level and node: number of far slots after its child group.
    far_count: Vec<Vec<u8>>,
}

impl Layout {
    fn plan(levels: &[Vec<LevelNode>], depth: u32) -> Self {
        let d = depth as usize;
        let mut subtree = vec![Vec::new(); d];
        let mut far_flags = vec![Vec::new(); d];
        let mut far_count = vec![Vec::new(); d];
        for l in (0..d).rev() {
            let n = levels[l].len();
            subtree[l] = vec![0u64; n];
            far_flags[l] = vec![0u8; n];
            far_count[l] = vec![0u8; n];
            if l + 1 == d {
                continue; // children are leaves: no group of descriptors
            }
            for (i, node) in levels[l].iter().enumerate() {
                let m = node.valid.count_ones() as usize;
                let first = node.first_child as usize;
                let kids = &subtree[l + 1][first..first + m];
                let (flags, f) = far_pointers(kids);
                far_flags[l][i] = flags;
                far_count[l][i] = f as u8;
                subtree[l][i] = m as u64 + f as u64 + kids.iter().sum::<u64>();
            }
        }
        Layout { subtree, far_flags, far_count }
    }
}

/// Given the subtree sizes of a group's children (laid out as: the group, then its far
/// slots, then each child's subtree in order), decides which children need a far pointer.
/// Iterates to the fixed point because far slots push the subtrees further away.
fn far_pointers(kid_subtrees: &[u64]) -> (u8, u32) {
    let m = kid_subtrees.len() as u64;
    let mut f = 0u64;
    loop {
        let (mut flags, mut count, mut acc) = (0u8, 0u64, 0u64);
        for (k, &g) in kid_subtrees.iter().enumerate() {
            let offset = (m - k as u64) + f + acc;
            if g > 0 && offset > MAX_NEAR_POINTER as u64 {
                flags |= 1 << k;
                count += 1;
            }
            acc += g;
        }
        if count == f {
            return (flags, f as u32);
        }
        f = count;
    }
}

struct Emitter<'a> {
    levels: &'a [Vec<LevelNode>],
    layout: &'a Layout,
    depth: u32,
    nodes: Vec<Node>,
    attrs: Vec<Attr>,
}

impl Emitter<'_> {
    /// Writes the descriptor of node (`level`, `idx`) into `slot` and emits its subtree.
    /// `far_slot` is the far-pointer slot its parent reserved for it, if any.
    fn emit(&mut self, level: usize, idx: usize, slot: usize, far_slot: Option<usize>) {
        let node = self.levels[level][idx];
        let m = node.valid.count_ones() as usize;
        let first = node.first_child as usize;
        let attr_base = self.attrs.len() as u32;
        for c in &self.levels[level + 1][first..first + m] {
            self.attrs.push(c.attr());
        }
        if level + 1 == self.depth as usize {
            self.nodes[slot] = Node::new(0, false, node.valid, node.valid, attr_base);
            return;
        }
        let group = self.nodes.len();
        let f = self.layout.far_count[level][idx] as usize;
        self.nodes.resize(group + m + f, Node::default());
        self.nodes[slot] = match far_slot {
            Some(fs) => {
                self.nodes[fs].desc = (group - fs) as u32;
                Node::new((fs - slot) as u32, true, node.valid, 0, attr_base)
            }
            None => {
                assert!(group - slot <= MAX_NEAR_POINTER as usize, "layout plan violated");
                Node::new((group - slot) as u32, false, node.valid, 0, attr_base)
            }
        };
        let flags = self.layout.far_flags[level][idx];
        let mut next_far = group + m;
        for k in 0..m {
            let fs = if flags & (1 << k) != 0 {
                next_far += 1;
                Some(next_far - 1)
            } else {
                None
            };
            self.emit(level + 1, first + k, group + k, fs);
        }
        debug_assert_eq!(self.nodes.len() as u64, group as u64 + self.layout.subtree[level][idx], "subtree size plan");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn far_pointer_fixed_point() {
        assert_eq!(far_pointers(&[1, 2, 3]), (0, 0));
        // The second child's group lies behind a 40 000-slot sibling subtree.
        let (flags, f) = far_pointers(&[40_000, 5, 0]);
        assert_eq!((flags, f), (0b10, 1));
        let (flags, f) = far_pointers(&[40_000, 40_000, 5]);
        assert_eq!((flags, f), (0b110, 2));
    }
}
