//! A few boxes covering an octree's occupied cells more tightly than their one bounding box
//! ([`Svo::occupied_box`]): a crowd tests its cars' parts against a frame's rays
//! (`scene::car::car_part_boxes`), and a car body's box is half empty around its cabin.

use super::Svo;
use glam::DVec3;

/// Boxes in object space, at most `count` (at least one), that together hold every cell
/// occupied at `level` (capped at the depth) — so every finer occupied cell too, as a node
/// holds geometry. Found by splitting the occupied box in two along the cell boundary that
/// most shrinks the summed volume of the two halves' tight boxes, then the box whose split
/// gains the most, and so on, while a split gains at least a twentieth of its box's volume.
/// (Volume, not surface area as a BVH's heuristic: a car body's shell split at its waist
/// gains a fifth of its volume, while the two new faces make the areas' sum grow.) An empty
/// octree gives its [`Svo::occupied_box`].
pub fn covering_boxes(svo: &Svo, level: u32, count: usize) -> Vec<(DVec3, DVec3)> {
    let level = level.min(svo.depth);
    // (`at_level` reads the root's mask and attributes, which an empty octree lacks.)
    if svo.voxel_count == 0 || svo.masks.is_empty() || svo.attrs.is_empty() {
        return vec![svo.occupied_box(level)];
    }
    let cell = svo.bounds.size as f64 / (1u64 << level) as f64;
    let min = svo.bounds.min.as_dvec3();
    let cells: Vec<[u32; 3]> = svo.at_level(level).into_iter().map(|(c, _)| c).collect();
    if cells.is_empty() {
        return vec![svo.occupied_box(level)];
    }
    let mut groups = vec![cells];
    while groups.len() < count.max(1) {
        // The group whose best split gains the most.
        let best = groups
            .iter()
            .enumerate()
            .filter_map(|(g, cells)| best_split(cells).map(|s| (g, s)))
            .max_by(|a, b| a.1 .0.total_cmp(&b.1 .0));
        let Some((g, (gain, axis, at))) = best else { break };
        if gain < volume(&bounds(&groups[g])) / 20.0 {
            break;
        }
        let (left, right): (Vec<_>, Vec<_>) = groups.swap_remove(g).into_iter().partition(|c| c[axis] < at);
        groups.push(left);
        groups.push(right);
    }
    groups
        .iter()
        .map(|cells| {
            let [lo, hi] = bounds(cells);
            let at = |c: [u32; 3]| min + DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * cell;
            (at(lo), at(hi))
        })
        .collect()
}

/// The smallest box of cells `[lo, hi)` holding `cells` (not empty).
fn bounds(cells: &[[u32; 3]]) -> [[u32; 3]; 2] {
    cells.iter().fold([[u32::MAX; 3], [0; 3]], |[lo, hi], c| {
        [[0, 1, 2].map(|i| lo[i].min(c[i])), [0, 1, 2].map(|i| hi[i].max(c[i] + 1))]
    })
}

/// Volume of a box of cells (in cells³).
fn volume([lo, hi]: &[[u32; 3]; 2]) -> f64 {
    (0..3).map(|i| (hi[i] - lo[i]) as f64).product()
}

/// The split of `cells` into those below and those at or above a cell boundary on an axis
/// that most shrinks the summed volumes of the two parts' boxes: (volume gained, axis,
/// boundary). None when no boundary leaves cells on both sides.
fn best_split(cells: &[[u32; 3]]) -> Option<(f64, usize, u32)> {
    let whole = volume(&bounds(cells));
    let mut best: Option<(f64, usize, u32)> = None;
    for axis in 0..3 {
        let mut sorted = cells.to_vec();
        sorted.sort_unstable_by_key(|c| c[axis]);
        // Boxes of every prefix and suffix, then each boundary between distinct coordinates.
        let grow = |b: [[u32; 3]; 2], c: &[u32; 3]| -> [[u32; 3]; 2] {
            [[0, 1, 2].map(|i| b[0][i].min(c[i])), [0, 1, 2].map(|i| b[1][i].max(c[i] + 1))]
        };
        let empty = [[u32::MAX; 3], [0; 3]];
        let mut suffix = vec![empty; sorted.len() + 1];
        for k in (0..sorted.len()).rev() {
            suffix[k] = grow(suffix[k + 1], &sorted[k]);
        }
        let mut prefix = empty;
        for k in 1..sorted.len() {
            prefix = grow(prefix, &sorted[k - 1]);
            if sorted[k][axis] == sorted[k - 1][axis] {
                continue;
            }
            let gain = whole - volume(&prefix) - volume(&suffix[k]);
            if best.is_none_or(|b| gain > b.0) {
                best = Some((gain, axis, sorted[k][axis]));
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::svo::Cube;
    use glam::Vec3;

    /// An octree of the given voxels at `depth` in a cube at (−1, 2, 0.5) of edge 4.
    fn octree(depth: u32, coords: &[[u32; 3]]) -> Svo {
        let cube = Cube { min: Vec3::new(-1.0, 2.0, 0.5), size: 4.0 };
        let grid = crate::voxelize::VoxelGrid::from_coords(depth, cube, coords.iter().copied(), Vec3::ONE);
        crate::svo::build(&grid).unwrap()
    }

    /// Every voxel's cube lies in one of the boxes, at every level asked for; an L of two
    /// bars is covered by two tight boxes (a tenth of its bounding box's volume); no more
    /// boxes than asked for; one box is the occupied box.
    #[test]
    fn the_boxes_hold_every_voxel_and_fit_an_l() {
        let depth = 6;
        // Two bars: one along x at the bottom, one up y at x = 40..44.
        let mut coords = Vec::new();
        for x in 0..44 {
            for z in 10..14 {
                coords.push([x, 3, z]);
                coords.push([x, 4, z]);
            }
        }
        for y in 5..60 {
            for x in 40..44 {
                coords.push([x, y, 11]);
            }
        }
        let mut rng = crate::rng::Rng::new(3);
        let scattered: Vec<[u32; 3]> = (0..300).map(|_| [0; 3].map(|_| rng.below(64) as u32)).collect();
        for (name, coords) in [("L", coords), ("scattered", scattered)] {
            let svo = octree(depth, &coords);
            let voxel = svo.bounds.size as f64 / 64.0;
            let min = svo.bounds.min.as_dvec3();
            for (level, count) in [(6, 1), (6, 2), (6, 4), (4, 3), (2, 8), (9, 3)] {
                let boxes = covering_boxes(&svo, level, count);
                assert!(!boxes.is_empty() && boxes.len() <= count, "{name} level {level}: {} boxes", boxes.len());
                for c in &coords {
                    let lo = min + DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) * voxel;
                    let hi = lo + DVec3::splat(voxel);
                    assert!(
                        boxes.iter().any(|(a, b)| a.cmple(lo).all() && hi.cmple(*b).all()),
                        "{name} level {level}, {count} boxes: voxel {c:?} in none of {boxes:?}"
                    );
                }
                if count == 1 {
                    assert_eq!(boxes, vec![svo.occupied_box(level)], "{name} level {level}");
                }
            }
            if name == "L" {
                // An octree without voxels (as a file could hold): its one occupied box.
                let empty =
                    Svo { masks: Vec::new(), links: Vec::new(), attrs: Vec::new(), voxel_count: 0, ..svo.clone() };
                assert_eq!(covering_boxes(&empty, depth, 3), vec![empty.occupied_box(depth)]);
                let boxes = covering_boxes(&svo, depth, 2);
                let sum: f64 = boxes.iter().map(|(a, b)| (*b - *a).element_product()).sum();
                let (a, b) = svo.occupied_box(depth);
                assert!(
                    sum < 0.1 * (b - a).element_product(),
                    "L: {boxes:?} hold {sum} of {}",
                    (b - a).element_product()
                );
            }
        }
    }
}
