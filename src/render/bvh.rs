//! A bounding volume hierarchy over instance bounding spheres (their boxes), built in
//! O(n log n) by median splits, so rays skip whole groups of instances and the cost per ray
//! grows with log n rather than n. Frame to frame it is refitted in O(n) (same tree, boxes
//! recomputed bottom-up) and built again only when refitting has made it
//! [`REBUILD_RATIO`] times costlier than when it was built.

use glam::DVec3;

/// A BVH node: a box and either two children or a range of instance indices.
#[derive(Clone, Copy, Debug)]
pub struct Node {
    /// Box minimum.
    pub lo: DVec3,
    /// Box maximum.
    pub hi: DVec3,
    /// Leaf: first index into [`Bvh::items`]; inner: index of the left child (right = +1).
    pub first: u32,
    /// Leaf: item count (> 0); inner: 0.
    pub count: u32,
}

/// The hierarchy.
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    /// Nodes; node 0 is the root, and every node's children come after it.
    pub nodes: Vec<Node>,
    /// Instance indices, grouped by leaf.
    pub items: Vec<u32>,
    /// [`Bvh::cost`] when the tree was built.
    pub built_cost: f64,
    /// Frames this tree has been refitted for since it was built.
    pub refits: u32,
    /// The same tree four children to a node with f32 boxes, for the searches' walks
    /// (collapsed again whenever the boxes change).
    pub wide: super::bvh_wide::WideBvh,
}

/// Build again once a refitted tree costs this many times what it cost when built.
pub const REBUILD_RATIO: f64 = 1.5;

impl Bvh {
    /// The BVH over prepared instances when there are enough of them to pay for it (the
    /// frame plan's own threshold), for passes that trace outside the plan (GI injection, the
    /// path-traced reference), with the search to use.
    pub fn when_worthwhile(prepared: &[super::instances::Prepared]) -> (Option<Bvh>, super::visibility::Search) {
        if prepared.len() >= super::plan::BVH_MIN_INSTANCES {
            let spheres: Vec<_> = prepared.iter().map(|p| (p.centre, p.radius)).collect();
            (Some(Bvh::build(&spheres)), super::visibility::Search::Bvh)
        } else {
            (None, super::visibility::Search::CullSort)
        }
    }
}

impl Bvh {
    /// Whether `item(i)` holds for some item of a leaf that `node(lo, hi)` lets through,
    /// with every box above it (a box it rules out must hold no item for which `item` could
    /// hold). None once more than `budget` boxes were let through, or when the walk outgrows
    /// its stack: the caller then answers without the tree.
    pub fn any_item(
        &self,
        budget: usize,
        node: impl Fn(DVec3, DVec3) -> bool,
        item: impl Fn(u32) -> bool,
    ) -> Option<bool> {
        let mut stack = [0u32; 64];
        let (mut len, mut passed) = (usize::from(!self.nodes.is_empty()), 0usize);
        while len > 0 {
            len -= 1;
            let n = &self.nodes[stack[len] as usize];
            if !node(n.lo, n.hi) {
                continue;
            }
            passed += 1;
            if passed > budget {
                return None;
            }
            if n.count > 0 {
                if self.items.get(n.first as usize..(n.first + n.count) as usize)?.iter().any(|&i| item(i)) {
                    return Some(true);
                }
                continue;
            }
            if len + 2 > stack.len() {
                return None;
            }
            stack[len] = n.first;
            stack[len + 1] = n.first + 1;
            len += 2;
        }
        Some(false)
    }
}

/// Instances per leaf at most.
const LEAF: usize = 4;

/// Surface area of a box (0 for an empty or inverted one).
fn area(lo: DVec3, hi: DVec3) -> f64 {
    let e = (hi - lo).max(DVec3::ZERO);
    2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
}

impl Bvh {
    /// The surface-area cost of the tree: the sum of its nodes' box areas over the root's,
    /// which is how many nodes a ray crossing the root box visits on average (the surface
    /// area heuristic without the leaf term). A tree whose boxes have grown apart costs more.
    pub fn cost(&self) -> f64 {
        let Some(root) = self.nodes.first() else { return 0.0 };
        let total: f64 = self.nodes.iter().map(|n| area(n.lo, n.hi)).sum();
        total / area(root.lo, root.hi).max(f64::MIN_POSITIVE)
    }

    /// Recomputes every box from `spheres` (same tree), children before parents.
    ///
    /// The leaves first, in parallel for large trees (each reads its own spheres, which is
    /// most of the work: the spheres are in instance order, not the tree's), then the inner
    /// nodes bottom-up from their children. Every box is the same min and max over the same
    /// values as node by node.
    pub fn refit(&mut self, spheres: &[(DVec3, f64)]) {
        let items = &self.items;
        let leaf = |node: &mut Node| {
            if node.count > 0 {
                let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
                for &i in &items[node.first as usize..(node.first + node.count) as usize] {
                    let (c, r) = spheres[i as usize];
                    lo = lo.min(c - r);
                    hi = hi.max(c + r);
                }
                (node.lo, node.hi) = (lo, hi);
            }
        };
        #[cfg(feature = "parallel")]
        let done = if self.nodes.len() >= super::bvh_wide::PARALLEL_NODES {
            use rayon::prelude::*;
            self.nodes.par_iter_mut().with_min_len(1024).for_each(leaf);
            true
        } else {
            false
        };
        #[cfg(not(feature = "parallel"))]
        let done = false;
        if !done {
            self.nodes.iter_mut().for_each(leaf);
        }
        for n in (0..self.nodes.len()).rev() {
            let node = self.nodes[n];
            if node.count == 0 {
                // From ±∞ as a leaf starts, so that even a NaN box folds in as it always did.
                let (a, b) = (self.nodes[node.first as usize], self.nodes[node.first as usize + 1]);
                self.nodes[n].lo = DVec3::INFINITY.min(a.lo).min(b.lo);
                self.nodes[n].hi = DVec3::NEG_INFINITY.max(a.hi).max(b.hi);
            }
        }
        self.refits += 1;
        self.wide.refit(&self.nodes);
    }

    /// `previous` refitted to `spheres` when it covers as many and stays within
    /// [`REBUILD_RATIO`] of its cost when built; otherwise a new tree.
    pub fn refit_or_build(previous: Option<Bvh>, spheres: &[(DVec3, f64)]) -> Bvh {
        if let Some(mut bvh) = previous.filter(|b| b.items.len() == spheres.len() && !b.nodes.is_empty()) {
            bvh.refit(spheres);
            if bvh.cost() <= REBUILD_RATIO * bvh.built_cost {
                return bvh;
            }
        }
        Bvh::build(spheres)
    }
    /// Builds over spheres (centre, radius).
    pub fn build(spheres: &[(DVec3, f64)]) -> Bvh {
        let mut bvh = Bvh {
            nodes: Vec::with_capacity(2 * spheres.len() / LEAF + 1),
            items: (0..spheres.len() as u32).collect(),
            ..Bvh::default()
        };
        if spheres.is_empty() {
            return bvh;
        }
        bvh.nodes.push(Node { lo: DVec3::ZERO, hi: DVec3::ZERO, first: 0, count: 0 });
        // (node, start, end) ranges still to split.
        let mut stack = vec![(0usize, 0usize, spheres.len())];
        while let Some((n, start, end)) = stack.pop() {
            let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
            let (mut clo, mut chi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
            for &i in &bvh.items[start..end] {
                let (c, r) = spheres[i as usize];
                lo = lo.min(c - r);
                hi = hi.max(c + r);
                clo = clo.min(c);
                chi = chi.max(c);
            }
            bvh.nodes[n].lo = lo;
            bvh.nodes[n].hi = hi;
            if end - start <= LEAF {
                bvh.nodes[n].first = start as u32;
                bvh.nodes[n].count = (end - start) as u32;
                continue;
            }
            // Median split on the axis where the centres spread most.
            let ext = chi - clo;
            let axis = if ext.x >= ext.y && ext.x >= ext.z {
                0
            } else if ext.y >= ext.z {
                1
            } else {
                2
            };
            let mid = (start + end) / 2;
            bvh.items[start..end].select_nth_unstable_by(mid - start, |a, b| {
                spheres[*a as usize].0[axis].total_cmp(&spheres[*b as usize].0[axis])
            });
            let left = bvh.nodes.len();
            bvh.nodes.push(Node { lo: DVec3::ZERO, hi: DVec3::ZERO, first: 0, count: 0 });
            bvh.nodes.push(Node { lo: DVec3::ZERO, hi: DVec3::ZERO, first: 0, count: 0 });
            bvh.nodes[n].first = left as u32;
            bvh.nodes[n].count = 0;
            stack.push((left, start, mid));
            stack.push((left + 1, mid, end));
        }
        bvh.built_cost = bvh.cost();
        bvh.wide = super::bvh_wide::WideBvh::collapse(&bvh);
        bvh
    }
}

/// Entry t of a ray into a box (`None` if it misses or the box is behind), with the ray's
/// precomputed reciprocal direction; zero components test the slab by position.
#[inline]
pub fn box_entry(lo: DVec3, hi: DVec3, o: DVec3, inv_d: DVec3, t_max: f64) -> Option<f64> {
    let (mut t0, mut t1) = (0.0f64, t_max);
    for i in 0..3 {
        if inv_d[i].is_infinite() {
            if o[i] < lo[i] || o[i] > hi[i] {
                return None;
            }
        } else {
            let (a, b) = ((lo[i] - o[i]) * inv_d[i], (hi[i] - o[i]) * inv_d[i]);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
    }
    (t0 <= t1).then_some(t0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Clusters of four spheres along x. `mix` deals the clusters' members out so that
    /// every cluster of the new layout holds one member of four old ones.
    fn clusters(n: usize, mix: bool) -> Vec<(DVec3, f64)> {
        (0..n)
            .map(|i| {
                let cluster = if mix { (i % 4) * (n / 16) + i / 16 } else { i / 4 };
                (DVec3::new(cluster as f64 * 10.0 + (i % 4) as f64 * 0.1, 0.0, 0.0), 0.5)
            })
            .collect()
    }

    /// Refitting leaves first (in parallel for a tree this large) and inner nodes after gives
    /// every box bit for bit as the node-by-node pass from the last node to the root.
    #[test]
    fn refits_as_node_by_node() {
        let mut rng = crate::rng::Rng::new(4);
        let mut random = |n: usize| -> Vec<(DVec3, f64)> {
            (0..n)
                .map(|_| {
                    let c = DVec3::new(rng.f64() * 1e3 - 500.0, rng.f64() * 3.0, rng.f64() * 1e3 - 500.0);
                    (c, 0.1 + rng.f64() * 2.0)
                })
                .collect()
        };
        let spheres = random(40_000);
        let mut bvh = Bvh::build(&spheres);
        assert!(bvh.nodes.len() >= 4096, "{}", bvh.nodes.len());
        let moved = random(40_000);
        let mut want = bvh.nodes.clone();
        for n in (0..want.len()).rev() {
            let node = want[n];
            let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
            if node.count > 0 {
                for &i in &bvh.items[node.first as usize..(node.first + node.count) as usize] {
                    let (c, r) = moved[i as usize];
                    lo = lo.min(c - r);
                    hi = hi.max(c + r);
                }
            } else {
                for child in [node.first, node.first + 1] {
                    lo = lo.min(want[child as usize].lo);
                    hi = hi.max(want[child as usize].hi);
                }
            }
            (want[n].lo, want[n].hi) = (lo, hi);
        }
        bvh.refit(&moved);
        let bits = |v: DVec3| v.to_array().map(f64::to_bits);
        for (n, (a, b)) in bvh.nodes.iter().zip(&want).enumerate() {
            assert_eq!((bits(a.lo), bits(a.hi)), (bits(b.lo), bits(b.hi)), "node {n}");
        }
    }

    #[test]
    fn refitting_keeps_the_tree_until_it_degrades() {
        let spheres = clusters(256, false);
        let built = Bvh::build(&spheres);
        assert!(built.built_cost > 0.0 && built.refits == 0);
        // Everything shifted: the same tree fits as well as before.
        let shifted: Vec<_> = spheres.iter().map(|&(c, r)| (c + DVec3::new(3.0, -2.0, 1.0), r)).collect();
        let kept = Bvh::refit_or_build(Some(built.clone()), &shifted);
        assert_eq!((kept.refits, kept.built_cost), (1, built.built_cost));
        for (n, m) in kept.nodes.iter().zip(&Bvh::build(&shifted).nodes) {
            assert!((n.lo - m.lo).length() < 1e-9 && (n.hi - m.hi).length() < 1e-9);
        }
        // Members dealt out to other clusters: refitted leaves span the scene, so a new tree.
        let mixed = clusters(256, true);
        let mut refitted = built.clone();
        refitted.refit(&mixed);
        assert!(refitted.cost() > REBUILD_RATIO * built.built_cost, "{} vs {}", refitted.cost(), built.built_cost);
        let rebuilt = Bvh::refit_or_build(Some(built), &mixed);
        assert_eq!(rebuilt.refits, 0);
        assert!(rebuilt.cost() < refitted.cost());
        // Another count of spheres always builds.
        assert_eq!(Bvh::refit_or_build(Some(rebuilt), &spheres[..100]).refits, 0);
    }
}
