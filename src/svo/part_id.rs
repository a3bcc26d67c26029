//! The identity of a shared part, for caches keyed by part (GPU pools, GI caches and
//! volumes). A raw address is not an identity: once a part is dropped, a new one can be
//! allocated at the same address and would be taken for the old. A [`PartId`] holds a weak
//! reference, which keeps the allocation reserved while the key exists, so equal keys always
//! mean the same part (an `Arc<Svo>` cannot be changed while another reference exists).

use super::Svo;
use std::hash::{Hash, Hasher};
use std::sync::{Arc, Weak};

/// A part's identity: equal only for the same `Arc` allocation.
#[derive(Clone, Debug)]
pub struct PartId(Weak<Svo>);

impl PartId {
    /// The identity of `svo`.
    pub fn of(svo: &Arc<Svo>) -> Self {
        PartId(Arc::downgrade(svo))
    }

    /// Whether the part still exists (a cache of a dropped part can go).
    pub fn alive(&self) -> bool {
        self.0.strong_count() > 0
    }

    /// Whether this is the identity of `svo`.
    pub fn is(&self, svo: &Arc<Svo>) -> bool {
        std::ptr::eq(self.0.as_ptr(), Arc::as_ptr(svo))
    }
}

impl PartialEq for PartId {
    fn eq(&self, other: &Self) -> bool {
        self.0.ptr_eq(&other.0)
    }
}

impl Eq for PartId {}

impl Hash for PartId {
    fn hash<H: Hasher>(&self, state: &mut H) {
        (self.0.as_ptr() as usize).hash(state);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_part_made_after_another_is_dropped_never_takes_its_identity() {
        let svo = || {
            Arc::new(Svo {
                bounds: crate::svo::Cube { min: glam::Vec3::ZERO, size: 1.0 },
                depth: 0,
                masks: Vec::new(),
                links: Vec::new(),
                level_start: vec![0],
                attrs: vec![crate::svo::Attr::default()],
                voxel_count: 0,
                emitters: Vec::new(),
                occupied: Default::default(),
            })
        };
        let a = svo();
        let id = PartId::of(&a);
        assert!(id.is(&a) && id == PartId::of(&a));
        drop(a);
        assert!(!id.alive());
        // Many fresh parts of the same size: the allocator would hand out the old address at
        // once if the key did not hold it.
        let fresh: Vec<_> = (0..64).map(|_| svo()).collect();
        assert!(fresh.iter().all(|b| !id.is(b) && id != PartId::of(b)));
    }
}
