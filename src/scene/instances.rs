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
#[derive(Debug, thiserror::Error, PartialEq)]
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
}

/// Parts (built once) and their instances.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    /// The part octrees, shared by every instance of them.
    pub parts: Vec<Arc<Svo>>,
    instances: Vec<Instance>,
    world: Vec<DAffine3>,
    dirty: Vec<bool>,
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
        self.instances.push(inst);
        self.world.push(DAffine3::IDENTITY);
        self.dirty.push(true);
        Ok(self.instances.len() - 1)
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

    /// Recomputes world transforms of dirty instances and their descendants. Refuses (and
    /// leaves the old transforms in place) if a composed transform is near-singular.
    pub fn update(&mut self) -> Result<(), SceneError> {
        let mut world = self.world.clone();
        let mut changed = vec![false; self.instances.len()];
        for (i, inst) in self.instances.iter().enumerate() {
            let parent_changed = inst.parent.is_some_and(|p| changed[p]);
            if !(self.dirty[i] || parent_changed) {
                continue;
            }
            let local = inst.local.to_affine();
            let w = match inst.parent {
                Some(p) => world[p] * local,
                None => local,
            };
            if !is_well_conditioned(&w) {
                return Err(TransformError::Singular(i).into());
            }
            changed[i] = true;
            world[i] = w;
        }
        self.world = world;
        self.dirty.iter_mut().for_each(|d| *d = false);
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
            for k in 0..8 {
                let corner = c.min.as_dvec3()
                    + DVec3::new((k & 1) as f64, ((k >> 1) & 1) as f64, (k >> 2) as f64) * c.size as f64;
                let p = self.world[i].transform_point3(corner);
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
        (lo, hi)
    }
}
