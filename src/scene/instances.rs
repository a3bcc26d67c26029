//! A scene of part instances in a hierarchy: each instance places one part (an SVO) with a
//! local transform relative to its parent; world transforms are recomputed for dirty
//! instances and their descendants.

use super::transform::{is_well_conditioned, Transform, TransformError};
use crate::svo::Svo;
use glam::{DAffine3, DVec3};
use std::sync::Arc;

/// One placed part.
#[derive(Clone, Debug, PartialEq)]
pub struct Instance {
    /// Index into [`Scene::parts`].
    pub part: usize,
    /// Parent instance (its index is smaller than this instance's).
    pub parent: Option<usize>,
    /// Transform relative to the parent (or the world).
    pub local: Transform,
}

/// Why a scene edit was refused.
#[derive(Clone, Debug, thiserror::Error, PartialEq)]
pub enum SceneError {
    /// No such part.
    #[error("part {0} does not exist")]
    Part(usize),
    /// No such instance, or a parent that does not precede its child.
    #[error("instance {0} does not exist or cannot be a parent here")]
    Instance(usize),
    /// Bad transform.
    #[error(transparent)]
    Transform(#[from] TransformError),
    /// No more instances fit (they are numbered in 32 bits).
    #[error("a scene holds at most {} instances", u32::MAX)]
    Full,
}

/// Parts (built once) and their instances.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    /// The part octrees, shared by every instance of them.
    pub parts: Vec<Arc<Svo>>,
    instances: Vec<Instance>,
    world: Vec<DAffine3>,
    dirty: Vec<bool>,
    /// Where the instance list splits into independent runs: no instance at or after a split
    /// has a parent before it (a car and its seven children form one run). Runs update in
    /// parallel; empty until the next update after an instance is added.
    splits: Vec<usize>,
    /// Buffers kept between frames so that updating tens of thousands of instances does not
    /// allocate (and fault in fresh pages) every frame.
    scratch: Scratch,
    /// Counts the edits of which part an instance places (adding one, or [`Scene::set_part`]),
    /// so that what is derived from the instances' parts can be kept until they change.
    part_edits: u64,
    /// This scene among all scenes of the process (a clone is another scene).
    id: SceneId,
    /// Counts updates; `stamps[i]` is the update that last changed instance i's world
    /// transform (or its part), so that per-instance data derived from them can be refilled
    /// for the changed instances only.
    epoch: u64,
    stamps: Vec<u64>,
    /// The instances whose stamp is `epoch` (ascending): what the last update changed.
    last_changed: Vec<u32>,
}

/// A number no other scene of the process has: a new scene and every clone draw a fresh one.
#[derive(Debug, PartialEq, Eq)]
struct SceneId(u64);

impl SceneId {
    fn fresh() -> SceneId {
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);
        SceneId(NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed))
    }
}

impl Default for SceneId {
    fn default() -> SceneId {
        SceneId::fresh()
    }
}

impl Clone for SceneId {
    fn clone(&self) -> SceneId {
        SceneId::fresh()
    }
}

#[derive(Clone, Debug, Default)]
struct Scratch {
    /// Validated local transforms waiting to be applied.
    locals: Vec<(usize, Transform)>,
    /// Which instances' world transforms an update changed.
    changed: Vec<bool>,
    /// Per chunk of an update, the world transforms (and stamps) it replaced, to put back
    /// when a later one is refused.
    undo: Vec<Vec<(usize, DAffine3, u64)>>,
}

/// Instances below this count update and pose on one thread (threads cost more than they
/// save).
const PARALLEL_MIN: usize = 2048;

/// Sets each validated local transform of `locals` on its instance's record in `instances`
/// (which starts at instance `offset`, as `dirty` does), marking those that change.
fn apply_locals(locals: &[(usize, Transform)], offset: usize, instances: &mut [Instance], dirty: &mut [bool]) {
    for (j, &(i, t)) in locals.iter().enumerate() {
        // A crowd's posed cars lie scattered over its instances.
        if let Some(next) = locals.get(j + 4).and_then(|&(next, _)| instances.get(next - offset)) {
            crate::prefetch::prefetch_bytes(next, std::mem::size_of::<Instance>());
        }
        let k = i - offset;
        if instances[k].local != t {
            instances[k].local = t;
            dirty[k] = true;
        }
    }
}

/// The starts of the independent runs of `instances`: a run starts where no later instance
/// has a parent before it.
fn independent_runs(instances: &[Instance]) -> Vec<usize> {
    let mut starts = Vec::new();
    let mut lowest_parent = usize::MAX; // over the instances after the current one
    for i in (0..instances.len()).rev() {
        if lowest_parent > i {
            starts.push(i + 1);
        }
        if let Some(p) = instances[i].parent {
            lowest_parent = lowest_parent.min(p);
        }
    }
    starts.push(0);
    starts.reverse();
    starts.dedup();
    starts.retain(|&s| s < instances.len());
    starts
}

/// Chunk boundaries (starting with 0, ending with `n`) made of whole runs, about 64 chunks.
fn chunk_runs(starts: &[usize], n: usize) -> Vec<usize> {
    let target = (n / 64).max(PARALLEL_MIN / 4);
    let mut out = vec![0];
    for &s in starts {
        if s - out[out.len() - 1] >= target {
            out.push(s);
        }
    }
    out.push(n);
    out.dedup();
    out
}

/// The eight corners of the box [lo, hi].
pub fn box_corners(lo: DVec3, hi: DVec3) -> [DVec3; 8] {
    std::array::from_fn(|c| {
        DVec3::new(
            if c & 1 == 0 { lo.x } else { hi.x },
            if c & 2 == 0 { lo.y } else { hi.y },
            if c & 4 == 0 { lo.z } else { hi.z },
        )
    })
}

impl Scene {
    /// A scene over these parts, with no instances.
    pub fn new(parts: Vec<Arc<Svo>>) -> Self {
        Scene { parts, ..Default::default() }
    }

    /// Adds an instance; parents must be added before their children.
    pub fn add(&mut self, inst: Instance) -> Result<usize, SceneError> {
        if inst.part >= self.parts.len() {
            return Err(SceneError::Part(inst.part));
        }
        if let Some(p) = inst.parent {
            if p >= self.instances.len() {
                return Err(SceneError::Instance(p));
            }
        }
        Transform::new(inst.local.translation, inst.local.rotation, inst.local.scale)?;
        if self.instances.len() >= u32::MAX as usize {
            return Err(SceneError::Full);
        }
        self.splits.clear();
        self.instances.push(inst);
        self.world.push(DAffine3::IDENTITY);
        self.dirty.push(true);
        self.stamps.push(u64::MAX);
        self.part_edits += 1;
        Ok(self.instances.len() - 1)
    }

    /// Sets many local transforms at once ([`Scene::set_local`] for each), validating them
    /// in parallel; on an error nothing is changed.
    pub fn set_locals(&mut self, items: &[(usize, Transform)]) -> Result<(), SceneError> {
        self.set_locals_from(items.len(), |k| [items[k]])
    }

    /// [`Scene::set_locals`] for the transforms `make(0..count)` yields, `N` at a time (a
    /// car's eight parts from one pose computation): they are computed and validated in
    /// parallel and applied only if all are valid (in parallel too when the instances ascend
    /// over the whole batch, as a crowd's cars do).
    pub fn set_locals_from<const N: usize>(
        &mut self,
        count: usize,
        make: impl Fn(usize) -> [(usize, Transform); N] + Sync + Send,
    ) -> Result<(), SceneError> {
        let n = self.instances.len();
        let mut locals = std::mem::take(&mut self.scratch.locals);
        // Each group's transforms are written straight into its own N slots (moving whole
        // arrays of them through iterator adapters copied kilobytes per car).
        locals.resize(count * N, (0, Transform::IDENTITY));
        // Whether some group names its instances out of ascending order.
        let unordered = std::sync::atomic::AtomicBool::new(false);
        let group = |k: usize, out: &mut [(usize, Transform)]| -> Result<(), SceneError> {
            let mut last = None;
            for (slot, (i, t)) in out.iter_mut().zip(make(k)) {
                if i >= n {
                    return Err(SceneError::Instance(i));
                }
                if last.is_some_and(|l| l >= i) {
                    unordered.store(true, std::sync::atomic::Ordering::Relaxed);
                }
                last = Some(i);
                *slot = (i, Transform::new(t.translation, t.rotation, t.scale)?);
            }
            Ok(())
        };
        let sequential = |locals: &mut [(usize, Transform)]| {
            locals.chunks_mut(N.max(1)).enumerate().try_for_each(|(k, out)| group(k, out))
        };
        #[cfg(feature = "parallel")]
        let result = if count >= PARALLEL_MIN / 8 && N > 0 {
            // Runs of 64 groups, each run whole up to its own first error, their results in
            // order: the first error is the first bad transform in order, as one thread would
            // meet it.
            const RUN: usize = 64;
            let runs: Vec<_> = locals.chunks_mut(RUN * N).enumerate().collect();
            crate::pool::map_owned(runs, |(r, run)| {
                run.chunks_mut(N).enumerate().try_for_each(|(k, out)| group(r * RUN + k, out))
            })
            .into_iter()
            .collect::<Result<(), _>>()
        } else {
            sequential(&mut locals)
        };
        #[cfg(not(feature = "parallel"))]
        let result = sequential(&mut locals);
        // Instances ascending over all groups (a crowd's cars, each one's eight in order): the
        // records split into stretches that threads apply apart.
        #[cfg(feature = "parallel")]
        if result.is_ok()
            && count * N >= PARALLEL_MIN
            && !unordered.load(std::sync::atomic::Ordering::Relaxed)
            && locals.chunks(N).zip(locals.chunks(N).skip(1)).all(|(a, b)| a[N - 1].0 < b[0].0)
        {
            self.apply_ascending(&locals);
            self.scratch.locals = locals;
            return result;
        }
        if result.is_ok() {
            apply_locals(&locals, 0, &mut self.instances, &mut self.dirty);
        }
        self.scratch.locals = locals;
        result
    }

    /// Applies validated local transforms whose instances ascend, in parallel stretches of
    /// the records (each owning those up to its last instance).
    #[cfg(feature = "parallel")]
    fn apply_ascending(&mut self, locals: &[(usize, Transform)]) {
        const CHUNK: usize = 1024;
        let mut pieces = Vec::with_capacity(locals.len().div_ceil(CHUNK));
        let (mut inst, mut dirty, mut offset) = (&mut self.instances[..], &mut self.dirty[..], 0);
        for chunk in locals.chunks(CHUNK) {
            let end = chunk.last().map_or(offset, |&(i, _)| i + 1);
            let (a, b) = std::mem::take(&mut inst).split_at_mut(end - offset);
            let (c, d) = std::mem::take(&mut dirty).split_at_mut(end - offset);
            pieces.push((chunk, offset, a, c));
            (inst, dirty, offset) = (b, d, end);
        }
        crate::pool::map_owned(pieces, |(chunk, offset, inst, dirty)| apply_locals(chunk, offset, inst, dirty));
    }

    /// Replaces the part an instance places (a flip-book's frame); its transform stays.
    /// Frame-to-frame reuse sees the change (the instances' parts are compared).
    pub fn set_part(&mut self, i: usize, part: usize) -> Result<(), SceneError> {
        if part >= self.parts.len() {
            return Err(SceneError::Part(part));
        }
        let inst = self.instances.get_mut(i).ok_or(SceneError::Instance(i))?;
        if inst.part != part {
            inst.part = part;
            self.dirty[i] = true;
            self.part_edits += 1;
        }
        Ok(())
    }

    /// Replaces an instance's local transform (validated) and marks it dirty.
    pub fn set_local(&mut self, i: usize, t: Transform) -> Result<(), SceneError> {
        let t = Transform::new(t.translation, t.rotation, t.scale)?;
        let inst = self.instances.get_mut(i).ok_or(SceneError::Instance(i))?;
        if inst.local != t {
            inst.local = t;
            self.dirty[i] = true;
        }
        Ok(())
    }

    /// Recomputes world transforms of dirty instances and their descendants, in index order
    /// (parents before children) within each independent run of instances, the runs in
    /// parallel. Refuses (and leaves the old transforms in place) if a composed transform is
    /// near-singular.
    pub fn update(&mut self) -> Result<(), SceneError> {
        let n = self.instances.len();
        if self.splits.is_empty() {
            self.splits = independent_runs(&self.instances);
        }
        let mut sc = std::mem::take(&mut self.scratch);
        sc.changed.clear();
        sc.changed.resize(n, false);
        let (instances, dirty) = (&self.instances, &self.dirty);
        let epoch = self.epoch + 1;
        // One chunk of whole runs (`runs`: their starts): composes in place (parents are in
        // it, before their children), remembering what it replaced. Unchanged instances are
        // not touched (a crowd whose cars are posed only when seen changes a few of its
        // transforms); an instance's parent is looked up only once something before it in
        // its run changed (the 80 000 instances' records were a scan of megabytes).
        let run = |start: usize,
                   runs: &[usize],
                   world: &mut [DAffine3],
                   changed: &mut [bool],
                   stamps: &mut [u64],
                   undo: &mut Vec<(usize, DAffine3, u64)>| {
            undo.clear();
            let mut run_changed = false;
            let mut next_run = runs.iter().copied().peekable();
            let edited = &dirty[start..start + world.len()];
            let mut next = 0;
            while next < world.len() {
                if !run_changed {
                    // Nothing carries over: on to the next instance edited (the crowd's
                    // untouched instances are passed over as a scan of flags).
                    match edited[next..].iter().position(|&d| d) {
                        Some(skip) => next += skip,
                        None => break,
                    }
                }
                let (k, i) = (next, start + next);
                next += 1;
                // A run starting here (or passed over) starts unchanged.
                while next_run.next_if(|&r| r <= i).is_some() {
                    run_changed = false;
                }
                if !dirty[i] && !run_changed {
                    continue;
                }
                let inst = &instances[i];
                let parent_changed = inst.parent.is_some_and(|p| changed[p - start]);
                if !(dirty[i] || parent_changed) {
                    continue;
                }
                let local = inst.local.to_affine();
                let w = match inst.parent {
                    Some(p) => world[p - start] * local,
                    None => local,
                };
                if !is_well_conditioned(&w) {
                    return Err(i);
                }
                undo.push((k, world[k], stamps[k]));
                world[k] = w;
                changed[k] = true;
                run_changed = true;
                stamps[k] = epoch;
            }
            Ok(())
        };
        // Cut the runs into chunks of whole runs, a few per thread.
        let chunks = chunk_runs(&self.splits, n);
        sc.undo.resize_with(chunks.len().saturating_sub(1), Vec::new);
        let mut pieces = Vec::with_capacity(chunks.len());
        let (mut world, mut changed, mut stamps) = (&mut self.world[..], &mut sc.changed[..], &mut self.stamps[..]);
        let splits = &self.splits;
        for (w, undo) in chunks.windows(2).zip(sc.undo.iter_mut()) {
            let (a, b) = world.split_at_mut(w[1] - w[0]);
            let (c, d) = changed.split_at_mut(w[1] - w[0]);
            let (e, f) = stamps.split_at_mut(w[1] - w[0]);
            let runs = &splits[splits.partition_point(|&r| r < w[0])..splits.partition_point(|&r| r < w[1])];
            pieces.push((w[0], runs, a, c, e, undo));
            (world, changed, stamps) = (b, d, f);
        }
        let results = crate::pool::map_owned(pieces, |(start, runs, w, c, s, undo)| run(start, runs, w, c, s, undo));
        if let Some(bad) = results.iter().find_map(|r| r.err()) {
            // Every chunk puts back what it replaced: the old transforms stay whole.
            for (w, undo) in chunks.windows(2).zip(&sc.undo) {
                for &(k, old, stamp) in undo.iter().rev() {
                    self.world[w[0] + k] = old;
                    self.stamps[w[0] + k] = stamp;
                }
            }
            self.scratch = sc;
            return Err(TransformError::Singular(bad).into());
        }
        self.epoch = epoch;
        // What each chunk changed, in order: its undo list (a crowd's renderer refills just
        // these, instead of scanning every instance's stamp).
        self.last_changed.clear();
        for (w, undo) in chunks.windows(2).zip(&sc.undo) {
            self.last_changed.extend(undo.iter().map(|&(k, _, _)| (w[0] + k) as u32));
        }
        self.dirty.fill(false);
        self.scratch = sc;
        Ok(())
    }

    /// Instances.
    pub fn instances(&self) -> &[Instance] {
        &self.instances
    }

    /// World transform of instance `i` as of the last [`Scene::update`].
    pub fn world(&self, i: usize) -> DAffine3 {
        self.world[i]
    }

    /// All world transforms.
    pub fn worlds(&self) -> &[DAffine3] {
        &self.world
    }

    /// How many times an instance was added or given another part: equal counts mean every
    /// instance places the same part as it did.
    pub fn part_edits(&self) -> u64 {
        self.part_edits
    }

    /// This scene's number, which no other scene of the process (a clone included) has.
    pub fn id(&self) -> u64 {
        self.id.0
    }

    /// How many updates this scene has had.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// The update ([`Scene::epoch`]) that last changed instance i's world transform or part
    /// (`u64::MAX` for an instance added since the last update).
    pub fn stamp(&self, i: usize) -> u64 {
        self.stamps[i]
    }

    /// The instances the last successful update changed (those whose [`Scene::stamp`] is
    /// [`Scene::epoch`]), ascending; empty before the first update.
    pub fn changed_by_last_update(&self) -> &[u32] {
        &self.last_changed
    }

    /// Whether any instance still has an unapplied local change.
    pub fn is_dirty(&self) -> bool {
        self.dirty.iter().any(|&d| d)
    }

    /// World-space bounding box of all instances (corners of each part cube), for framing.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        self.bounds_of(0..self.instances.len())
    }

    /// World-space bounding box of some instances.
    pub fn bounds_of(&self, which: impl IntoIterator<Item = usize>) -> (DVec3, DVec3) {
        let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for i in which {
            let c = &self.parts[self.instances[i].part].bounds;
            let min = c.min.as_dvec3();
            for corner in box_corners(min, min + DVec3::splat(c.size as f64)) {
                let p = self.world[i].transform_point3(corner);
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        (lo, hi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::svo::Cube;
    use glam::DQuat;

    fn one_voxel() -> Arc<Svo> {
        let grid = crate::voxelize::VoxelGrid::from_coords(
            1,
            Cube { min: glam::Vec3::ZERO, size: 1.0 },
            [[0, 0, 0]],
            glam::Vec3::ONE,
        );
        Arc::new(crate::svo::build(&grid).unwrap())
    }

    fn t(k: usize) -> Transform {
        let q = DQuat::from_euler(glam::EulerRot::XYZ, 0.1 * k as f64, 0.2, -0.3 * (k % 7) as f64);
        Transform::new(DVec3::new(k as f64 * 0.5, 1.0, -((k % 5) as f64)), q, DVec3::new(1.0, 1.5, 0.75)).unwrap()
    }

    /// Roots with chains and fans of children, some parents far back, more instances than
    /// the parallel threshold.
    fn hierarchy(n: usize) -> Scene {
        let mut s = Scene::new(vec![one_voxel()]);
        for i in 0..n {
            let parent = match i % 10 {
                0 => None,
                1..=6 => Some(i - 1),
                7 => Some(i - 7),
                _ => Some(i - 3),
            };
            s.add(Instance { part: 0, parent, local: t(i) }).unwrap();
        }
        s
    }

    /// The parallel update of independent runs equals composing parent before child one at
    /// a time, for the first update and after a few locals change.
    #[test]
    fn parallel_update_matches_a_serial_composition() {
        let n = 3 * PARALLEL_MIN + 17;
        let mut s = hierarchy(n);
        assert!(s.update().is_ok());
        let serial = |s: &Scene| {
            let mut w = vec![DAffine3::IDENTITY; n];
            for (i, inst) in s.instances().iter().enumerate() {
                w[i] = inst.parent.map_or(DAffine3::IDENTITY, |p| w[p]) * inst.local.to_affine();
            }
            w
        };
        assert_eq!(s.worlds(), &serial(&s)[..]);
        for i in [5usize, 900, 2 * PARALLEL_MIN + 3] {
            s.set_local(i, t(i + 1)).unwrap();
        }
        s.update().unwrap();
        assert_eq!(s.worlds(), &serial(&s)[..]);
        assert!(s.splits.len() > 100, "runs found: {}", s.splits.len());
        // What the update changed: the edited instances and their descendants, in order.
        let stamped: Vec<u32> = (0..n).filter(|&i| s.stamp(i) == s.epoch()).map(|i| i as u32).collect();
        assert_eq!(s.changed_by_last_update(), &stamped[..]);
        assert!(stamped.len() > 3 && stamped.len() < n / 2, "{} changed", stamped.len());
    }

    /// A near-singular composition deep in a run is refused and leaves every world
    /// transform as it was.
    #[test]
    fn a_refused_update_changes_nothing() {
        let mut s = hierarchy(2 * PARALLEL_MIN);
        s.update().unwrap();
        let before = s.worlds().to_vec();
        let tiny = Transform::new(DVec3::ZERO, DQuat::IDENTITY, DVec3::splat(2e-4)).unwrap();
        // Two nested tiny scales: each is allowed, together they are near-singular.
        s.set_locals(&[(PARALLEL_MIN + 1, t(3)), (PARALLEL_MIN + 4, tiny), (PARALLEL_MIN + 5, tiny)]).unwrap();
        assert!(matches!(s.update(), Err(SceneError::Transform(TransformError::Singular(_)))));
        assert_eq!(s.worlds(), &before[..]);
        // A bad local in a batch: nothing of the batch is applied.
        let bad = Transform { scale: DVec3::ZERO, ..t(1) };
        assert!(s.set_locals(&[(0, t(9)), (1, bad)]).is_err());
        assert_eq!(s.instances()[0].local, t(0));
    }

    /// A batch long enough to be validated in parallel reports the first bad entry in order,
    /// whichever thread meets which first, and applies nothing.
    #[test]
    fn a_parallel_batch_names_its_first_bad_entry() {
        let n = 2 * PARALLEL_MIN;
        let mut s = hierarchy(n);
        s.update().unwrap();
        let bad_at = [n / 2 + 1, n - 3];
        let err = s.set_locals_from(n, |k| [(if bad_at.contains(&k) { n + k } else { k }, t(k + 2))]);
        assert_eq!(err, Err(SceneError::Instance(n + bad_at[0])));
        assert!(s.instances().iter().enumerate().all(|(i, inst)| inst.local == t(i)));
        // Without the bad entries every transform lands.
        s.set_locals_from(n, |k| [(k, t(k + 2))]).unwrap();
        let valid = |k: usize| Transform::new(t(k).translation, t(k).rotation, t(k).scale).unwrap();
        assert!(s.instances().iter().enumerate().all(|(i, inst)| inst.local == valid(i + 2)));
    }

    /// A batch leaves the records and, after the update, the world transforms as setting its
    /// transforms one at a time in order does: applied in parallel stretches when its
    /// instances ascend (a crowd's cars, scattered) and in order otherwise (groups given
    /// backwards, or overlapping so that a later group's transform wins).
    #[test]
    fn a_batch_lands_as_one_transform_at_a_time() {
        let n = 4 * PARALLEL_MIN;
        let mut base = hierarchy(n);
        base.update().unwrap();
        let scattered: Vec<[usize; 8]> = (0..600).map(|k| std::array::from_fn(|j| 13 * k + j)).collect();
        let backwards: Vec<[usize; 8]> = scattered.iter().rev().copied().collect();
        let overlapping: Vec<[usize; 8]> = (0..600).map(|k| std::array::from_fn(|j| 5 * k + j)).collect();
        for groups in [scattered, backwards, overlapping] {
            let (mut batch, mut one_by_one) = (base.clone(), base.clone());
            batch.set_locals_from(groups.len(), |k| groups[k].map(|i| (i, t(i + 3 + k)))).unwrap();
            for (k, group) in groups.iter().enumerate() {
                for &i in group {
                    one_by_one.set_local(i, t(i + 3 + k)).unwrap();
                }
            }
            assert_eq!(batch.instances(), one_by_one.instances());
            batch.update().unwrap();
            one_by_one.update().unwrap();
            assert_eq!(batch.worlds(), one_by_one.worlds());
            assert_eq!(batch.changed_by_last_update(), one_by_one.changed_by_last_update());
        }
    }

    #[test]
    fn independent_runs_start_where_no_later_parent_reaches_back() {
        let inst = |parent| Instance { part: 0, parent, local: Transform::IDENTITY };
        let list = [inst(None), inst(Some(0)), inst(None), inst(Some(2)), inst(Some(0)), inst(None), inst(Some(5))];
        // Instance 4's parent 0 joins the runs starting at 0 and 2; 5 starts a new one.
        assert_eq!(independent_runs(&list), vec![0, 5]);
        assert_eq!(independent_runs(&list[..4]), vec![0, 2]);
        assert_eq!(independent_runs(&[]), Vec::<usize>::new());
    }
}
