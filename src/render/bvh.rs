//! A bounding volume hierarchy over instance bounding spheres (their boxes), rebuilt every
//! frame in O(n log n) by median splits, so rays skip whole groups of instances and the cost
//! per ray grows with log n rather than n.

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
    /// Nodes; node 0 is the root.
    pub nodes: Vec<Node>,
    /// Instance indices, grouped by leaf.
    pub items: Vec<u32>,
}

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

/// Instances per leaf at most.
const LEAF: usize = 4;

impl Bvh {
    /// Builds over spheres (centre, radius).
    pub fn build(spheres: &[(DVec3, f64)]) -> Bvh {
        let mut bvh =
            Bvh { nodes: Vec::with_capacity(2 * spheres.len() / LEAF + 1), items: (0..spheres.len() as u32).collect() };
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
