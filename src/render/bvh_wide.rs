//! The instance BVH collapsed to four children per node with f32 boxes, tested four at a
//! time in SIMD lanes: what the nearest-hit search walks in a crowd of instances.
//!
//! It only culls: a box a ray really crosses must never be skipped, and the f64 sphere test and
//! the octree traversal decide the hit as before, so the answer is bit-identical to the binary
//! f64 walk's (`tests`, and `tests/render.rs` against the plain search). Every box is widened
//! on both sides by [`SLACK`] times the largest coordinate magnitude of the scene's boxes,
//! which dwarfs the f32 rounding of the box corners and of the slab arithmetic for any ray
//! whose origin lies within [`REACH`] times that magnitude ([`WideBvh::covers_origin`]); other
//! rays use the binary f64 walk.
//!
//! Why that reach. A slab's t is `(corner − origin) · (1 / d)` in f32: the corner, the origin,
//! their difference, the reciprocal and the product each round once, by at most 2⁻²⁴ of
//! their magnitude, so the t found is the exact t of a plane moved along its axis by at most
//! about 4·2⁻²⁴·(|corner| + |origin|). Max, min and `≤` are exact, so the walk tests the
//! exact box with its planes moved that little. With corners within the scale `s` (widened by
//! 10⁻⁵ s) and origins within 10 s, a plane moves by at most 44·2⁻²⁴ s ≈ 2.6·10⁻⁶ s, under a
//! third of the widening: the box tested still holds the f64 box strictly inside, and a ray
//! that meets the f64 box (even at one point) meets it with room to spare.

use super::bvh::Bvh;
use glam::{BVec4A, DVec3, Vec4};

/// Widening of every box, relative to the largest coordinate magnitude of the scene's boxes.
/// The slab arithmetic in f32 errs by a few units in 2⁻²⁴ of that magnitude.
pub const SLACK: f64 = 1e-5;

/// The f32 walk answers for rays whose origin lies within this many times the scale (the
/// module notes show why 10 is safe: its rounding stays under a third of [`SLACK`]).
pub const REACH: f64 = 10.0;

/// Four children's boxes (lane k: child k) and what each child is.
#[derive(Clone, Copy, Debug)]
pub struct Node4 {
    /// Box minima and maxima per axis, lane by lane.
    pub lo: [Vec4; 3],
    /// Box maxima.
    pub hi: [Vec4; 3],
    /// Inner child: its node index; leaf child: its first index into [`Bvh::items`].
    pub child: [u32; 4],
    /// Leaf child: its item count (> 0); inner child: 0.
    pub count: [u32; 4],
    /// Lanes holding a child.
    pub used: u32,
    /// The binary node each lane was taken from (its box is refitted from there).
    pub src: [u32; 4],
}

/// The collapsed tree.
#[derive(Clone, Debug, Default)]
pub struct WideBvh {
    /// Nodes; node 0 is the root.
    pub nodes: Vec<Node4>,
    /// Largest coordinate magnitude of the scene's boxes: the widening's scale, and the
    /// largest origin magnitude the f32 walk answers for.
    pub scale: f64,
}

/// Trees with at least this many nodes are refitted in parallel.
#[cfg(feature = "parallel")]
pub(crate) const PARALLEL_NODES: usize = 4096;

/// Rays whose direction has a zero component get this for its reciprocal: finite, so that a
/// slab plane through the origin gives 0 or ±∞ and never NaN.
const INV_LIMIT: f32 = f32::MAX;

impl WideBvh {
    /// Collapses `bvh` (its current boxes), taking at each node the children of the larger
    /// inner children until four are found.
    pub fn collapse(bvh: &Bvh) -> WideBvh {
        let mut wide = WideBvh { nodes: Vec::with_capacity(bvh.nodes.len() / 3 + 1), scale: 0.0 };
        if bvh.nodes.is_empty() {
            return wide;
        }
        let mut pending = vec![(0usize, 0u32)]; // (wide node to fill, binary node)
        wide.nodes.push(empty());
        while let Some((w, b)) = pending.pop() {
            let node = bvh.nodes[b as usize];
            let mut slots = [0u32; 4];
            let mut len = if node.count > 0 {
                slots[0] = b;
                1
            } else {
                slots[..2].copy_from_slice(&[node.first, node.first + 1]);
                2
            };
            while len < 4 {
                let mut widest = None;
                for (k, &s) in slots[..len].iter().enumerate() {
                    if bvh.nodes[s as usize].count == 0 {
                        let a = area(bvh, s);
                        if widest.is_none_or(|(_, b)| a > b) {
                            widest = Some((k, a));
                        }
                    }
                }
                let Some((k, _)) = widest else { break };
                let first = bvh.nodes[slots[k] as usize].first;
                slots[k] = first;
                slots[len] = first + 1;
                len += 1;
            }
            let mut n = empty();
            for (k, &s) in slots[..len].iter().enumerate() {
                let c = bvh.nodes[s as usize];
                n.used |= 1 << k;
                n.src[k] = s;
                if c.count > 0 {
                    (n.child[k], n.count[k]) = (c.first, c.count);
                } else {
                    n.child[k] = wide.nodes.len() as u32;
                    wide.nodes.push(empty());
                    pending.push((n.child[k] as usize, s));
                }
            }
            wide.nodes[w] = n;
        }
        wide.refit(&bvh.nodes);
        wide
    }

    /// Copies the binary tree's current boxes (same topology) into the lanes, widened.
    pub fn refit(&mut self, binary: &[super::bvh::Node]) {
        let Some(root) = binary.first() else { return };
        self.scale = root.lo.abs().max(root.hi.abs()).max_element();
        if !self.scale.is_finite() {
            self.nodes.clear(); // the binary walk handles what f32 cannot
            return;
        }
        let slack = DVec3::splat(self.scale * SLACK);
        // Rounding to f32 moves a corner by at most 2⁻²⁴ of the scale, far inside the slack.
        let fill = |n: &mut Node4| {
            for k in 0..4 {
                if n.used & (1 << k) == 0 {
                    continue;
                }
                let c = &binary[n.src[k] as usize];
                let (lo, hi) = ((c.lo - slack).as_vec3(), (c.hi + slack).as_vec3());
                for axis in 0..3 {
                    n.lo[axis][k] = lo[axis];
                    n.hi[axis][k] = hi[axis];
                }
            }
        };
        #[cfg(feature = "parallel")]
        if self.nodes.len() >= PARALLEL_NODES {
            use rayon::prelude::*;
            self.nodes.par_iter_mut().with_min_len(1024).for_each(fill);
            return;
        }
        self.nodes.iter_mut().for_each(fill);
    }

    /// Whether the f32 walk answers for rays from `o`: within [`REACH`] times the magnitude
    /// the boxes were widened for.
    #[inline]
    pub fn covers_origin(&self, o: DVec3) -> bool {
        !self.nodes.is_empty() && o.abs().max_element() <= self.scale * REACH
    }
}

/// The ray as the f32 walk takes it.
#[derive(Clone, Copy)]
pub struct WideRay {
    o: [Vec4; 3],
    inv: [Vec4; 3],
}

impl WideRay {
    /// The ray `o + t·d`.
    #[inline]
    pub fn new(o: DVec3, d: DVec3) -> WideRay {
        let inv = |v: f64| {
            let r = (1.0 / v) as f32;
            if r.is_finite() {
                r
            } else if v.is_sign_negative() {
                -INV_LIMIT
            } else {
                INV_LIMIT
            }
        };
        WideRay { o: [0, 1, 2].map(|i| Vec4::splat(o[i] as f32)), inv: [0, 1, 2].map(|i| Vec4::splat(inv(d[i]))) }
    }

    /// Per lane: whether the ray meets child k's box within `[0, t_max]`, and its entry t
    /// (+∞ where it does not: a packet takes the least entry of its rays lane by lane).
    #[inline]
    pub fn test(&self, n: &Node4, t_max: f32) -> (u32, Vec4) {
        let mut t0 = Vec4::ZERO;
        let mut t1 = Vec4::splat(t_max);
        for axis in 0..3 {
            let a = (n.lo[axis] - self.o[axis]) * self.inv[axis];
            let b = (n.hi[axis] - self.o[axis]) * self.inv[axis];
            // With a finite reciprocal neither product is NaN (0·MAX = 0, ±∞·MAX = ±∞).
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        let hit: BVec4A = t0.cmple(t1);
        (hit.bitmask() & n.used, Vec4::select(hit, t0, Vec4::INFINITY))
    }
}

fn empty() -> Node4 {
    Node4 { lo: [Vec4::ZERO; 3], hi: [Vec4::ZERO; 3], child: [0; 4], count: [0; 4], used: 0, src: [0; 4] }
}

fn area(bvh: &Bvh, n: u32) -> f64 {
    let e = (bvh.nodes[n as usize].hi - bvh.nodes[n as usize].lo).max(DVec3::ZERO);
    e.x * e.y + e.y * e.z + e.z * e.x
}

/// A walk's stack: the tree is at most 32 binary levels deep and a four-wide node leaves at
/// most three siblings waiting, so 128 entries always suffice.
///
/// Its storage is left uninitialized (every ray's walk makes one).
pub type WideStack = crate::uninit_stack::UninitStack<(u32, f32), 128>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stack_pops_what_was_pushed_last_first() {
        let mut stack = WideStack::new();
        assert_eq!(stack.pop(), None);
        for round in 0..3u32 {
            for i in 0..128 {
                stack.push((i + round, i as f32 * 0.5));
            }
            for i in (0..128).rev() {
                assert_eq!(stack.pop(), Some((i + round, i as f32 * 0.5)));
            }
            assert_eq!(stack.pop(), None);
        }
    }
    use crate::render::bvh::box_entry;

    /// Every box a ray meets in f64 (from origins within the scene) is met by the f32 walk:
    /// random spheres, rays from random origins including axis-parallel ones.
    #[test]
    fn the_f32_walk_never_skips_a_box_the_f64_test_meets() {
        let mut rng = crate::rng::Rng::new(7);
        let spheres: Vec<(DVec3, f64)> = (0..2000)
            .map(|_| {
                let c = DVec3::new(rng.f64() * 200.0 - 100.0, rng.f64() * 4.0, rng.f64() * 200.0 - 100.0);
                (c, 0.05 + rng.f64())
            })
            .collect();
        let bvh = Bvh::build(&spheres);
        let wide = WideBvh::collapse(&bvh);
        // Origins within the scene, and from every third ray on, out to `REACH` times its scale
        // (the last ones right at it, per axis), those aimed at a point just inside or outside
        // a face of some sphere's box: the rays that graze the boxes, where rounding tells.
        let mut far = 0;
        for r in 0..6000 {
            let near = DVec3::new(rng.f64() * 200.0 - 100.0, rng.f64() * 4.0, rng.f64() * 200.0 - 100.0);
            let (o, mut d) = if r % 3 == 0 {
                (near, DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5).normalize())
            } else {
                let reach = wide.scale * REACH * if r % 10 == 1 { 1.0 } else { rng.f64() };
                let o = (rng.unit_vector().as_dvec3() * reach * 3f64.sqrt())
                    .clamp(DVec3::splat(-reach), DVec3::splat(reach));
                let (c, rad) = spheres[rng.below(spheres.len() as u64) as usize];
                let axis = rng.below(3) as usize;
                let mut target = c + DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5) * 2.0 * rad;
                target[axis] = c[axis] + rad * if rng.below(2) == 0 { 1.0 } else { -1.0 };
                target[axis] += (rng.f64() - 0.5) * 1e-6 * wide.scale;
                far += usize::from(o.abs().max_element() > wide.scale);
                (o, (target - o).normalize())
            };
            assert!(wide.covers_origin(o));
            if r % 7 == 0 {
                d.y = 0.0; // parallel to a slab
            }
            // Items whose sphere box the f64 test meets, against the items the f32 walk reaches.
            let inv = d.recip();
            let mut want: Vec<u32> = (0..spheres.len() as u32)
                .filter(|&i| {
                    let (c, rad) = spheres[i as usize];
                    box_entry(c - rad, c + rad, o, inv, f64::INFINITY).is_some()
                })
                .collect();
            let ray = WideRay::new(o, d);
            let mut got = Vec::new();
            let mut stack = WideStack::new();
            stack.push((0, 0.0));
            while let Some((n, _)) = stack.pop() {
                let node = &wide.nodes[n as usize];
                let (mut hit, _) = ray.test(node, f32::INFINITY);
                while hit != 0 {
                    let k = hit.trailing_zeros() as usize;
                    hit &= hit - 1;
                    if node.count[k] > 0 {
                        got.extend_from_slice(
                            &bvh.items[node.child[k] as usize..(node.child[k] + node.count[k]) as usize],
                        );
                    } else {
                        stack.push((node.child[k], 0.0));
                    }
                }
            }
            got.sort();
            want.retain(|i| got.binary_search(i).is_err());
            assert!(want.is_empty(), "ray {r} from {o}: skipped {want:?}");
        }
        assert!(far > 2000, "{far} rays from beyond the scale");
    }
}
