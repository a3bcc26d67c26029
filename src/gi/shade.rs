//! GI for a rendered frame (CPU): caches from each part's SVO, the world volume around the
//! scene, injection, levels, and cones gathered at every pixel that hit something. The indirect
//! light replaces the renderer's flat ambient term (albedo × sky) with albedo × the cone-traced
//! light, in which the sky fills only what the cones do not see — colour bleeding and ambient
//! occlusion together. A glossy pixel (specular reflectance ks > 0) also swaps its specular
//! ambient term (ks × sky) for ks × one specular cone along the mirror direction, as wide as
//! its Phong lobe ([`crate::render::brdf::cone_aperture`]).

use super::cache::{VoxelCache, MAX_CACHE_DEPTH};
use super::cone::{gather, trace, ConeSettings};
use super::inject::{inject_cells, Cells};
use super::levels::{self, Chain, Levels};
use super::sparse::{SparseLevels, SparseVolume};
use super::volume::{Filter, GiError, Layout, Volume, VolumeSpec};
use crate::render::hitbuffer::HitRecord;
use crate::render::Frame;
use crate::scene::{Camera, Lights, Scene};
use crate::svo::PartId;
use glam::{DVec3, Vec3};
use std::collections::HashMap;
use std::time::Instant;

/// Voxel caches kept between frames: one per part and cache level, built the first time a
/// frame needs it (the level follows the volume's cell size, which follows the camera).
#[derive(Default)]
pub struct GiCaches {
    // Keyed by the part's identity and cache level.
    built: HashMap<(PartId, u32), VoxelCache>,
    // The last frame's volume and level chain, with what they were made from.
    last: Option<LastVolume>,
    // Hears what the light's passes are doing (see `on_stage`).
    stage: Option<StageHook>,
}

/// What [`GiCaches::on_stage`] keeps.
type StageHook = Box<dyn Fn(&str) + Send + Sync>;

/// What a level chain depends on besides its volume and lights: the bounces and the cones
/// they were gathered with (past one bounce), whether it is anisotropic, the emitter
/// samples its cells drew, and whether the bounces' tail was added (past one bounce).
pub(crate) type ChainKey = (u32, ConeSettings, bool, u32, bool);

struct LastVolume {
    key: VolumeKey,
    lights: Lights,
    bounces: ChainKey,
    // The cones the pixels gathered with (their light changes with them, the chain does not).
    cones: ConeSettings,
    volume: WorldVolume,
    chain: WorldChain,
}

/// A frame's world volume in the layout the frame picked.
enum WorldVolume {
    Dense(Volume),
    Sparse(SparseVolume),
}

impl WorldVolume {
    fn cells(&self) -> &dyn CellsDyn {
        match self {
            WorldVolume::Dense(v) => v,
            WorldVolume::Sparse(v) => v,
        }
    }
    fn occupied(&self) -> usize {
        match self {
            WorldVolume::Dense(v) => v.occupancy.iter().filter(|&&o| o > 0.0).count(),
            WorldVolume::Sparse(v) => v.occupancy.iter().filter(|&&o| o > 0.0).count(),
        }
    }
    fn bytes(&self) -> u64 {
        match self {
            WorldVolume::Dense(v) => SparseVolume::dense_bytes(v.spec.res),
            WorldVolume::Sparse(v) => v.bytes(),
        }
    }
    /// The level chain over this volume's cells lit to `rgba`.
    fn chain(&self, rgba: Vec<glam::Vec4>, anisotropic: bool) -> WorldChain {
        match self {
            WorldVolume::Dense(v) if anisotropic => WorldChain::DenseAniso(levels::build_aniso_from(
                levels::Level { res: v.spec.res, cell: v.spec.cell, rgba },
                v.spec.min,
            )),
            WorldVolume::Dense(v) => WorldChain::Dense(levels::build_from(
                levels::Level { res: v.spec.res, cell: v.spec.cell, rgba },
                v.spec.min,
            )),
            WorldVolume::Sparse(v) => WorldChain::Sparse(SparseLevels::build(v, rgba)),
        }
    }
}

/// [`Cells`] as a trait object (both layouts behind one reference).
trait CellsDyn: Sync {
    fn count(&self) -> usize;
    fn get(&self, i: usize) -> super::inject::CellSums;
}

impl<T: Cells> CellsDyn for T {
    fn count(&self) -> usize {
        self.cell_count()
    }
    fn get(&self, i: usize) -> super::inject::CellSums {
        self.sums(i)
    }
}

/// A level chain of either layout.
enum WorldChain {
    Dense(Levels),
    DenseAniso(levels::AnisoLevels),
    Sparse(SparseLevels),
}

impl Chain for WorldChain {
    fn min(&self) -> DVec3 {
        match self {
            WorldChain::Dense(c) => c.min(),
            WorldChain::DenseAniso(c) => c.min(),
            WorldChain::Sparse(c) => c.min(),
        }
    }
    fn count(&self) -> usize {
        match self {
            WorldChain::Dense(c) => c.count(),
            WorldChain::DenseAniso(c) => c.count(),
            WorldChain::Sparse(c) => c.count(),
        }
    }
    fn res(&self, l: usize) -> u32 {
        match self {
            WorldChain::Dense(c) => c.res(l),
            WorldChain::DenseAniso(c) => c.res(l),
            WorldChain::Sparse(c) => c.res(l),
        }
    }
    fn cell(&self, l: usize) -> f64 {
        match self {
            WorldChain::Dense(c) => c.cell(l),
            WorldChain::DenseAniso(c) => c.cell(l),
            WorldChain::Sparse(c) => c.cell(l),
        }
    }
    fn value(&self, l: usize, c: [u32; 3]) -> glam::Vec4 {
        match self {
            WorldChain::Dense(ch) => ch.value(l, c),
            WorldChain::DenseAniso(ch) => ch.value(l, c),
            WorldChain::Sparse(ch) => ch.value(l, c),
        }
    }
    // Dispatched once per sample, not once per corner.
    fn trilinear(&self, l: usize, p: DVec3) -> glam::Vec4 {
        match self {
            WorldChain::Dense(ch) => ch.trilinear(l, p),
            WorldChain::DenseAniso(ch) => ch.trilinear(l, p),
            WorldChain::Sparse(ch) => ch.trilinear(l, p),
        }
    }
    fn trilinear_dir(&self, l: usize, p: DVec3, faces: &levels::FaceWeights) -> glam::Vec4 {
        match self {
            WorldChain::Dense(ch) => ch.trilinear(l, p),
            WorldChain::DenseAniso(ch) => ch.trilinear_dir(l, p, faces),
            WorldChain::Sparse(ch) => ch.trilinear(l, p),
        }
    }
}

/// Which world volume layout GI uses (`--gi-volume`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum VolumeChoice {
    /// The frame plan picks: sparse above [`SPARSE_ABOVE`] cells per side (when the
    /// resolution is a multiple of 8), dense otherwise.
    #[default]
    Auto,
    /// Always dense (up to 512³).
    Dense,
    /// Always sparse (multiples of 8 up to 1024³).
    Sparse,
}

/// Resolution above which `auto` picks the sparse volume (docs/gi.md, "Sparse volume").
pub const SPARSE_ABOVE: u32 = 128;

impl VolumeChoice {
    /// The layout for `res` cells per side.
    pub fn pick(self, res: u32) -> Layout {
        match self {
            VolumeChoice::Dense => Layout::Dense,
            VolumeChoice::Sparse => Layout::Sparse,
            VolumeChoice::Auto if res > SPARSE_ABOVE && res % super::sparse::BRICK == 0 => Layout::Sparse,
            VolumeChoice::Auto => Layout::Dense,
        }
    }

    /// The layout on the GPU, whose storage bindings hold at most `max_binding` bytes. `auto`
    /// is the CPU's choice — dense up to 128³, sparse above where 8 divides `res` (on an NVIDIA
    /// H200 the sparse box took 7.0 ms against the dense 9.4 at 256³, in a fifth of the memory,
    /// and par at 128³: docs/gi.md) — but dense where a dense volume's accumulation cells do
    /// not fit one binding only if 8 does not divide `res`, and, for anisotropic levels (which
    /// need the dense volume), dense wherever it fits.
    pub fn pick_on_gpu(self, res: u32, max_binding: u64, anisotropic: bool) -> Layout {
        let dense_fits = res <= Layout::Dense.max_res()
            && super::sparse::SparseVolume::dense_bytes(res).saturating_add(4) <= max_binding;
        match self {
            VolumeChoice::Auto if res % super::sparse::BRICK != 0 => Layout::Dense,
            VolumeChoice::Auto if dense_fits && (anisotropic || res <= SPARSE_ABOVE) => Layout::Dense,
            VolumeChoice::Auto => Layout::Sparse,
            other => other.pick(res),
        }
    }
}

impl std::str::FromStr for VolumeChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "auto" => Ok(VolumeChoice::Auto),
            "dense" => Ok(VolumeChoice::Dense),
            "sparse" => Ok(VolumeChoice::Sparse),
            other => Err(format!("unknown GI volume '{other}' (use dense, sparse or auto)")),
        }
    }
}

/// Where the GPU's cones read the dense level chain (`--gi-levels`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum LevelStore {
    /// A storage buffer filtered in the shader in f32, exactly as the CPU filters (the GPU
    /// image equals the CPU's).
    #[default]
    Buffer,
    /// A 3D texture with a mip chain (rgba16float, cells per side rounded up to a power of
    /// two), filtered by the sampler: one quadrilinear sample per cone step instead of 16
    /// fetches. GPU and dense volume only; the CPU always filters as `Buffer`.
    Texture,
}

impl std::str::FromStr for LevelStore {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "buffer" => Ok(LevelStore::Buffer),
            "texture" => Ok(LevelStore::Texture),
            other => Err(format!("unknown GI level store '{other}' (use buffer or texture)")),
        }
    }
}

/// What a GI frame can keep from the frame before (DESIGN.md, "Leave out what a scene does not
/// need").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
pub enum GiReuse {
    /// Nothing: transformation, injection and levels run.
    #[default]
    Nothing,
    /// The transformed volume (nothing moved, the lights changed): injection and levels run.
    Volume,
    /// The level chain (nothing moved, same lights): only the cones run.
    Levels,
}

impl GiReuse {
    /// One line for `--explain`.
    pub fn explain(self) -> &'static str {
        match self {
            GiReuse::Nothing => "GI: transform, inject, levels, cones (first frame, or an instance, the camera's volume or a setting changed)",
            GiReuse::Volume => "GI: volume reused (nothing moved), inject + levels again (the lights changed), cones",
            GiReuse::Levels => "GI: volume and levels reused (nothing moved, same lights), cones only",
        }
    }

    /// What to keep, given the last frame's key and lights.
    pub fn decide(last: Option<(&VolumeKey, &Lights)>, key: &VolumeKey, lights: &Lights) -> GiReuse {
        match last {
            Some((k, l)) if k == key && l == lights => GiReuse::Levels,
            Some((k, _)) if k == key => GiReuse::Volume,
            _ => GiReuse::Nothing,
        }
    }
}

/// Everything a transformed volume depends on: its placement and filter, the caches used and
/// every instance's part and world matrix. Equal keys give equal volumes.
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeKey {
    spec: VolumeSpec,
    layout: Layout,
    filter: Filter,
    caches: Vec<(PartId, u32)>,
    instances: Vec<(usize, glam::DAffine3)>,
}

impl VolumeKey {
    /// The key of `scene` moved into `spec` (stored as `layout`) with the parts' cache levels
    /// `levels_of`.
    pub fn new(scene: &Scene, spec: VolumeSpec, layout: Layout, filter: Filter, levels_of: &[u32]) -> VolumeKey {
        VolumeKey {
            spec,
            layout,
            filter,
            caches: scene.parts.iter().zip(levels_of).map(|(p, &l)| (PartId::of(p), l)).collect(),
            instances: scene.instances().iter().enumerate().map(|(i, inst)| (inst.part, scene.world(i))).collect(),
        }
    }
}

impl GiCaches {
    /// No caches yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Has `hook` told what [`prepare_light`] is doing as it goes ("injecting light into 2 M
    /// cells", "bounce 2 of 3 over 2 M cells"): on a large volume these passes take long
    /// before the first pixel, and a progress bar can show them.
    pub fn on_stage(&mut self, hook: impl Fn(&str) + Send + Sync + 'static) {
        self.stage = Some(Box::new(hook));
    }

    fn stage(&self, what: &str) {
        if let Some(h) = &self.stage {
            h(what);
        }
    }

    /// Forgets the last frame's volume and level chain (keeping the parts' caches), so the
    /// next frame runs every GI pass: for timing the whole pass, or to free the memory.
    pub fn forget_last_frame(&mut self) {
        self.last = None;
    }

    /// The cache of `svo` at `level` if it is built.
    pub fn built(&self, svo: &std::sync::Arc<crate::svo::Svo>, level: u32) -> Option<&VoxelCache> {
        self.built.get(&(PartId::of(svo), level))
    }

    /// The cache of `svo` at `level`, built on first use.
    pub fn get(&mut self, svo: &std::sync::Arc<crate::svo::Svo>, level: u32) -> Result<&VoxelCache, GiError> {
        let key = (PartId::of(svo), level);
        if !self.built.contains_key(&key) {
            // A new cache: first let go of the caches of parts that no longer exist.
            self.built.retain(|(id, _), _| id.alive());
        }
        let entry = match self.built.entry(key) {
            std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::hash_map::Entry::Vacant(e) => {
                let cache = VoxelCache::from_svo(svo, level).map_err(|e| GiError::Settings(e.to_string()))?;
                e.insert(cache)
            }
        };
        Ok(entry)
    }
}

/// The GI knobs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GiSettings {
    /// World volume cells per side.
    pub res: u32,
    /// How moved voxels are written.
    pub filter: Filter,
    /// The cones.
    pub cones: ConeSettings,
    /// Edge of the world volume (world units); None: three times the camera's distance to its
    /// target, at most the scene's size.
    pub extent: Option<f64>,
    /// Bounces of indirect light (1…MAX_BOUNCES): 1 lights the pixels with the injected
    /// direct light; each more cone-traces every occupied cell's incoming light from the
    /// previous chain into the next.
    pub bounces: u32,
    /// The world volume's layout.
    pub volume: VolumeChoice,
    /// Where the GPU's cones read the level chain (ignored on the CPU).
    pub levels: LevelStore,
    /// Where the diffuse cones are gathered: radiance caches (the default), every pixel or half
    /// resolution (both backends).
    pub gather: crate::render::Gather,
    /// Directional (six-face) coarse levels: cones read what is seen along their direction,
    /// so a wall's lit far side does not leak through its dark near side.
    pub anisotropic: bool,
    /// Emitters' soft shadows as one cone per emitter triangle through the level chain's
    /// opacity (as wide as the triangle looks from the shaded point) instead of a shadow ray
    /// per light sample: no noise, at the volume's resolution. Suns, points and spots keep
    /// their rays (they have no area), and so does the light injected into the volume.
    pub cone_shadows: bool,
    /// Points each lit cell draws on the emitters in light injection (1…1024), where the
    /// lights sample them at all. The cones average many cells, so one measured as well as
    /// four in the panel room in 0.64× the frame time (docs/lights.md).
    pub cell_light_samples: u32,
    /// With more than one bounce, the bounces left out are estimated as a geometric series
    /// and added ([`bounce_tail`]): the last bounce's light, scaled by r/(1 − r), where r (per
    /// channel) is the share of that light that meets the scene again (its cells' cones that
    /// did not escape) times the scene's mean albedo. Off, the light is that of exactly
    /// `bounces` bounces.
    pub bounce_tail: bool,
}

impl GiSettings {
    /// What the level chain made with these settings depends on besides its volume and lights
    /// (both backends reuse a chain only under the same key).
    pub(crate) fn chain_key(&self) -> ChainKey {
        let cones = if self.bounces > 1 { self.cones } else { ConeSettings::default() };
        (self.bounces, cones, self.anisotropic, self.cell_light_samples, self.tail())
    }

    /// Whether the bounces' tail is added: asked for, and past one bounce (one bounce has no
    /// last bounce's light to extend).
    pub fn tail(&self) -> bool {
        self.bounces > 1 && self.bounce_tail
    }

    /// The volume layout these settings use (anisotropic levels are built over the dense
    /// volume only, so `auto` stays dense with them).
    pub fn layout(&self) -> Layout {
        match self.volume {
            VolumeChoice::Auto if self.anisotropic => Layout::Dense,
            v => v.pick(self.res),
        }
    }
}

/// Most GI bounces.
pub const MAX_BOUNCES: u32 = 8;

impl Default for GiSettings {
    fn default() -> Self {
        GiSettings {
            res: 128,
            filter: Filter::Split,
            cones: ConeSettings::default(),
            extent: None,
            bounces: 1,
            volume: VolumeChoice::Auto,
            levels: LevelStore::Buffer,
            gather: crate::render::Gather::default(),
            anisotropic: false,
            cone_shadows: false,
            cell_light_samples: 1,
            bounce_tail: true,
        }
    }
}

impl GiSettings {
    /// Checks the knobs that do not depend on the scene.
    pub fn validated(self) -> Result<Self, GiError> {
        VolumeSpec::with_layout(self.res, DVec3::ZERO, 1.0, self.layout())?;
        self.cones.validated().map_err(|e| GiError::Settings(e.to_string()))?;
        if let crate::render::Gather::Caches(c) = self.gather {
            c.validated().map_err(GiError::Settings)?;
        }
        if !(1..=MAX_BOUNCES).contains(&self.bounces) {
            return Err(GiError::Settings(format!("bounces must be 1…{MAX_BOUNCES}, not {}", self.bounces)));
        }
        let most = crate::scene::lights::MAX_EMITTER_SAMPLES;
        if !(1..=most).contains(&self.cell_light_samples) {
            return Err(GiError::Settings(format!(
                "light samples per GI cell must be 1…{most}, not {}",
                self.cell_light_samples
            )));
        }
        if let Some(e) = self.extent.filter(|e| !(e.is_finite() && *e > 0.0)) {
            return Err(GiError::Settings(format!("volume extent {e} must be finite and positive")));
        }
        if self.anisotropic {
            if self.layout() == Layout::Sparse {
                return Err(GiError::Settings(
                    "anisotropic GI levels are built over the dense volume only: use --gi-volume dense (up to 512³) \
                     or leave out --gi-anisotropic"
                        .into(),
                ));
            }
            crate::memory::check(
                &format!("the six directional levels of an anisotropic {}³ GI chain", self.res),
                levels::aniso_extra_bytes(self.res),
                "lower the GI resolution, leave out --gi-anisotropic, or raise the memory budget",
            )?;
        }
        Ok(self)
    }
}

/// One more bounce: every occupied cell of `cells` gathers the light of `chain` (made from
/// `before`, the light per stored cell so far) over its hemisphere (cones from its centre
/// along its mean normal, the sky where they escape) and sends out its albedo times that on
/// top of its direct light `direct` (one per stored cell); returns the new light per stored
/// cell, with the sums [`bounce_tail`] estimates the bounces after it from.
fn bounce(
    cells: &dyn CellsDyn,
    direct: &[glam::Vec4],
    before: &[glam::Vec4],
    chain: &impl Chain,
    sky: glam::Vec3,
    cones: &ConeSettings,
) -> (Vec<glam::Vec4>, TailSums) {
    let out = crate::render::cpu::par_map(cells.count(), |i| {
        let c = cells.get(i);
        let (occ, n) = (c.occupancy, c.normal);
        if occ <= 0.0 || n.length_squared() <= 1e-6 {
            return (direct[i], TailSums::default());
        }
        let (light, open) = gather(chain, c.centre, n.normalize().as_dvec3(), sky, cones);
        let a = occ.min(1.0);
        let albedo = c.albedo / occ;
        let next = direct[i] + (albedo * light * a).extend(0.0);
        let added = (next - before[i]).truncate().max(Vec3::ZERO).as_dvec3();
        let sums = TailSums {
            added,
            met: added * (1.0 - open.clamp(0.0, 1.0)) as f64,
            albedo: (albedo * a).as_dvec3(),
            area: a as f64,
        };
        (next, sums)
    });
    let sums = out.iter().fold(TailSums::default(), |s, o| s.plus(&o.1));
    (out.into_iter().map(|o| o.0).collect(), sums)
}

/// What one bounce sums over the occupied cells for [`bounce_tail`] (premultiplied radiance,
/// so a cell counts as much of the scene's surface as it holds).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TailSums {
    /// The light the bounce added (its light minus the light before it).
    pub added: DVec3,
    /// That light weighted by the fraction of its cell's cones that met the scene.
    pub met: DVec3,
    /// Albedo times opacity.
    pub albedo: DVec3,
    /// Opacity (occupancy clamped to 1).
    pub area: f64,
}

impl TailSums {
    fn plus(&self, o: &TailSums) -> TailSums {
        TailSums {
            added: self.added + o.added,
            met: self.met + o.met,
            albedo: self.albedo + o.albedo,
            area: self.area + o.area,
        }
    }
}

/// Most share of a bounce's light that the tail lets the next bounce keep: the series
/// r + r² + … = r/(1 − r) stays at most 19 times the last bounce.
pub const MAX_TAIL_RATIO: f64 = 0.95;

/// The factor (per channel) the last bounce's light is scaled by to stand for every bounce
/// after it: r/(1 − r), with r = (the share of that light whose cell's cones met the scene)
/// × (the scene's mean albedo), at most [`MAX_TAIL_RATIO`]. Light that bounces again leaves
/// a cell and meets the scene where its cones do, and is sent on by the albedo where it
/// lands: the scene's mean, since the bounces after the last are not traced (progressive
/// radiosity's ambient term uses the same mean reflectance). Zero without light or surfaces.
pub fn bounce_tail(s: &TailSums) -> Vec3 {
    if !(s.area > 0.0) {
        return Vec3::ZERO;
    }
    let mean_albedo = s.albedo / s.area;
    let channel = |met: f64, added: f64, albedo: f64| {
        if !(added > 0.0) {
            return 0.0;
        }
        let r = (met / added * albedo).clamp(0.0, MAX_TAIL_RATIO);
        if r.is_finite() {
            (r / (1.0 - r)) as f32
        } else {
            0.0
        }
    };
    Vec3::new(
        channel(s.met.x, s.added.x, mean_albedo.x),
        channel(s.met.y, s.added.y, mean_albedo.y),
        channel(s.met.z, s.added.z, mean_albedo.z),
    )
}

/// Where a GI frame's time went (milliseconds) and what it did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GiStats {
    /// Caches from the SVOs (zero once every part's cache is built).
    pub caches_ms: f64,
    /// Moving the caches into the volume.
    pub transform_ms: f64,
    /// Light injection (with its shadow rays).
    pub inject_ms: f64,
    /// The level chain.
    pub levels_ms: f64,
    /// Cone tracing at the pixels (the lighting pass's gather of the ambient term).
    pub cones_ms: f64,
    /// Cache voxels moved.
    pub voxels: u64,
    /// Occupied world cells.
    pub occupied: usize,
    /// What was kept from the frame before.
    pub reuse: GiReuse,
    /// The pixels' GI light is the frame before's (the level chain kept and the same cones),
    /// so colours kept by the hit buffer stay valid.
    pub reuse_pixels: bool,
    /// The volume's layout.
    pub layout: Option<Layout>,
    /// The factor (per channel) the last bounce's light was scaled by for the bounces after
    /// it ([`bounce_tail`]); None when no tail was added.
    pub tail: Option<Vec3>,
    /// Bytes the volume's cells take (for the dense layout, all of them).
    pub volume_bytes: u64,
    /// Bytes a dense volume of the same resolution takes.
    pub dense_bytes: u64,
}

/// Where the world volume is centred: on the camera's target, moved (per axis) as far as
/// needed to take in as much of the scene's box as `extent` allows — the whole scene when it
/// fits — so a target near a wall does not leave half the volume outside the scene.
pub fn volume_centre(target: DVec3, lo: DVec3, hi: DVec3, extent: f64) -> DVec3 {
    let half = extent * 0.5;
    let axis = |t: f64, l: f64, h: f64| if h - l <= extent { (l + h) * 0.5 } else { t.clamp(l + half, h - half) };
    DVec3::new(axis(target.x, lo.x, hi.x), axis(target.y, lo.y, hi.y), axis(target.z, lo.z, hi.z))
}

/// Where this frame's world volume lies and which cache level each part uses: the volume
/// follows the camera (centred on its target, sized to what it looks at, taking in the whole
/// scene when it fits); each part's cache has voxels about one world cell in size (the part's
/// own size is the guide, as instances may scale it). Builds any cache not built yet; the CPU
/// and GPU passes both start here, so they move the same voxels into the same cells.
pub fn plan_volume(
    scene: &Scene,
    camera: &Camera,
    s: &GiSettings,
    caches: &mut GiCaches,
) -> Result<(VolumeSpec, Vec<u32>), GiError> {
    let (lo, hi) = scene.bounds();
    let scene_extent = (hi - lo).max_element() * 1.1;
    let extent = s.extent.unwrap_or_else(|| (3.0 * (camera.eye - camera.target).length()).min(scene_extent));
    if !(extent.is_finite() && extent > 0.0) {
        return Err(GiError::Settings(format!("volume extent {extent} must be finite and positive")));
    }
    let spec = VolumeSpec::following_with(volume_centre(camera.target, lo, hi, extent), extent, s.res, s.layout())?;
    let levels_of: Vec<u32> = scene
        .parts
        .iter()
        .map(|p| (p.bounds.size as f64 / spec.cell).log2().round().clamp(0.0, MAX_CACHE_DEPTH as f64) as u32)
        .collect();
    for (p, &level) in scene.parts.iter().zip(&levels_of) {
        caches.get(p, level)?;
    }
    Ok((spec, levels_of))
}

/// Makes this frame's GI light: the world volume (transformed, injected, averaged into the
/// level chain; or the last frame's, kept as [`GiReuse`] allows), left in `caches` for
/// [`GiCaches::ambient`]. The returned statistics have every time but the cones'.
pub fn prepare_light(
    scene: &Scene,
    camera: &Camera,
    lights: &Lights,
    s: &GiSettings,
    caches: &mut GiCaches,
) -> Result<GiStats, GiError> {
    let s = &s.validated()?;
    let cones = s.cones;
    let mut stats = GiStats::default();
    let t0 = Instant::now();
    let (spec, levels_of) = plan_volume(scene, camera, s, caches)?;
    let t1 = Instant::now();
    let layout = s.layout();
    let key = VolumeKey::new(scene, spec, layout, s.filter, &levels_of);
    let last = caches.last.take();
    let same_cones = last.as_ref().is_some_and(|l| l.cones == cones);
    let bounce_key = s.chain_key();
    stats.reuse = GiReuse::decide(last.as_ref().map(|l| (&l.key, &l.lights)), &key, lights);
    if stats.reuse == GiReuse::Levels && last.as_ref().is_some_and(|l| l.bounces != bounce_key) {
        stats.reuse = GiReuse::Volume;
    }
    let (vol, kept_chain) = match last {
        Some(l) if stats.reuse != GiReuse::Nothing => (l.volume, (stats.reuse == GiReuse::Levels).then_some(l.chain)),
        _ => {
            caches.stage(&format!("GI: moving {} instances' voxels into the volume", scene.instances().len()));
            let vol = match layout {
                Layout::Dense => {
                    let mut vol = Volume::new(spec);
                    for (i, inst) in scene.instances().iter().enumerate() {
                        let cache = caches.get(&scene.parts[inst.part], levels_of[inst.part])?;
                        stats.voxels += vol.splat(cache, &scene.world(i), s.filter)?.voxels;
                    }
                    WorldVolume::Dense(vol)
                }
                Layout::Sparse => {
                    let mut moves = Vec::with_capacity(scene.instances().len());
                    for (i, inst) in scene.instances().iter().enumerate() {
                        let part = &scene.parts[inst.part];
                        let cache = caches
                            .built(part, levels_of[inst.part])
                            .ok_or_else(|| GiError::Settings("a part's GI cache was not built".into()))?;
                        moves.push((cache, scene.world(i)));
                    }
                    let (vol, splat) = SparseVolume::build(spec, &moves, s.filter)?;
                    stats.voxels = splat.voxels;
                    WorldVolume::Sparse(vol)
                }
            };
            (vol, None)
        }
    };
    stats.occupied = vol.occupied();
    stats.layout = Some(layout);
    stats.volume_bytes = vol.bytes();
    stats.dense_bytes = SparseVolume::dense_bytes(spec.res);
    let t2 = Instant::now();
    let (chain, t3) = match kept_chain {
        Some(chain) => (chain, Instant::now()),
        None => {
            caches.stage(&format!("GI: injecting light into {} cells", stats.occupied));
            let (direct, _shadow_rays) = match &vol {
                WorldVolume::Dense(v) => inject_cells(v, scene, lights, s.cell_light_samples),
                WorldVolume::Sparse(v) => inject_cells(v, scene, lights, s.cell_light_samples),
            };
            let t3 = Instant::now();
            // The direct light is kept apart only when bounces add to it (at 1024³ it is hundreds
            // of MiB).
            let chain = if s.bounces > 1 {
                let mut chain = vol.chain(direct.clone(), s.anisotropic);
                let mut light = direct.clone();
                for b in 1..s.bounces {
                    caches.stage(&format!("GI: bounce {} of {} over {} cells", b + 1, s.bounces, stats.occupied));
                    let before = std::mem::take(&mut light);
                    let (next, sums) = bounce(vol.cells(), &direct, &before, &chain, lights.sky(), &cones);
                    light = next;
                    if b + 1 == s.bounces && s.tail() {
                        // The light the last bounce added, scaled, stands for the bounces after it.
                        let f = bounce_tail(&sums);
                        stats.tail = Some(f);
                        for (l, b) in light.iter_mut().zip(&before) {
                            let added = (l.truncate() - b.truncate()).max(Vec3::ZERO);
                            *l += (added * f).extend(0.0);
                        }
                    }
                    chain = vol.chain(light.clone(), s.anisotropic);
                }
                chain
            } else {
                vol.chain(direct, s.anisotropic)
            };
            (chain, t3)
        }
    };
    let t4 = Instant::now();
    // The pixels' light is the last frame's only when the chain and the cones are.
    stats.reuse_pixels = stats.reuse == GiReuse::Levels && same_cones;
    caches.last = Some(LastVolume { key, lights: lights.clone(), bounces: bounce_key, cones, volume: vol, chain });
    let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
    stats.caches_ms = ms(t0, t1);
    stats.transform_ms = ms(t1, t2);
    stats.inject_ms = ms(t2, t3);
    stats.levels_ms = ms(t3, t4);
    Ok(stats)
}

impl GiCaches {
    /// The ambient term under the light [`prepare_light`] made last (None before it), as
    /// [`crate::render::AmbientLight`] takes it, in two parts: what the diffuse cones gather
    /// at a hit (cosine-weighted, the sky where they escape; with the fraction that escaped),
    /// and the term made from that — the albedo times it, and for a glossy hit (specular
    /// reflectance ks > 0) one cone along the mirror direction as wide as its Phong lobe.
    /// Arguments: the hit's record, the world-space hit point, the primary ray's unit
    /// direction and the diffuse light.
    #[allow(clippy::type_complexity)]
    pub fn ambient(
        &self,
        lights: &Lights,
    ) -> Option<(
        impl Fn(&HitRecord, DVec3) -> (glam::Vec3, f32) + Sync + '_,
        impl Fn(&HitRecord, DVec3, DVec3, glam::Vec3, Option<glam::Vec3>) -> glam::Vec3 + Sync + '_,
        impl Fn(DVec3, DVec3, DVec3, f64) -> glam::Vec4 + Sync + '_,
        impl Fn(DVec3, DVec3, DVec3, f64, crate::gi::cone::ConeEnd) -> f32 + Sync + '_,
    )> {
        let last = self.last.as_ref()?;
        let (chain, cones, sky) = (&last.chain, last.cones, lights.sky());
        let diffuse = move |r: &HitRecord, p: DVec3| gather(chain, p, r.normal.as_dvec3(), sky, &cones);
        let term = move |r: &HitRecord, p: DVec3, d: DVec3, light: glam::Vec3, glossy: Option<glam::Vec3>| {
            let n = r.normal.as_dvec3();
            let mut ambient = r.attr.albedo_linear() * light;
            let ks = r.attr.specular();
            if ks > 0.0 && !cones.specular_cone {
                ambient += sky * ks;
            } else if let Some(g) = glossy.filter(|_| ks > 0.0) {
                // The radiance caches' lobe-sized level along the mirror direction.
                ambient += g * ks;
            } else if ks > 0.0 {
                // The specular cone: the Phong lobe's light, the sky where the cone escapes.
                let reflected = crate::render::brdf::reflect(d, n).normalize();
                let shininess = crate::render::brdf::shininess_of_gloss_bits(r.attr.gloss_bits());
                let aperture = crate::render::brdf::cone_aperture(shininess);
                let s = trace(chain, p, n, reflected, aperture, cones.max_distance);
                ambient += (s.truncate() + sky * (1.0 - s.w)) * ks;
            }
            ambient
        };
        // One cone of a radiance cache's map: its light, the sky where it escapes.
        let cone = move |o: DVec3, n: DVec3, d: DVec3, aperture: f64| {
            let s = trace(chain, o, n, d, aperture, cones.max_distance);
            (s.truncate() + sky * (1.0 - s.w)).extend(1.0 - s.w)
        };
        // A cone from a world point towards an emitter: what of it gets through.
        let shadow = move |p: DVec3, n: DVec3, d: DVec3, aperture: f64, end: crate::gi::cone::ConeEnd| {
            crate::gi::cone::visibility(chain, p, n, d, aperture, end)
        };
        Some((diffuse, term, cone, shadow))
    }
}

/// Renders one CPU frame lit with GI: [`prepare_light`], then [`crate::render::render_lit`]
/// with the cones as the ambient term (kept colours stay only where the pixels' light was
/// reused too). `cones_ms` of the statistics is the time of gathering them.
#[allow(clippy::too_many_arguments)]
pub fn render_with_gi(
    scene: &Scene,
    camera: &Camera,
    lights: &Lights,
    plan: &crate::render::FramePlan,
    opts: &crate::render::RenderOptions,
    hits: Option<&mut crate::render::HitBuffer>,
    s: &GiSettings,
    caches: &mut GiCaches,
    progress: &(dyn Fn(u32, u32) + Sync),
) -> Result<(Frame, GiStats), GiError> {
    let mut stats = prepare_light(scene, camera, lights, s, caches)?;
    let (diffuse, term, cone, shadow) =
        caches.ambient(lights).ok_or_else(|| GiError::Settings("no GI light was made".into()))?;
    let ambient = crate::render::AmbientLight {
        diffuse: &diffuse,
        term: &term,
        cone: Some(&cone),
        gather: s.gather,
        unchanged: stats.reuse_pixels,
        shadow_cone: if s.cone_shadows { Some(&shadow) } else { None },
    };
    let (frame, cones_ms) =
        crate::render::render_lit(scene, camera, lights, plan, opts, hits, Some(&ambient), progress)?;
    stats.cones_ms = cones_ms;
    Ok((frame, stats))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sums(added: f64, met: f64, albedo: f64, area: f64) -> TailSums {
        TailSums { added: DVec3::splat(added), met: DVec3::splat(met), albedo: DVec3::splat(albedo * area), area }
    }

    #[test]
    fn the_tail_is_the_geometric_series_of_what_meets_the_scene() {
        // A closed scene (every cone met something) of albedo 0.5: r = 0.5, r/(1 − r) = 1.
        assert!((bounce_tail(&sums(10.0, 10.0, 0.5, 4.0)) - Vec3::ONE).abs().max_element() < 1e-6);
        // Half of the light escapes: r = 0.25, 1/3.
        let f = bounce_tail(&sums(10.0, 5.0, 0.5, 4.0));
        assert!((f - Vec3::splat(1.0 / 3.0)).abs().max_element() < 1e-6, "{f}");
        // Per channel: a red scene sends red on.
        let s = TailSums { added: DVec3::ONE, met: DVec3::ONE, albedo: DVec3::new(0.8, 0.2, 0.0), area: 1.0 };
        let f = bounce_tail(&s);
        assert!((f - Vec3::new(4.0, 0.25, 0.0)).abs().max_element() < 1e-5, "{f}");
        // Nothing escapes and nothing is absorbed: the series diverges; it is capped.
        let most = (MAX_TAIL_RATIO / (1.0 - MAX_TAIL_RATIO)) as f32;
        assert!((bounce_tail(&sums(1.0, 1.0, 1.0, 1.0)) - Vec3::splat(most)).abs().max_element() < 1e-3);
        // An open scene adds nothing, and so do no light, no surfaces, or values that are no
        // numbers (never a NaN factor).
        assert_eq!(bounce_tail(&sums(10.0, 0.0, 0.5, 4.0)), Vec3::ZERO);
        assert_eq!(bounce_tail(&sums(0.0, 0.0, 0.5, 4.0)), Vec3::ZERO);
        assert_eq!(bounce_tail(&sums(1.0, 1.0, 0.5, 0.0)), Vec3::ZERO);
        for bad in [f64::NAN, f64::INFINITY] {
            for s in [sums(bad, 1.0, 0.5, 1.0), sums(1.0, bad, 0.5, 1.0), sums(1.0, 1.0, bad, 1.0)] {
                let f = bounce_tail(&s);
                assert!(f.is_finite() && f.min_element() >= 0.0 && f.max_element() <= most + 1e-3, "{s:?}: {f}");
            }
        }
    }
}
