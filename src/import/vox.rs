//! MagicaVoxel `.vox` through the `dot_vox` crate: every model goes straight to an SVO, one
//! voxel per `.vox` voxel (no triangles, no voxelization), and the scene graph's transforms
//! become a [`Rig`]:
//!
//! - A model's voxel (x, y, z) fills [v − ⌊size/2⌋, v − ⌊size/2⌋ + 1) in its shape's space
//!   (MagicaVoxel centres a model on its transform); one `.vox` voxel is one scene unit.
//! - A transform node (`nTRN`) is a rig node with its translation `_t` and signed permutation
//!   `_r` (a rotation, or a mirror); its shape (`nSHP`) makes it place a part. Groups
//!   (`nGRP`) are nodes without geometry. Hidden nodes and layers are left out.
//! - MagicaVoxel's z is up; a root node turns the scene so that y is up, as voxray's scenes are.
//! - Animation (flip-book): a shape listing several models by frame (`_f`) swaps between them,
//!   and a transform with several frames steps between them, at [`FRAMES_PER_SECOND`].
//! - Palette colours (sRGB) are the albedo. Materials: `_emit` gives emission = colour ·
//!   `_emit` · (1 + `_flux`); `_metal` gives a specular lobe of reflectance `_metal` (the
//!   albedo keeps 1 − `_metal`) with glossiness 1 − `_rough`.
//! - A voxel's normal is the mean of its open faces' directions (zero for buried voxels).
//!
//! The parser panics on some malformed input (an invalid rotation byte); `_r` is decoded
//! here instead, and any panic left in the parser is caught and reported as an error.

use super::ImportError;
use crate::scene::animation::{decompose, Channel, Clip, Interpolation, Node, Property, Rest, Rig};
use crate::svo::format::morton_encode;
use crate::svo::{Cube, Svo};
use crate::voxelize::{Voxel, VoxelGrid};
use glam::{DAffine3, DMat3, DQuat, DVec3, Vec3};
use std::path::Path;

/// Largest `.vox` file read.
pub const MAX_VOX_BYTES: u64 = 512 << 20;
/// Largest model edge read (MagicaVoxel itself makes at most 256).
pub const MAX_MODEL_SIZE: u32 = 1024;
/// Playback rate of `.vox` animation frames (the file does not store one).
pub const FRAMES_PER_SECOND: f64 = 10.0;
/// Memory one voxel takes while its SVO is built (sorting, levels, the tree).
const BYTES_PER_VOXEL: u64 = 96;

/// A `.vox` file's models as SVOs and its scene graph as a rig: node `k` with
/// `part: Some(p)` places `svos[p]`.
pub struct VoxScene {
    /// One SVO per model.
    pub svos: Vec<Svo>,
    /// Model names ("model N").
    pub names: Vec<String>,
    /// The scene graph and its flip-book clip.
    pub rig: Rig,
    /// Non-fatal problems.
    pub warnings: Vec<String>,
}

fn invalid(path: &Path, element: impl Into<String>, message: impl std::fmt::Display) -> ImportError {
    ImportError::Invalid { path: path.display().to_string(), element: element.into(), message: message.to_string() }
}

fn srgb_to_linear(c: u8) -> f32 {
    crate::mesh::srgb_to_linear(c as f32 / 255.0)
}

/// The signed permutation of a `_r` byte, or None when it is not one.
pub fn rotation_of_byte(b: u8) -> Option<DMat3> {
    let (first, second) = ((b & 3) as usize, ((b >> 2) & 3) as usize);
    if first == second || first > 2 || second > 2 || b >> 7 != 0 {
        return None;
    }
    let third = 3 - first - second;
    let mut rows = [[0.0f64; 3]; 3];
    for (r, col) in [first, second, third].into_iter().enumerate() {
        rows[r][col] = if b & (1 << (4 + r)) != 0 { -1.0 } else { 1.0 };
    }
    Some(DMat3::from_cols_array_2d(&rows).transpose())
}

/// A frame's transform: `_t` "x y z" and `_r` byte (both optional).
fn frame_transform(path: &Path, element: &str, attrs: &dot_vox::Dict) -> Result<DAffine3, ImportError> {
    let t = match attrs.get("_t") {
        None => DVec3::ZERO,
        Some(s) => {
            let v: Vec<f64> = s.split_whitespace().filter_map(|x| x.parse::<i64>().ok()).map(|x| x as f64).collect();
            if v.len() != 3 || v.iter().any(|x| x.abs() > 1e9) {
                return Err(invalid(path, element, format!("translation '_t' \"{s}\" is not three integers")));
            }
            DVec3::new(v[0], v[1], v[2])
        }
    };
    let r = match attrs.get("_r") {
        None => DMat3::IDENTITY,
        Some(s) => s
            .trim()
            .parse::<u8>()
            .ok()
            .and_then(rotation_of_byte)
            .ok_or_else(|| invalid(path, element, format!("rotation '_r' \"{s}\" is not a signed permutation")))?,
    };
    Ok(DAffine3 { matrix3: r, translation: t })
}

fn frame_index(attrs: &dot_vox::Dict) -> u32 {
    attrs.get("_f").and_then(|f| f.trim().parse().ok()).unwrap_or(0)
}

/// Loads a `.vox` file.
pub fn load(path: &Path) -> Result<VoxScene, ImportError> {
    load_with_progress(path, &|_, _| {})
}

/// [`load`], calling `progress(models built, models)` as each model's SVO is done.
pub fn load_with_progress(path: &Path, progress: &dyn Fn(usize, usize)) -> Result<VoxScene, ImportError> {
    let bytes = crate::input::read_limited(path, MAX_VOX_BYTES, "a MagicaVoxel file")?;
    let parsed = std::panic::catch_unwind(|| dot_vox::load_bytes(&bytes));
    let data = match parsed {
        Ok(Ok(d)) => d,
        Ok(Err(e)) => return Err(invalid(path, "file", e)),
        Err(_) => return Err(invalid(path, "file", "the MagicaVoxel parser failed on malformed data")),
    };
    drop(bytes);
    if data.models.is_empty() {
        return Err(invalid(path, "file", "holds no model"));
    }
    let total: u64 = data.models.iter().map(|m| m.voxels.len() as u64).sum();
    crate::memory::check(
        &format!("{}: {} models of {total} voxels", path.display(), data.models.len()),
        total * BYTES_PER_VOXEL,
        "raise the memory budget",
    )
    .map_err(|e| invalid(path, "file", e))?;

    // Per palette index (the voxel's, 0-based): albedo, emission, specular, gloss.
    let mut looks = [(Vec3::splat(0.5), Vec3::ZERO, 0.0f32, 0.0f32); 256];
    for (i, look) in looks.iter_mut().enumerate() {
        let c = data.palette.get(i).copied().unwrap_or(dot_vox::Color { r: 128, g: 128, b: 128, a: 255 });
        let colour = Vec3::new(srgb_to_linear(c.r), srgb_to_linear(c.g), srgb_to_linear(c.b));
        *look = (colour, Vec3::ZERO, 0.0, 0.0);
        // Material ids count palette entries from 1, as the file's voxel indices do.
        let Some(m) = data.materials.iter().find(|m| m.id as usize == i + 1) else { continue };
        let num = |k: &str| m.properties.get(k).and_then(|v| v.trim().parse::<f32>().ok()).filter(|v| v.is_finite());
        match m.properties.get("_type").map(String::as_str) {
            Some("_emit") => {
                let e =
                    num("_emit").unwrap_or(0.0).clamp(0.0, 1e4) * (1.0 + num("_flux").unwrap_or(0.0).clamp(0.0, 16.0));
                look.1 = colour * e;
            }
            Some("_metal") => {
                let metal = num("_metal").unwrap_or(0.0).clamp(0.0, 1.0);
                look.0 = colour * (1.0 - metal);
                look.2 = metal.min(1.0 - look.0.max_element());
                look.3 = 1.0 - num("_rough").unwrap_or(0.5).clamp(0.0, 1.0);
            }
            _ => {}
        }
    }

    let mut svos = Vec::with_capacity(data.models.len());
    for (k, m) in data.models.iter().enumerate() {
        let element = format!("model {k}");
        let size = [m.size.x, m.size.y, m.size.z];
        if size.iter().any(|&s| s == 0 || s > MAX_MODEL_SIZE) {
            return Err(invalid(path, element, format!("size {size:?} is not 1…{MAX_MODEL_SIZE} per axis")));
        }
        if m.voxels.is_empty() {
            return Err(invalid(path, element, "has no voxels"));
        }
        let depth = size.iter().max().copied().unwrap_or(1).next_power_of_two().trailing_zeros().max(1);
        let half = size.map(|s| (s / 2) as f32);
        // Occupancy as one bit per cell of the model's box (at most 128 MiB at 1024³): the
        // normals look up six neighbours of every voxel.
        let cells = size.iter().map(|&s| s as u64).product::<u64>();
        crate::memory::check(
            &format!("{}: {element}'s occupancy", path.display()),
            cells / 4,
            "raise the memory budget",
        )
        .map_err(|e| invalid(path, &element, e))?;
        let index =
            |c: [u32; 3]| (c[0] as u64 + size[0] as u64 * (c[1] as u64 + size[1] as u64 * c[2] as u64)) as usize;
        let mut occupied = vec![0u64; (cells as usize).div_ceil(64)];
        for v in &m.voxels {
            let c = [v.x as u32, v.y as u32, v.z as u32];
            if c.iter().zip(size).any(|(&c, s)| c >= s) {
                return Err(invalid(path, &element, format!("voxel {c:?} lies outside its size {size:?}")));
            }
            let k = index(c);
            occupied[k / 64] |= 1 << (k % 64);
        }
        let is_set = |bits: &[u64], c: [u32; 3]| {
            let k = index(c);
            bits[k / 64] & (1 << (k % 64)) != 0
        };
        let mut seen = vec![0u64; occupied.len()];
        let mut voxels: Vec<Voxel> = Vec::with_capacity(m.voxels.len());
        for v in &m.voxels {
            let c = [v.x as u32, v.y as u32, v.z as u32];
            let k = index(c);
            if seen[k / 64] & (1 << (k % 64)) != 0 {
                continue; // the first of duplicate voxels stands
            }
            seen[k / 64] |= 1 << (k % 64);
            let mut normal = Vec3::ZERO;
            for axis in 0..3 {
                let below = c[axis] == 0 || {
                    let mut n = c;
                    n[axis] -= 1;
                    !is_set(&occupied, n)
                };
                let above = c[axis] + 1 >= size[axis] || {
                    let mut n = c;
                    n[axis] += 1;
                    !is_set(&occupied, n)
                };
                normal[axis] = above as i32 as f32 - below as i32 as f32;
            }
            let (albedo, emission, specular, gloss) = looks[v.i as usize];
            voxels.push(Voxel {
                code: morton_encode(c[0], c[1], c[2]),
                albedo,
                normal: normal.normalize_or_zero(),
                emission,
                specular,
                gloss,
                weight: 1.0,
            });
        }
        voxels.sort_unstable_by_key(|v| v.code);
        let grid = VoxelGrid {
            depth,
            bounds: Cube { min: Vec3::from(half.map(|h| -h)), size: (1u64 << depth) as f32 },
            voxels,
            emitters: Vec::new(),
        };
        svos.push(crate::svo::build(&grid).map_err(|e| invalid(path, &element, e))?);
        progress(svos.len(), data.models.len());
    }
    let names = (0..svos.len()).map(|k| format!("model {k}")).collect();

    let mut rig = Rig::default();
    let mut warnings = Vec::new();
    // MagicaVoxel is z-up: turn x, y, z into x, z, −y.
    rig.nodes.push(Node {
        name: "z-up to y-up".into(),
        parent: None,
        rest: Rest::Trs(DVec3::ZERO, DQuat::from_rotation_x(-std::f64::consts::FRAC_PI_2), DVec3::ONE),
        part: None,
    });
    let mut channels = Vec::new();
    if data.scenes.is_empty() {
        for k in 0..svos.len() {
            rig.nodes.push(Node {
                name: format!("model {k}"),
                parent: Some(0),
                rest: Rest::Matrix(DAffine3::IDENTITY),
                part: Some(k),
            });
        }
    } else {
        let hidden_layers: Vec<bool> = data.layers.iter().map(|l| l.hidden()).collect();
        let mut stack: Vec<(u32, usize)> = vec![(0, 0)];
        let mut visits = 0usize;
        while let Some((id, parent)) = stack.pop() {
            visits += 1;
            if visits > data.scenes.len() {
                return Err(invalid(path, "scene graph", "a node is reached twice (a cycle or a shared child)"));
            }
            let element = format!("scene node {id}");
            let node = data.scenes.get(id as usize).ok_or_else(|| invalid(path, &element, "does not exist"))?;
            use dot_vox::SceneNode;
            match node {
                SceneNode::Transform { attributes, frames, child, layer_id } => {
                    let hidden = attributes.get("_hidden").is_some_and(|h| h.trim() == "1")
                        || hidden_layers.get(*layer_id as usize).copied().unwrap_or(false);
                    if hidden {
                        continue;
                    }
                    let name = attributes.get("_name").map_or_else(|| element.clone(), |n| format!("'{n}'"));
                    let mut keyed: Vec<(u32, DAffine3)> = Vec::new();
                    for f in frames {
                        keyed.push((frame_index(&f.attributes), frame_transform(path, &element, &f.attributes)?));
                    }
                    keyed.sort_by_key(|k| k.0);
                    keyed.dedup_by_key(|k| k.0);
                    let first = keyed.first().map_or(DAffine3::IDENTITY, |k| k.1);
                    let k = rig.nodes.len();
                    let rest = if keyed.len() > 1 {
                        let trs = |m: &DAffine3| {
                            decompose(m).ok_or_else(|| {
                                invalid(path, &element, "a frame's transform is not a rotation or mirror")
                            })
                        };
                        let t0 = trs(&first)?;
                        let times: Vec<f64> = keyed.iter().map(|k| k.0 as f64 / FRAMES_PER_SECOND).collect();
                        let mut values = [Vec::new(), Vec::new(), Vec::new()];
                        for (_, m) in &keyed {
                            let t = trs(m)?;
                            values[0].push([t.translation.x, t.translation.y, t.translation.z, 0.0]);
                            values[1].push(t.rotation.to_array());
                            values[2].push([t.scale.x, t.scale.y, t.scale.z, 0.0]);
                        }
                        for (property, values) in
                            [Property::Translation, Property::Rotation, Property::Scale].into_iter().zip(values)
                        {
                            channels.push(Channel {
                                node: k,
                                property,
                                interpolation: Interpolation::Step,
                                times: times.clone(),
                                values,
                            });
                        }
                        Rest::Trs(t0.translation, t0.rotation, t0.scale)
                    } else {
                        Rest::Matrix(first)
                    };
                    rig.nodes.push(Node { name, parent: Some(parent), rest, part: None });
                    stack.push((*child, k));
                }
                SceneNode::Group { children, .. } => {
                    for c in children.iter().rev() {
                        stack.push((*c, parent));
                    }
                }
                SceneNode::Shape { models, .. } => {
                    let mut frames: Vec<(u32, usize)> = Vec::new();
                    for m in models {
                        let id = m.model_id as usize;
                        if id >= svos.len() {
                            return Err(invalid(path, &element, format!("refers to model {id} of {}", svos.len())));
                        }
                        frames.push((frame_index(&m.attributes), id));
                    }
                    frames.sort_by_key(|f| f.0);
                    frames.dedup_by_key(|f| f.0);
                    let Some(&(_, first)) = frames.first() else {
                        warnings.push(format!("{element}: a shape without models"));
                        continue;
                    };
                    if rig.nodes[parent].part.is_some() {
                        return Err(invalid(path, &element, "a transform with two shapes"));
                    }
                    rig.nodes[parent].part = Some(first);
                    if frames.len() > 1 {
                        channels.push(Channel {
                            node: parent,
                            property: Property::Part,
                            interpolation: Interpolation::Step,
                            times: frames.iter().map(|f| f.0 as f64 / FRAMES_PER_SECOND).collect(),
                            values: frames.iter().map(|f| [f.1 as f64, 0.0, 0.0, 0.0]).collect(),
                        });
                    }
                }
            }
        }
    }
    if !rig.nodes.iter().any(|n| n.part.is_some()) {
        return Err(invalid(path, "scene graph", "shows no model (all hidden?)"));
    }
    if !channels.is_empty() {
        // The last frame holds for one frame's time before the loop starts over.
        let mut clip = Clip::new("frames".into(), channels);
        clip.duration += 1.0 / FRAMES_PER_SECOND;
        rig.clips.push(clip);
    }
    Ok(VoxScene { svos, names, rig, warnings })
}
