//! Clustered pre-convolved radiance caching: GI's diffuse (and glossy) light evaluated at a
//! few cache points instead of at every pixel. The screen is split into tiles; in each tile
//! the pixels' normals are histogrammed over fixed directions (smoothed by a Gaussian) and up
//! to [`CacheSettings::per_tile`] dominant normals are picked, each pick damping the
//! directions near it by w ← w·(1 − |d·d_best|⁸); a cache goes to the pixel that best
//! represents each picked cluster. Each cache traces one narrow cone per texel of a small
//! hemispherical radiance map about its normal (equal-area texels; each cone a fraction,
//! [`CacheSettings::cone_percent`], of the aperture that would cover its texel's solid angle,
//! so that it reads finer levels), then pre-convolves the map: a mip pyramid whose level matches a glossy
//! lobe's width, and an irradiance map (the cosine-weighted mean of the texels about each of
//! its texels' directions). A pixel blends the caches within [`CacheSettings::radius`] tiles,
//! each weighted by the smaller of a normal-similarity and a distance weight; where none
//! applies it gathers its own cones.

use crate::scene::camera::Basis;
use crate::scene::Camera;
use glam::{DVec3, Vec3, Vec4};
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// Where caches are placed in a tile.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Placement {
    /// At the pixels representing the tile's dominant normals (the method).
    #[default]
    Clustered,
    /// On a regular grid of pixels (the baseline the clustering is weighed against).
    Even,
}

/// The radiance caches' knobs (`--gi-gather caches` and the `--gi-cache-*` options).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CacheSettings {
    /// Tile edge in pixels.
    pub tile: u32,
    /// Most caches per tile (the cache count's knob).
    pub per_tile: u32,
    /// Texels per side of a cache's hemispherical map (a power of two, 4…32).
    pub res: u32,
    /// Gathering radius in tiles.
    pub radius: u32,
    /// Clustered or evenly spaced placement.
    pub placement: Placement,
    /// Aperture of each texel's cone, in percent of the aperture whose solid angle is the
    /// texel's (5…100). Narrower cones read finer levels of the chain, whose coarse levels
    /// make thin lit surfaces glow (docs/accuracy.md, "Why the box errs"); the map's
    /// convolution still averages the texels over the hemisphere.
    pub cone_percent: u32,
}

impl Default for CacheSettings {
    fn default() -> Self {
        CacheSettings { tile: 16, per_tile: 3, res: 16, radius: 1, placement: Placement::Clustered, cone_percent: 50 }
    }
}

impl CacheSettings {
    /// Full aperture (radians) of the cone each texel of a map traces.
    pub fn cone_aperture(&self) -> f64 {
        texel_aperture(self.res as usize) * self.cone_percent as f64 / 100.0
    }

    /// Checks the knobs.
    pub fn validated(self) -> Result<Self, String> {
        // 128² pixels keep a tile's pixel index in the 16 bits the GPU's placement packs it in.
        if !(4..=128).contains(&self.tile) {
            return Err(format!("cache tile must be 4…128 pixels, not {}", self.tile));
        }
        if !(1..=16).contains(&self.per_tile) {
            return Err(format!("caches per tile must be 1…16, not {}", self.per_tile));
        }
        if !(4..=32).contains(&self.res) || !self.res.is_power_of_two() {
            return Err(format!("cache map resolution must be 4, 8, 16 or 32, not {}", self.res));
        }
        if !(1..=8).contains(&self.radius) {
            return Err(format!("cache gathering radius must be 1…8 tiles, not {}", self.radius));
        }
        if !(5..=100).contains(&self.cone_percent) {
            return Err(format!("cache cone width must be 5…100 % of a texel's, not {}", self.cone_percent));
        }
        Ok(self)
    }
}

impl std::str::FromStr for Placement {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "clustered" => Ok(Placement::Clustered),
            "even" => Ok(Placement::Even),
            other => Err(format!("unknown cache placement '{other}' (use clustered or even)")),
        }
    }
}

/// The point of the unit square `(u, v)` ∈ [0, 1]² on the unit disk (Shirley and Chiu's
/// concentric map: area-preserving up to a constant, so equal squares are equal areas).
fn square_to_disk(u: f64, v: f64) -> (f64, f64) {
    let (a, b) = (2.0 * u - 1.0, 2.0 * v - 1.0);
    if a == 0.0 && b == 0.0 {
        return (0.0, 0.0);
    }
    let (r, phi) = if a.abs() > b.abs() { (a, FRAC_PI_4 * (b / a)) } else { (b, FRAC_PI_2 - FRAC_PI_4 * (a / b)) };
    (r * phi.cos(), r * phi.sin())
}

/// The inverse of [`square_to_disk`].
fn disk_to_square(x: f64, y: f64) -> (f64, f64) {
    let r = (x * x + y * y).sqrt();
    if r == 0.0 {
        return (0.5, 0.5);
    }
    let mut phi = y.atan2(x);
    if phi < -FRAC_PI_4 {
        phi += 2.0 * PI;
    }
    let (a, b) = if phi < FRAC_PI_4 {
        (r, phi * r / FRAC_PI_4)
    } else if phi < 3.0 * FRAC_PI_4 {
        (-(phi - FRAC_PI_2) * r / FRAC_PI_4, r)
    } else if phi < 5.0 * FRAC_PI_4 {
        (-r, -(phi - PI) * r / FRAC_PI_4)
    } else {
        ((phi - 1.5 * PI) * r / FRAC_PI_4, -r)
    };
    ((a + 1.0) * 0.5, (b + 1.0) * 0.5)
}

/// The local direction (z up) of map point `(u, v)`: the disk lifted to the hemisphere with
/// z = 1 − ρ², which keeps areas, so every texel spans the same solid angle (2π / texels).
pub fn map_direction(u: f64, v: f64) -> DVec3 {
    let (x, y) = square_to_disk(u, v);
    let rho2 = (x * x + y * y).min(1.0);
    let s = (2.0 - rho2).sqrt();
    DVec3::new(x * s, y * s, 1.0 - rho2)
}

/// The map point of local unit direction `d` (z clamped to the hemisphere).
pub fn map_point(d: DVec3) -> (f64, f64) {
    let z = d.z.clamp(0.0, 1.0);
    let horizontal = (d.x * d.x + d.y * d.y).sqrt();
    // Scale the horizontal part to the disk radius ρ = √(1 − z).
    let rho = (1.0 - z).sqrt();
    let (x, y) = if horizontal > 0.0 { (d.x / horizontal * rho, d.y / horizontal * rho) } else { (0.0, 0.0) };
    disk_to_square(x, y)
}

/// One square map level: `n × n` texels, row by row.
#[derive(Clone, Debug, PartialEq)]
pub struct MapLevel {
    /// Texels per side.
    pub n: usize,
    /// Radiance (rgb) and the cones' open fraction (w).
    pub texels: Vec<Vec4>,
}

impl MapLevel {
    /// Bilinear lookup at map point `(u, v)` (texel centres at (i + ½)/n, clamped at the edges).
    pub fn lookup(&self, u: f64, v: f64) -> Vec4 {
        let n = self.n;
        let fx = (u * n as f64 - 0.5).clamp(0.0, (n - 1) as f64);
        let fy = (v * n as f64 - 0.5).clamp(0.0, (n - 1) as f64);
        let (x0, y0) = (fx.floor() as usize, fy.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(n - 1), (y0 + 1).min(n - 1));
        let (tx, ty) = ((fx - x0 as f64) as f32, (fy - y0 as f64) as f32);
        let at = |x: usize, y: usize| self.texels[y * n + x];
        let top = at(x0, y0) * (1.0 - tx) + at(x1, y0) * tx;
        let bottom = at(x0, y1) * (1.0 - tx) + at(x1, y1) * tx;
        top * (1.0 - ty) + bottom * ty
    }
}

/// A placed cache: where, facing where, and for which tile.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CachePoint {
    /// The pixel it sits on.
    pub pixel: (u32, u32),
    /// World point (the pixel's hit).
    pub point: DVec3,
    /// Unit world normal (the pixel's).
    pub normal: DVec3,
}

/// A cache's traced and pre-convolved maps.
#[derive(Clone, Debug, PartialEq)]
pub struct CacheMap {
    /// Where it sits.
    pub at: CachePoint,
    /// Tangent frame: world = t·x + b·y + normal·z.
    pub tangent: DVec3,
    /// Second tangent.
    pub bitangent: DVec3,
    /// The radiance pyramid, finest first (level 0 has `res²` texels, one cone each).
    pub mips: Vec<MapLevel>,
    /// Cosine-convolved: each texel holds the irradiance (over π) and open fraction for a
    /// normal along its direction.
    pub irradiance: MapLevel,
}

impl CacheMap {
    /// World direction → local (z along the cache's normal).
    pub fn local(&self, d: DVec3) -> DVec3 {
        DVec3::new(d.dot(self.tangent), d.dot(self.bitangent), d.dot(self.at.normal))
    }

    /// The cosine-weighted light (and open fraction) arriving at a surface with unit world
    /// normal `n` near the cache.
    pub fn irradiance(&self, n: DVec3) -> Vec4 {
        let (u, v) = map_point(self.local(n));
        self.irradiance.lookup(u, v)
    }

    /// The radiance arriving along unit world direction `d` averaged over a lobe of solid
    /// angle `omega` (steradians): the pyramid level whose texels are that size, blended
    /// between the two nearest.
    pub fn radiance(&self, d: DVec3, omega: f64) -> Vec3 {
        let texel = 2.0 * PI / (self.mips[0].n * self.mips[0].n) as f64;
        let level = (0.5 * (omega / texel).max(1.0).log2()).min((self.mips.len() - 1) as f64);
        let (u, v) = map_point(self.local(d));
        let lo = level.floor() as usize;
        let hi = (lo + 1).min(self.mips.len() - 1);
        let f = (level - lo as f64) as f32;
        let a = self.mips[lo].lookup(u, v).truncate();
        if hi == lo || f == 0.0 {
            return a;
        }
        a * (1.0 - f) + self.mips[hi].lookup(u, v).truncate() * f
    }
}

/// Full aperture (radians) of the cone whose solid angle is one texel of an `n × n` map
/// (2π / n² steradians).
pub fn texel_aperture(n: usize) -> f64 {
    let omega = 2.0 * PI / (n * n) as f64;
    2.0 * (1.0 - omega / (2.0 * PI)).clamp(-1.0, 1.0).acos()
}

/// The map's texel directions in the local frame (z along the normal), row by row.
fn texel_directions(res: usize) -> Vec<DVec3> {
    (0..res * res)
        .map(|k| map_direction(((k % res) as f64 + 0.5) / res as f64, ((k / res) as f64 + 0.5) / res as f64))
        .collect()
}

/// Traces the `res × res` texels of a cache's map with `cone(origin, normal, direction,
/// aperture)` (radiance with the sky filled in where the cone escapes, and the open fraction
/// in w), one cone of full `aperture` (radians) at each texel's centre.
pub fn trace_texels(
    at: &CachePoint,
    res: usize,
    aperture: f64,
    cone: &(dyn Fn(DVec3, DVec3, DVec3, f64) -> Vec4 + Sync),
) -> Vec<Vec4> {
    let (tangent, bitangent) = at.normal.any_orthonormal_pair();
    texel_directions(res)
        .into_iter()
        .map(|l| cone(at.point, at.normal, tangent * l.x + bitangent * l.y + at.normal * l.z, aperture))
        .collect()
}

/// Pre-convolves a traced map (`res²` texels from [`trace_texels`]): its mip pyramid and its
/// irradiance map.
pub fn convolve(at: CachePoint, res: usize, texels: &[Vec4]) -> CacheMap {
    let (tangent, bitangent) = at.normal.any_orthonormal_pair();
    let dirs = texel_directions(res);
    let mut mips = vec![MapLevel { n: res, texels: texels.to_vec() }];
    while mips.last().is_some_and(|m| m.n > 1) {
        let fine = &mips[mips.len() - 1];
        let n = fine.n / 2;
        let texels = (0..n * n)
            .map(|k| {
                let (x, y) = (2 * (k % n), 2 * (k / n));
                let t = |dx: usize, dy: usize| fine.texels[(y + dy) * fine.n + x + dx];
                (t(0, 0) + t(1, 0) + t(0, 1) + t(1, 1)) * 0.25
            })
            .collect();
        mips.push(MapLevel { n, texels });
    }
    // Irradiance at half the resolution: for each direction, the cosine-weighted mean of the
    // texels it sees (equal solid angles, so the weights are the cosines alone). What lies
    // below the cache's horizon is not in the map; normalizing by the weights seen fills it
    // with the mean of what is.
    let ni = (res / 2).max(2);
    let irradiance = texel_directions(ni)
        .into_iter()
        .map(|n| {
            let (mut sum, mut weight) = (Vec4::ZERO, 0.0f32);
            for (d, t) in dirs.iter().zip(&mips[0].texels) {
                let c = n.dot(*d) as f32;
                if c > 0.0 {
                    sum += *t * c;
                    weight += c;
                }
            }
            if weight > 0.0 {
                sum / weight
            } else {
                Vec4::ZERO
            }
        })
        .collect();
    CacheMap { at, tangent, bitangent, mips, irradiance: MapLevel { n: ni, texels: irradiance } }
}

/// [`trace_texels`] (with cones as wide as the texels) then [`convolve`].
pub fn trace_cache(at: CachePoint, res: usize, cone: &(dyn Fn(DVec3, DVec3, DVec3, f64) -> Vec4 + Sync)) -> CacheMap {
    let texels = trace_texels(&at, res, texel_aperture(res), cone);
    convolve(at, res, &texels)
}

/// Directions of the normal histogram: a Fibonacci sphere.
fn histogram_directions() -> Vec<DVec3> {
    const N: usize = 64;
    let golden = PI * (3.0 - 5f64.sqrt());
    (0..N)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / N as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * i as f64;
            DVec3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}

/// Picks up to `k` dominant normals among `normals` (each with its weight 1): a histogram
/// over fixed directions smoothed by a Gaussian, the best direction taken and the others
/// damped by w ← w·(1 − |d·d_best|⁸) before the next pick. A pick must gather at least a
/// tenth of the first's weight.
pub fn dominant_normals(normals: &[DVec3], k: usize) -> Vec<DVec3> {
    let dirs = histogram_directions();
    // Gaussian in the angle's chord: exp(−(1 − n·d) / σ²), σ² = 0.1 (about 25°).
    let mut w: Vec<f64> =
        dirs.iter().map(|d| normals.iter().map(|n| (-(1.0 - n.dot(*d)) / 0.1).exp()).sum::<f64>()).collect();
    let mut picks = Vec::new();
    let mut first = 0.0;
    for _ in 0..k {
        let Some((b, &best)) = w.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)) else { break };
        if picks.is_empty() {
            first = best;
        }
        if !(best > 0.0) || best < 0.1 * first {
            break;
        }
        let d = dirs[b];
        picks.push(d);
        for (wi, di) in w.iter_mut().zip(&dirs) {
            *wi *= 1.0 - di.dot(d).abs().powi(8);
        }
    }
    picks
}

/// Places the caches of one tile (pixels `x0..x1`, `y0..y1`): `hit(x, y)` gives the world
/// point and unit normal of a pixel to be shaded.
pub fn place_tile(
    s: &CacheSettings,
    (x0, y0, x1, y1): (u32, u32, u32, u32),
    hit: &dyn Fn(u32, u32) -> Option<(DVec3, DVec3)>,
) -> Vec<CachePoint> {
    let mut pixels = Vec::new();
    for y in y0..y1 {
        for x in x0..x1 {
            if let Some((p, n)) = hit(x, y) {
                pixels.push(((x, y), p, n));
            }
        }
    }
    if pixels.is_empty() {
        return Vec::new();
    }
    match s.placement {
        Placement::Even => {
            // A grid of per_tile cells (rounded to a square), one cache at the hit nearest
            // each cell's centre.
            let k = (s.per_tile as f64).sqrt().ceil() as u32;
            let cell = (x1 - x0).div_ceil(k).max(1);
            let mut out = Vec::new();
            for j in 0..k {
                for i in 0..k {
                    if out.len() >= s.per_tile as usize {
                        break;
                    }
                    let c = (x0 as f64 + (i as f64 + 0.5) * cell as f64, y0 as f64 + (j as f64 + 0.5) * cell as f64);
                    let inside = |&&((x, y), _, _): &&((u32, u32), DVec3, DVec3)| {
                        (x - x0) / cell == i && (y - y0).min(y1 - y0 - 1) / cell == j
                    };
                    let best = pixels.iter().filter(inside).min_by(|a, b| {
                        let d = |q: &((u32, u32), DVec3, DVec3)| {
                            (q.0 .0 as f64 - c.0).powi(2) + (q.0 .1 as f64 - c.1).powi(2)
                        };
                        d(a).total_cmp(&d(b))
                    });
                    if let Some(&(pixel, point, normal)) = best {
                        out.push(CachePoint { pixel, point, normal });
                    }
                }
            }
            out
        }
        Placement::Clustered => {
            let normals: Vec<DVec3> = pixels.iter().map(|p| p.2).collect();
            let picks = dominant_normals(&normals, s.per_tile as usize);
            let mut out = Vec::new();
            for (c, d) in picks.iter().enumerate() {
                // The cluster: pixels whose normal is nearest this pick (and within 60° of it).
                let members: Vec<&((u32, u32), DVec3, DVec3)> = pixels
                    .iter()
                    .filter(|p| {
                        let own = p.2.dot(*d);
                        own > 0.5 && picks.iter().enumerate().all(|(o, e)| o == c || p.2.dot(*e) <= own)
                    })
                    .collect();
                if members.is_empty() {
                    continue;
                }
                let mean = members.iter().fold(DVec3::ZERO, |a, p| a + p.2).normalize_or(*d);
                let centre = members.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0 .0 as f64, a.1 + p.0 .1 as f64));
                let centre = (centre.0 / members.len() as f64, centre.1 / members.len() as f64);
                let tile = (x1 - x0).max(1) as f64;
                // The representative: a normal close to the cluster's mean, near its centre.
                let score = |p: &((u32, u32), DVec3, DVec3)| {
                    let dist = ((p.0 .0 as f64 - centre.0).powi(2) + (p.0 .1 as f64 - centre.1).powi(2)).sqrt();
                    p.2.dot(mean) - 0.5 * dist / tile
                };
                if let Some(best) = members.iter().max_by(|a, b| score(a).total_cmp(&score(b))) {
                    out.push(CachePoint { pixel: best.0, point: best.1, normal: best.2 });
                }
            }
            out
        }
    }
}

/// Smallest cosine between a pixel's normal and a cache's that it blends (about 25°), and
/// where the normal weight starts falling from 1.
const NORMAL_FLOOR: f64 = 0.9;

/// The caches of one frame, indexed by tile.
pub struct FrameCaches {
    /// Tile edge in pixels and tiles per row and column.
    pub tile: u32,
    /// Tiles per row.
    pub tiles_x: u32,
    /// Tiles per column.
    pub tiles_y: u32,
    /// First cache of each tile in `maps` (a prefix sum of the per-tile counts), one more at
    /// the end.
    pub first: Vec<u32>,
    /// The caches, tile by tile.
    pub maps: Vec<CacheMap>,
}

/// Where one frame's cache gather spent its time (milliseconds).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
pub struct CacheStages {
    /// Clustering the G-buffer and placing the caches.
    pub placement_ms: f64,
    /// Tracing the caches' texel cones.
    pub tracing_ms: f64,
    /// Building the mips and irradiance maps.
    pub convolution_ms: f64,
    /// Blending the caches at the pixels (with the fallback gathers).
    pub gathering_ms: f64,
    /// Caches placed.
    pub caches: u64,
}

/// Places and traces the caches of a frame. `hit(x, y)` is a pixel's world point and unit
/// normal when it is to be shaded.
pub fn build(
    s: &CacheSettings,
    camera: &Camera,
    hit: &(dyn Fn(u32, u32) -> Option<(DVec3, DVec3)> + Sync),
    cone: &(dyn Fn(DVec3, DVec3, DVec3, f64) -> Vec4 + Sync),
    stages: &mut CacheStages,
) -> FrameCaches {
    let t0 = std::time::Instant::now();
    let (w, h) = (camera.width, camera.height);
    let (tiles_x, tiles_y) = (w.div_ceil(s.tile), h.div_ceil(s.tile));
    let per_tile: Vec<Vec<CachePoint>> = super::cpu::par_map((tiles_x * tiles_y) as usize, |t| {
        let (tx, ty) = (t as u32 % tiles_x, t as u32 / tiles_x);
        let rect = (tx * s.tile, ty * s.tile, ((tx + 1) * s.tile).min(w), ((ty + 1) * s.tile).min(h));
        place_tile(s, rect, hit)
    });
    // The cache list: a prefix sum of the tiles' counts.
    let mut first = Vec::with_capacity(per_tile.len() + 1);
    let mut total = 0u32;
    for t in &per_tile {
        first.push(total);
        total += t.len() as u32;
    }
    first.push(total);
    let points: Vec<CachePoint> = per_tile.into_iter().flatten().collect();
    let t1 = std::time::Instant::now();
    let (res, aperture) = (s.res as usize, s.cone_aperture());
    let texels = super::cpu::par_map(points.len(), |i| trace_texels(&points[i], res, aperture, cone));
    let t2 = std::time::Instant::now();
    let maps = super::cpu::par_map(points.len(), |i| convolve(points[i], res, &texels[i]));
    let t3 = std::time::Instant::now();
    let ms = |a: std::time::Instant, b: std::time::Instant| (b - a).as_secs_f64() * 1e3;
    stages.placement_ms = ms(t0, t1);
    stages.tracing_ms = ms(t1, t2);
    stages.convolution_ms = ms(t2, t3);
    stages.caches = maps.len() as u64;
    FrameCaches { tile: s.tile, tiles_x, tiles_y, first, maps }
}

impl FrameCaches {
    /// Calls `f(cache, weight)` for every cache of the tiles within `radius` of pixel (x, y)
    /// whose weight at world point `p` with unit normal `n` is positive (`footprint`: world
    /// units per pixel at its depth): the smaller of the normal and the distance weight.
    #[allow(clippy::too_many_arguments)]
    fn near(&self, radius: u32, x: u32, y: u32, p: DVec3, n: DVec3, footprint: f64, mut f: impl FnMut(&CacheMap, f64)) {
        let (tx, ty) = (x / self.tile, y / self.tile);
        let reach = radius as f64 * self.tile as f64 * footprint;
        for jy in ty.saturating_sub(radius)..(ty + radius + 1).min(self.tiles_y) {
            for jx in tx.saturating_sub(radius)..(tx + radius + 1).min(self.tiles_x) {
                let t = (jy * self.tiles_x + jx) as usize;
                for c in &self.maps[self.first[t] as usize..self.first[t + 1] as usize] {
                    let wn = ((n.dot(c.at.normal) - NORMAL_FLOOR) / (1.0 - NORMAL_FLOOR)).clamp(0.0, 1.0);
                    let wd = (1.0 - (c.at.point - p).length() / reach).clamp(0.0, 1.0);
                    let wc = wn.min(wd);
                    if wc > 0.0 {
                        f(c, wc);
                    }
                }
            }
        }
    }

    /// The caches' blend at a pixel (x, y) with world point `p` and unit normal `n`, a pixel's
    /// footprint `footprint` (world units per pixel at its depth): the cosine-weighted light
    /// and open fraction, and the caches' total weight (0: none applies). The caches within
    /// `radius` tiles, or where none applies within `radius + 1` (a surface seen at a grazing
    /// angle, whose caches lie farther apart than its pixels): the pixel's own cones are
    /// dearer and, wide, err more than a farther cache.
    pub fn blend(&self, radius: u32, x: u32, y: u32, p: DVec3, n: DVec3, footprint: f64) -> (Vec4, f64) {
        let near = self.blend_within(radius, x, y, p, n, footprint);
        if near.1 > 0.0 {
            return near;
        }
        self.blend_within(radius + 1, x, y, p, n, footprint)
    }

    /// [`Self::blend`] over the caches within `radius` tiles alone.
    fn blend_within(&self, radius: u32, x: u32, y: u32, p: DVec3, n: DVec3, footprint: f64) -> (Vec4, f64) {
        let (mut sum, mut weight) = (Vec4::ZERO, 0.0f64);
        self.near(radius, x, y, p, n, footprint, |c, wc| {
            sum += c.irradiance(n) * wc as f32;
            weight += wc;
        });
        (if weight > 0.0 { sum / weight as f32 } else { Vec4::ZERO }, weight)
    }

    /// The caches' glossy light at a pixel along unit world direction `d` over a lobe of
    /// `omega` steradians (None where no cache applies or `d` is below every near cache's
    /// horizon), from the caches within `radius` tiles or, where none applies, `radius + 1`
    /// (as [`Self::blend`]).
    #[allow(clippy::too_many_arguments)]
    pub fn glossy(
        &self,
        radius: u32,
        x: u32,
        y: u32,
        p: DVec3,
        n: DVec3,
        footprint: f64,
        d: DVec3,
        omega: f64,
    ) -> Option<Vec3> {
        self.glossy_within(radius, x, y, p, n, footprint, d, omega)
            .or_else(|| self.glossy_within(radius + 1, x, y, p, n, footprint, d, omega))
    }

    /// [`Self::glossy`] over the caches within `radius` tiles alone.
    #[allow(clippy::too_many_arguments)]
    fn glossy_within(
        &self,
        radius: u32,
        x: u32,
        y: u32,
        p: DVec3,
        n: DVec3,
        footprint: f64,
        d: DVec3,
        omega: f64,
    ) -> Option<Vec3> {
        let (mut sum, mut weight) = (Vec3::ZERO, 0.0f64);
        self.near(radius, x, y, p, n, footprint, |c, wc| {
            if d.dot(c.at.normal) > 0.0 {
                sum += c.radiance(d, omega) * wc as f32;
                weight += wc;
            }
        });
        (weight > 0.0).then(|| sum / weight as f32)
    }
}

/// A pixel's world footprint: the width of one pixel at ray parameter `t`.
pub fn footprint(camera: &Camera, basis: &Basis, t: f64) -> f64 {
    t * 2.0 * basis.tan_half / camera.height as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_map_round_trips_and_covers_the_hemisphere() {
        for k in 0..400 {
            let (u, v) = ((k % 20) as f64 / 19.0, (k / 20) as f64 / 19.0);
            let d = map_direction(u, v);
            assert!((d.length() - 1.0).abs() < 1e-12 && d.z >= -1e-12, "{d:?}");
            let (u2, v2) = map_point(d);
            // The square's corners and edges meet the horizon, where φ decides the side.
            if d.z > 1e-9 {
                assert!((u - u2).abs() < 1e-9 && (v - v2).abs() < 1e-9, "({u}, {v}) → {d:?} → ({u2}, {v2})");
            }
        }
        assert!((map_direction(0.5, 0.5) - DVec3::Z).length() < 1e-12);
    }

    #[test]
    fn texels_span_equal_solid_angles() {
        // Monte Carlo over the hemisphere: each texel of a 4×4 map receives a sixteenth of
        // uniformly spread directions.
        let n = 4;
        let mut count = vec![0u32; n * n];
        let mut rng = crate::rng::Rng::new(7);
        let samples = 160_000;
        for _ in 0..samples {
            let z = rng.f64();
            let phi = 2.0 * PI * rng.f64();
            let r = (1.0 - z * z).sqrt();
            let (u, v) = map_point(DVec3::new(r * phi.cos(), r * phi.sin(), z));
            let (i, j) = (((u * n as f64) as usize).min(n - 1), ((v * n as f64) as usize).min(n - 1));
            count[j * n + i] += 1;
        }
        let expected = samples as f64 / (n * n) as f64;
        for c in count {
            assert!((c as f64 - expected).abs() < 0.05 * expected, "{c} of {expected}");
        }
    }

    #[test]
    fn texel_cones_are_as_wide_as_the_knob_asks_and_the_knob_is_checked() {
        let at = CachePoint { pixel: (0, 0), point: DVec3::ZERO, normal: DVec3::Z };
        for percent in [100u32, 25] {
            let s = CacheSettings { cone_percent: percent, ..CacheSettings::default() };
            let seen = std::sync::Mutex::new(Vec::new());
            let texels = trace_texels(&at, s.res as usize, s.cone_aperture(), &|_, _, _, a| {
                seen.lock().unwrap().push(a);
                Vec4::ZERO
            });
            let seen = seen.into_inner().unwrap();
            assert_eq!((texels.len(), seen.len()), (256, 256));
            let want = texel_aperture(16) * percent as f64 / 100.0;
            assert!(seen.iter().all(|&a| (a - want).abs() < 1e-12), "{} against {want}", seen[0]);
        }
        for bad in [0u32, 4, 101] {
            assert!(CacheSettings { cone_percent: bad, ..CacheSettings::default() }.validated().is_err());
        }
    }

    /// A pixel with no cache within the radius borrows from one tile farther, and from no
    /// farther: a 4×1 row of 16-pixel tiles with one cache in the first, one pixel per world
    /// unit.
    #[test]
    fn a_pixel_without_a_near_cache_widens_the_radius_once() {
        let env = Vec4::new(0.5, 0.25, 1.0, 0.8);
        let at = CachePoint { pixel: (8, 8), point: DVec3::new(8.0, 8.0, 0.0), normal: DVec3::Z };
        let caches = FrameCaches {
            tile: 16,
            tiles_x: 4,
            tiles_y: 1,
            first: vec![0, 1, 1, 1, 1],
            maps: vec![trace_cache(at, 8, &|_, _, _, _| env)],
        };
        let at_pixel = |x: u32| {
            let (e, w) = caches.blend(1, x, 8, DVec3::new(x as f64, 8.0, 0.0), DVec3::Z, 1.0);
            let g = caches.glossy(1, x, 8, DVec3::new(x as f64, 8.0, 0.0), DVec3::Z, 1.0, DVec3::Z, 0.1);
            (w > 0.0, (e - env).abs().max_element() < 1e-5, g.is_some())
        };
        // Tile 1 is within one tile; tile 2 within two (widened); tile 3 within neither.
        assert_eq!(at_pixel(20), (true, true, true));
        assert_eq!(at_pixel(36), (true, true, true));
        assert_eq!(at_pixel(52), (false, false, false));
        assert_eq!(caches.blend_within(1, 36, 8, DVec3::new(36.0, 8.0, 0.0), DVec3::Z, 1.0).1, 0.0);
    }

    #[test]
    fn a_uniform_environment_gives_its_radiance_at_every_normal_and_lobe() {
        let at = CachePoint { pixel: (0, 0), point: DVec3::ZERO, normal: DVec3::new(0.3, 0.9, 0.1).normalize() };
        let env = Vec4::new(0.2, 0.5, 1.5, 0.75);
        let map = trace_cache(at, 16, &|_, _, _, _| env);
        for n in [at.normal, DVec3::Y, DVec3::new(0.5, 0.8, 0.0).normalize()] {
            let e = map.irradiance(n);
            assert!((e - env).abs().max_element() < 1e-5, "{e:?}");
        }
        for omega in [0.001, 0.1, 1.0, 6.0] {
            let r = map.radiance(DVec3::Y, omega);
            assert!((r - env.truncate()).abs().max_element() < 1e-5, "{r:?}");
        }
    }

    #[test]
    fn irradiance_is_the_cosine_weighted_mean_of_the_map() {
        // Light from one side only: the irradiance for the cache's own normal equals the
        // cosine-weighted fraction of the hemisphere that is lit (half of it: 0.5).
        let at = CachePoint { pixel: (0, 0), point: DVec3::ZERO, normal: DVec3::Z };
        let map = trace_cache(at, 32, &|_, _, d, _| if d.x > 0.0 { Vec4::new(1.0, 1.0, 1.0, 1.0) } else { Vec4::ZERO });
        let e = map.irradiance(DVec3::Z);
        assert!((e.x - 0.5).abs() < 0.02, "{e:?}");
        // Tilted towards the light, more of it.
        let tilted = map.irradiance(DVec3::new(0.4, 0.0, 0.9).normalize());
        assert!(tilted.x > e.x + 0.1, "{tilted:?} vs {e:?}");
    }

    #[test]
    fn clustering_finds_the_faces_of_a_corner() {
        // A tile showing three faces of a box corner, unequal in area.
        let faces = [DVec3::X, DVec3::Y, DVec3::Z];
        let mut normals = Vec::new();
        for (k, f) in faces.iter().enumerate() {
            normals.extend(std::iter::repeat_n(*f, 40 + 30 * k));
        }
        let picks = dominant_normals(&normals, 3);
        assert_eq!(picks.len(), 3);
        for f in faces {
            assert!(picks.iter().any(|p| p.dot(f) > 0.95), "{f:?} not among {picks:?}");
        }
        // Placed in a tile: one cache per face, each on a pixel of its face.
        let s = CacheSettings::default();
        let corner = |x: u32, y: u32| {
            let n = if x < 6 {
                DVec3::X
            } else if y < 5 {
                DVec3::Y
            } else {
                DVec3::Z
            };
            Some((DVec3::new(x as f64, y as f64, 0.0), n))
        };
        let caches = place_tile(&s, (0, 0, 16, 16), &corner);
        assert_eq!(caches.len(), 3, "{caches:?}");
        for c in &caches {
            assert_eq!(corner(c.pixel.0, c.pixel.1).map(|h| h.1), Some(c.normal));
        }
        // One face: one cache (picks near the first gather no pixels of their own).
        let flat = place_tile(&s, (0, 0, 16, 16), &|x, y| Some((DVec3::new(x as f64, y as f64, 0.0), DVec3::Y)));
        assert_eq!(flat.len(), 1);
        // Even placement: the grid, whatever the normals.
        let even = CacheSettings { placement: Placement::Even, per_tile: 4, ..s };
        assert_eq!(place_tile(&even, (0, 0, 16, 16), &corner).len(), 4);
        assert!(place_tile(&s, (0, 0, 16, 16), &|_, _| None).is_empty());
    }
}
