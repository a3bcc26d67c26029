//! A bounding volume hierarchy over instance bounding spheres (their boxes), built in
//! O(n log n) by median splits (or, for a tree made afresh every frame, faster and looser by
//! Morton order: [`Bvh::build_sorted`]), so rays skip whole groups of instances and the cost per ray
//! grows with log n rather than n (large ranges split on two threads). Frame to frame it is
//! refitted in O(n) (same tree, boxes recomputed bottom-up), or only above the instances that
//! changed when the caller knows them ([`Bvh::refit_changed`]), and built again only when
//! refitting has made it [`REBUILD_RATIO`] times costlier than when it was built.

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
    /// The sum of the nodes' box areas as of the last build or refit ([`Bvh::cost`]'s
    /// numerator, kept up to date by the refit of a few instances without a pass over all).
    area_sum: f64,
    /// Leaves for [`Bvh::refit_changed`] (made on its first call on this tree).
    links: Links,
}

/// What refitting the boxes above a few instances needs: each instance's leaf.
#[derive(Clone, Debug, Default)]
struct Links {
    leaf_of: Vec<u32>,
    /// Scratch: the nodes this refit recomputes (all false between refits).
    marked: Vec<bool>,
}

/// A refit of at most one instance in this many takes the boxes above them alone
/// ([`Bvh::refit_changed_or_build`]); more, and the whole tree is refitted (in parallel).
pub const FEW_CHANGED: usize = 4;

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
        self.area_total() / area(root.lo, root.hi).max(f64::MIN_POSITIVE)
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
        self.area_sum = self.area_total();
        self.wide.refit(&self.nodes);
    }

    /// Recomputes only the boxes that hold one of the instances `changed` (instance indices,
    /// any order; those past the tree's are ignored): their leaves, and every node above them,
    /// children before parents, from `spheres` as [`Bvh::refit`] does. Every other instance's
    /// sphere must be the one the tree was last fitted to; then every box comes out as a whole
    /// refit makes it. Fills `dirty` with the nodes recomputed, ascending (what a copy of the
    /// tree elsewhere must update). A wide tree, if the tree has one, is refitted whole (the
    /// GPU's trees, which this serves, have none).
    pub fn refit_changed(&mut self, spheres: &[(DVec3, f64)], changed: &[u32], dirty: &mut Vec<u32>) {
        self.link();
        dirty.clear();
        let links = &mut self.links;
        for &i in changed {
            if let Some(q) = links.leaf_of.get(i as usize).and_then(|&n| links.marked.get_mut(n as usize)) {
                *q = true;
            }
        }
        // One pass from the last node to the root (children have higher indices than their
        // parents), reading only marks until a box must be recomputed: a walk up from each
        // leaf instead chased a parent pointer per level (1.2 ms for a crowd's 14 000 nodes).
        for n in (0..self.nodes.len()).rev() {
            let node = self.nodes[n];
            let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
            if node.count > 0 {
                if !links.marked[n] {
                    continue;
                }
                for &i in &self.items[node.first as usize..(node.first + node.count) as usize] {
                    let (c, r) = spheres[i as usize];
                    lo = lo.min(c - r);
                    hi = hi.max(c + r);
                }
            } else {
                let first = node.first as usize;
                if !(links.marked[first] || links.marked[first + 1]) {
                    continue;
                }
                links.marked[n] = true;
                let (a, b) = (self.nodes[first], self.nodes[first + 1]);
                lo = lo.min(a.lo).min(b.lo);
                hi = hi.max(a.hi).max(b.hi);
            }
            self.area_sum += area(lo, hi) - area(node.lo, node.hi);
            (self.nodes[n].lo, self.nodes[n].hi) = (lo, hi);
            dirty.push(n as u32);
        }
        for &n in dirty.iter() {
            links.marked[n as usize] = false;
        }
        dirty.reverse();
        self.refits += 1;
        if !self.wide.nodes.is_empty() {
            self.wide.refit(&self.nodes);
        }
    }

    /// Makes the leaves [`Bvh::refit_changed`] reads, once per tree.
    fn link(&mut self) {
        let links = &mut self.links;
        if links.marked.len() == self.nodes.len() && links.leaf_of.len() == self.items.len() {
            return;
        }
        links.leaf_of = vec![u32::MAX; self.items.len()];
        links.marked = vec![false; self.nodes.len()];
        for (n, node) in self.nodes.iter().enumerate().filter(|(_, node)| node.count > 0) {
            for &i in &self.items[node.first as usize..(node.first + node.count) as usize] {
                links.leaf_of[i as usize] = n as u32;
            }
        }
    }

    /// The sum of the nodes' box areas.
    fn area_total(&self) -> f64 {
        self.nodes.iter().map(|n| area(n.lo, n.hi)).sum()
    }

    /// [`Bvh::cost`] from the kept sum of areas.
    fn kept_cost(&self) -> f64 {
        let Some(root) = self.nodes.first() else { return 0.0 };
        self.area_sum / area(root.lo, root.hi).max(f64::MIN_POSITIVE)
    }

    /// [`Bvh::refit_or_build`] knowing which instances changed since `previous` was last
    /// fitted (`changed`, any order; None: any may have): up to one in [`FEW_CHANGED`], only
    /// the boxes above them are recomputed ([`Bvh::refit_changed`]). Fills `dirty` with the
    /// nodes recomputed, ascending, and returns the tree and whether every node is to be taken
    /// as new (built, or refitted whole; `dirty` is then empty). Without `wide`, the tree has
    /// no wide tree (dropped, or not made), for trees walked only elsewhere.
    pub fn refit_changed_or_build(
        previous: Option<Bvh>,
        spheres: &[(DVec3, f64)],
        changed: Option<&[u32]>,
        dirty: &mut Vec<u32>,
        wide: bool,
    ) -> (Bvh, bool) {
        dirty.clear();
        let previous = previous.filter(|b| wide || b.wide.nodes.is_empty());
        if let Some(mut bvh) = previous.filter(|b| b.items.len() == spheres.len() && !b.nodes.is_empty()) {
            let whole = match changed {
                Some(ids) if ids.len() * FEW_CHANGED <= spheres.len() => {
                    bvh.refit_changed(spheres, ids, dirty);
                    false
                }
                _ => {
                    bvh.refit(spheres);
                    true
                }
            };
            if bvh.kept_cost() <= REBUILD_RATIO * bvh.built_cost {
                return (bvh, whole);
            }
            dirty.clear();
        }
        (Bvh::build_with(spheres, wide), true)
    }

    /// `previous` refitted to `spheres` when it covers as many and stays within
    /// [`REBUILD_RATIO`] of its cost when built; otherwise a new tree.
    pub fn refit_or_build(previous: Option<Bvh>, spheres: &[(DVec3, f64)]) -> Bvh {
        if let Some(mut bvh) = previous.filter(|b| b.items.len() == spheres.len() && !b.nodes.is_empty()) {
            bvh.refit(spheres);
            if bvh.kept_cost() <= REBUILD_RATIO * bvh.built_cost {
                return bvh;
            }
        }
        Bvh::build(spheres)
    }
    /// Builds over spheres (centre, radius).
    pub fn build(spheres: &[(DVec3, f64)]) -> Bvh {
        Bvh::build_with(spheres, true)
    }

    /// [`Bvh::build`], with the wide tree or without it (a tree walked only elsewhere, as the
    /// GPU walks its own copy: refits then skip it).
    pub fn build_with(spheres: &[(DVec3, f64)], wide: bool) -> Bvh {
        let mut bvh = Bvh::default();
        if spheres.is_empty() {
            return bvh;
        }
        let mut items: Vec<u32> = (0..spheres.len() as u32).collect();
        bvh.nodes = build_nodes(spheres, &mut items, 0);
        bvh.items = items;
        bvh.area_sum = bvh.area_total();
        bvh.built_cost = bvh.kept_cost();
        if wide {
            bvh.wide = super::bvh_wide::WideBvh::collapse(&bvh);
        }
        bvh
    }
}

impl Bvh {
    /// [`Bvh::build_with`] in O(n log n) with small constants: the spheres sorted by the
    /// Morton code of their centres (10 bits an axis on a cube around them: nearby centres
    /// lie nearby in the order) and each range split where the leading bit in which its codes
    /// differ turns to 1 — the planes of an octree over that cube — or at its middle when
    /// they are all equal; the boxes fitted after. Each split of the first kind uses up a bit,
    /// so no leaf lies deeper than 30 + log₂ n. Looser boxes than the median splits' (which
    /// pick the widest axis at every level), built in about 2/5 of the time (benchmarks.md,
    /// step 76): for a tree made afresh every frame (the hit buffer's moved spheres). Centres
    /// that are not finite sort first.
    pub fn build_sorted(spheres: &[(DVec3, f64)], wide: bool) -> Bvh {
        let mut bvh = Bvh::default();
        if spheres.is_empty() {
            return bvh;
        }
        let (items, codes) = morton_order(spheres);
        bvh.items = items;
        let n = spheres.len();
        let mut nodes = Vec::with_capacity(2 * n / LEAF + 1);
        nodes.push(Node { lo: DVec3::ZERO, hi: DVec3::ZERO, first: 0, count: 0 });
        let mut stack = vec![(0usize, 0usize, n)];
        while let Some((k, start, end)) = stack.pop() {
            if end - start <= LEAF {
                nodes[k].first = start as u32;
                nodes[k].count = (end - start) as u32;
                continue;
            }
            let left = nodes.len();
            nodes.push(Node { lo: DVec3::ZERO, hi: DVec3::ZERO, first: 0, count: 0 });
            nodes.push(Node { lo: DVec3::ZERO, hi: DVec3::ZERO, first: 0, count: 0 });
            nodes[k].first = left as u32;
            // Sorted, the range's first code has a 0 at that bit and its last a 1: both halves
            // hold some (the clamp only guards that every range shrinks).
            let (a, b) = (codes[start], codes[end - 1]);
            let mid = if a == b {
                (start + end) / 2
            } else {
                let bit = 31 - (a ^ b).leading_zeros();
                (start + codes[start..end].partition_point(|&c| (c >> bit) & 1 == 0)).clamp(start + 1, end - 1)
            };
            stack.push((left, start, mid));
            stack.push((left + 1, mid, end));
        }
        bvh.nodes = nodes;
        // The boxes as a refit fits them: leaves from their spheres, parents from children.
        bvh.refit(spheres);
        bvh.refits = 0;
        bvh.built_cost = bvh.kept_cost();
        if wide {
            bvh.wide = super::bvh_wide::WideBvh::collapse(&bvh);
        }
        bvh
    }
}

/// The sphere indices ordered by the Morton code of their centres (10 bits per axis over a
/// cube around the finite centres; ties, and centres that are not finite, by index), and
/// their codes in that order: a stable radix sort, in O(n).
fn morton_order(spheres: &[(DVec3, f64)]) -> (Vec<u32>, Vec<u32>) {
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for (c, _) in spheres.iter().filter(|(c, _)| c.is_finite()) {
        lo = lo.min(*c);
        hi = hi.max(*c);
    }
    // One scale for all three axes (a cube around the centres): a flat crowd's height then
    // takes few of the bits, and the code's leading bits split the ground, not the cars.
    let scale = DVec3::splat(1023.0 / (hi - lo).max_element().max(f64::MIN_POSITIVE));
    // Spreads the low 10 bits of v two zero bits apart.
    let spread = |v: u32| {
        let mut x = v & 0x3ff;
        x = (x | (x << 16)) & 0x0300_00ff;
        x = (x | (x << 8)) & 0x0300_f00f;
        x = (x | (x << 4)) & 0x030c_30c3;
        (x | (x << 2)) & 0x0924_9249
    };
    // (A NaN or infinite coordinate quantizes to 0 or 1023: a cast saturates.)
    let code = |c: DVec3| {
        let q = ((c - lo) * scale).clamp(DVec3::ZERO, DVec3::splat(1023.0));
        let finite = c.is_finite() as u32;
        finite * (spread(q.x as u32) | spread(q.y as u32) << 1 | spread(q.z as u32) << 2)
    };
    let mut keys: Vec<(u32, u32)> = spheres.iter().enumerate().map(|(i, (c, _))| (code(*c), i as u32)).collect();
    let mut spare = vec![(0u32, 0u32); keys.len()];
    // The 30-bit codes ten bits at a time, least significant first, each pass stable (equal
    // codes keep the index order); the three passes' counts in one read of the keys.
    let mut counts = [[0usize; 1025]; 3];
    for &(k, _) in &keys {
        for (p, count) in counts.iter_mut().enumerate() {
            count[((k >> (10 * p)) & 0x3ff) as usize + 1] += 1;
        }
    }
    for (p, count) in counts.iter_mut().enumerate() {
        for b in 1..1025 {
            count[b] += count[b - 1];
        }
        for &(k, i) in &keys {
            let slot = &mut count[((k >> (10 * p)) & 0x3ff) as usize];
            spare[*slot] = (k, i);
            *slot += 1;
        }
        std::mem::swap(&mut keys, &mut spare);
    }
    (keys.iter().map(|&(_, i)| i).collect(), keys.iter().map(|&(k, _)| k).collect())
}

/// Ranges at least this long are split in two built side by side (where the build has
/// threads).
#[cfg(feature = "parallel")]
const PARALLEL_BUILD: usize = 16_384;

/// The box around `work`'s spheres, and the axis along which their centres spread most.
fn bounds(spheres: &[(DVec3, f64)], work: &[u32]) -> (DVec3, DVec3, usize) {
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    let (mut clo, mut chi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for &i in work {
        let (c, r) = spheres[i as usize];
        lo = lo.min(c - r);
        hi = hi.max(c + r);
        clo = clo.min(c);
        chi = chi.max(c);
    }
    let ext = chi - clo;
    let axis = if ext.x >= ext.y && ext.x >= ext.z {
        0
    } else if ext.y >= ext.z {
        1
    } else {
        2
    };
    (lo, hi, axis)
}

/// Reorders `work` into leaf order and returns the nodes of its tree (root first, every
/// node's children after it; leaves index `work` from `offset`, its place in the whole list):
/// median splits on the axis where the centres spread most, down to [`LEAF`] spheres. Large
/// ranges build their two halves on two threads and put the halves' nodes after the root.
fn build_nodes(spheres: &[(DVec3, f64)], work: &mut [u32], offset: usize) -> Vec<Node> {
    let key = |i: u32, axis: usize| spheres[i as usize].0[axis];
    #[cfg(feature = "parallel")]
    if work.len() >= PARALLEL_BUILD {
        let (lo, hi, axis) = bounds(spheres, work);
        let mid = work.len() / 2;
        work.select_nth_unstable_by(mid, |&a, &b| key(a, axis).total_cmp(&key(b, axis)));
        let (a, b) = work.split_at_mut(mid);
        let (left, right) = rayon::join(|| build_nodes(spheres, a, offset), || build_nodes(spheres, b, offset + mid));
        // The root, the halves' roots as its two children, then the rest of each half: a
        // half's node k ≥ 1 lands at `base + k - 1`.
        let (left_base, right_base) = (3, 3 + left.len() - 1);
        let moved = |n: Node, base: usize| {
            if n.count == 0 {
                Node { first: (base + n.first as usize - 1) as u32, ..n }
            } else {
                n
            }
        };
        let mut nodes = Vec::with_capacity(1 + left.len() + right.len());
        nodes.push(Node { lo, hi, first: 1, count: 0 });
        nodes.push(moved(left[0], left_base));
        nodes.push(moved(right[0], right_base));
        nodes.extend(left[1..].iter().map(|&n| moved(n, left_base)));
        nodes.extend(right[1..].iter().map(|&n| moved(n, right_base)));
        return nodes;
    }
    let mut nodes = Vec::with_capacity(2 * work.len() / LEAF + 1);
    nodes.push(Node { lo: DVec3::ZERO, hi: DVec3::ZERO, first: 0, count: 0 });
    // (node, start, end) ranges still to split.
    let mut stack = vec![(0usize, 0usize, work.len())];
    while let Some((n, start, end)) = stack.pop() {
        let (lo, hi, axis) = bounds(spheres, &work[start..end]);
        nodes[n].lo = lo;
        nodes[n].hi = hi;
        if end - start <= LEAF {
            nodes[n].first = (offset + start) as u32;
            nodes[n].count = (end - start) as u32;
            continue;
        }
        let mid = (start + end) / 2;
        work[start..end].select_nth_unstable_by(mid - start, |&a, &b| key(a, axis).total_cmp(&key(b, axis)));
        let left = nodes.len();
        nodes.push(Node { lo: DVec3::ZERO, hi: DVec3::ZERO, first: 0, count: 0 });
        nodes.push(Node { lo: DVec3::ZERO, hi: DVec3::ZERO, first: 0, count: 0 });
        nodes[n].first = left as u32;
        nodes[n].count = 0;
        stack.push((left, start, mid));
        stack.push((left + 1, mid, end));
    }
    nodes
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
    fn refitting_the_changed_instances_boxes_is_a_whole_refit() {
        let mut rng = crate::rng::Rng::new(9);
        let mut spheres: Vec<(DVec3, f64)> = (0..5_000)
            .map(|_| (DVec3::new(rng.f64() * 400.0 - 200.0, rng.f64(), rng.f64() * 400.0 - 200.0), 0.5 + rng.f64()))
            .collect();
        let mut part = Bvh::build(&spheres);
        let mut whole = part.clone();
        let mut dirty = Vec::new();
        let bits = |v: DVec3| v.to_array().map(f64::to_bits);
        // A few, one, a thousand (some twice) and none; then one flung far out, which widens
        // the root (and with it the wide tree's widening).
        for (round, count) in [10usize, 1, 1_000, 0, 1].into_iter().enumerate() {
            let before = part.nodes.clone();
            let changed: Vec<u32> = (0..count).map(|_| rng.below(spheres.len() as u64) as u32).collect();
            for &i in &changed {
                let far = if round == 4 { 1e4 } else { 3.0 };
                spheres[i as usize].0 += DVec3::new(rng.f64() - 0.5, 0.0, rng.f64() - 0.5) * far;
            }
            part.refit_changed(&spheres, &changed, &mut dirty);
            whole.refit(&spheres);
            assert!(dirty.windows(2).all(|p| p[0] < p[1]), "round {round}: not ascending");
            for (n, (a, b)) in part.nodes.iter().zip(&whole.nodes).enumerate() {
                assert_eq!((bits(a.lo), bits(a.hi)), (bits(b.lo), bits(b.hi)), "round {round}, node {n}");
                let was = (bits(before[n].lo), bits(before[n].hi));
                assert!(
                    was == (bits(a.lo), bits(a.hi)) || dirty.binary_search(&(n as u32)).is_ok(),
                    "round {round}: node {n} changed unlisted"
                );
            }
            for (w, (a, b)) in part.wide.nodes.iter().zip(&whole.wide.nodes).enumerate() {
                assert_eq!((a.lo, a.hi), (b.lo, b.hi), "round {round}, wide node {w}");
            }
            assert_eq!(part.wide.scale, whole.wide.scale);
            assert!((part.kept_cost() - whole.cost()).abs() <= 1e-9 * whole.cost(), "round {round}");
        }
        // Through refit_changed_or_build: few changed, only their boxes; many, the whole tree.
        let few: Vec<u32> = (0..10).collect();
        let (kept, all) = Bvh::refit_changed_or_build(Some(part.clone()), &spheres, Some(&few), &mut dirty, true);
        assert!(!all && !dirty.is_empty() && kept.refits == part.refits + 1);
        let many: Vec<u32> = (0..spheres.len() as u32 / 2).collect();
        let (_, all) = Bvh::refit_changed_or_build(Some(part), &spheres, Some(&many), &mut dirty, true);
        assert!(all && dirty.is_empty());
    }

    /// A tree built from halves built apart (past `PARALLEL_BUILD` spheres) is one tree:
    /// every node after its parent, every sphere in exactly one leaf, and every box what a
    /// refit of its own spheres makes it.
    #[test]
    fn a_tree_built_in_halves_is_one_tree() {
        let mut rng = crate::rng::Rng::new(21);
        let spheres: Vec<(DVec3, f64)> = (0..70_001)
            .map(|_| (DVec3::new(rng.f64() * 900.0, rng.f64() * 5.0, rng.f64() * 300.0), 0.2 + rng.f64() * 3.0))
            .collect();
        let built = Bvh::build(&spheres);
        let mut seen = vec![0u32; spheres.len()];
        for (n, node) in built.nodes.iter().enumerate() {
            if node.count == 0 {
                assert!(node.first as usize > n && node.first as usize + 1 < built.nodes.len(), "node {n}");
            } else {
                for &i in &built.items[node.first as usize..(node.first + node.count) as usize] {
                    seen[i as usize] += 1;
                }
            }
        }
        assert!(seen.iter().all(|&k| k == 1), "a sphere in no leaf or in two");
        let mut refitted = built.clone();
        refitted.refit(&spheres);
        let bits = |v: DVec3| v.to_array().map(f64::to_bits);
        for (n, (a, b)) in built.nodes.iter().zip(&refitted.nodes).enumerate() {
            assert_eq!((bits(a.lo), bits(a.hi)), (bits(b.lo), bits(b.hi)), "node {n}");
        }
    }

    /// The sorted build makes a tree as the median one does (every node after its parent,
    /// every sphere in one leaf of at most [`LEAF`], every box its refit's), of nearby spheres
    /// (points along a line given scrambled come out in order), whose walks find what a scan
    /// of the spheres finds; centres that are not finite are kept.
    #[test]
    fn a_sorted_tree_is_a_tree_of_nearby_spheres() {
        let mut rng = crate::rng::Rng::new(5);
        let mut spheres: Vec<(DVec3, f64)> = (0..5_001)
            .map(|_| (DVec3::new(rng.f64() * 900.0, rng.f64() * 5.0, rng.f64() * 300.0), 0.2 + rng.f64() * 3.0))
            .collect();
        spheres.push((DVec3::new(f64::NAN, 0.0, 0.0), 1.0));
        spheres.push((DVec3::new(f64::INFINITY, 1.0, 2.0), 1.0));
        let tree = Bvh::build_sorted(&spheres, true);
        let mut seen = vec![0u32; spheres.len()];
        for (n, node) in tree.nodes.iter().enumerate() {
            if node.count == 0 {
                assert!(node.first as usize > n && node.first as usize + 1 < tree.nodes.len(), "node {n}");
            } else {
                assert!(node.count as usize <= LEAF, "node {n}");
                for &i in &tree.items[node.first as usize..(node.first + node.count) as usize] {
                    seen[i as usize] += 1;
                }
            }
        }
        assert!(seen.iter().all(|&k| k == 1), "a sphere in no leaf or in two");
        let depth = |tree: &Bvh| {
            let (mut stack, mut deepest) = (vec![(0usize, 1u32)], 0);
            while let Some((k, d)) = stack.pop() {
                deepest = deepest.max(d);
                let node = tree.nodes[k];
                if node.count == 0 {
                    stack.extend([(node.first as usize, d + 1), (node.first as usize + 1, d + 1)]);
                }
            }
            deepest
        };
        assert!(depth(&tree) <= 30 + 13 + 1, "{}", depth(&tree));
        // All in one place: every code equal, halves all the way down.
        let same = vec![(DVec3::splat(2.0), 1.0); 1000];
        assert_eq!(depth(&Bvh::build_sorted(&same, false)), 9);
        let mut refitted = tree.clone();
        refitted.refit(&spheres);
        let bits = |v: DVec3| v.to_array().map(f64::to_bits);
        for (n, (a, b)) in tree.nodes.iter().zip(&refitted.nodes).enumerate() {
            assert_eq!((bits(a.lo), bits(a.hi)), (bits(b.lo), bits(b.hi)), "node {n}");
        }
        // (Its cost is not a number here, with a sphere at infinity: as the median tree's.)
        assert_eq!((tree.built_cost.to_bits(), tree.refits), (tree.cost().to_bits(), 0));
        assert_eq!(tree.wide.nodes.len(), super::super::bvh_wide::WideBvh::collapse(&tree).nodes.len());
        // Walks against a scan: which spheres' boxes meet a query box.
        let meets = |lo: DVec3, hi: DVec3, qlo: DVec3, qhi: DVec3| lo.cmple(qhi).all() && qlo.cmple(hi).all();
        let mut found = 0;
        for _ in 0..300 {
            let qlo = DVec3::new(rng.f64() * 950.0 - 25.0, rng.f64() * 6.0 - 0.5, rng.f64() * 320.0 - 10.0);
            let qhi = qlo + DVec3::new(rng.f64() * 8.0, rng.f64() * 3.0, rng.f64() * 8.0);
            let hit = |i: u32| {
                let (c, r) = spheres[i as usize];
                meets(c - r, c + r, qlo, qhi)
            };
            let want = (0..spheres.len() as u32).any(hit);
            found += want as u32;
            assert_eq!(tree.any_item(usize::MAX, |lo, hi| meets(lo, hi, qlo, qhi), hit), Some(want), "{qlo} {qhi}");
        }
        assert!((30..270).contains(&found), "the queries should both meet and miss ({found})");
        // Along a line, scrambled: sorted by position.
        let line: Vec<(DVec3, f64)> = (0..64).map(|k| (DVec3::new(((k * 37) % 64) as f64, 0.0, 0.0), 0.1)).collect();
        let order: Vec<f64> = Bvh::build_sorted(&line, false).items.iter().map(|&i| line[i as usize].0.x).collect();
        assert_eq!(order, (0..64).map(|k| k as f64).collect::<Vec<_>>());
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
