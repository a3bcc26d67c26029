//! glTF 2.0 through the `gltf` crate: every mesh the scene uses becomes one part (a mesh
//! placed by several nodes is voxelized once and instanced), the node hierarchy becomes a
//! [`Rig`], and the animations' translation, rotation and scale channels become its clips.
//!
//! Buffers and images are read here, not by the crate's importer, so that every file goes
//! through the size limits and every accessor is checked against its buffer before it is
//! read: a malformed file gets an error naming the element, never a panic.
//!
//! Materials (metallic-roughness) map onto voxray's diffuse + Phong material:
//! albedo = base colour · (1 − metallic) (the base colour texture, sRGB, times its factor);
//! specular = luminance of the reflectance at normal incidence, mix(0.04, base, metallic),
//! limited so that albedo + specular ≤ 1; Phong exponent = 2/α² − 2 with α = roughness²
//! (the Blinn–Phong match of a GGX lobe), at most 10 000; emission = emissive factor ·
//! `KHR_materials_emissive_strength`. Emissive textures, normal maps and occlusion are not
//! read (a warning says so once per material).

use super::{ImportError, Imported, MAX_GLTF_BYTES, MAX_IMAGE_BYTES};
use crate::mesh::{is_degenerate, Material, Mesh, Part, Texture, Triangle};
use crate::scene::animation::{Channel, Clip, Interpolation, Node, Property, Rest, Rig};
use glam::{DAffine3, DMat4, DQuat, DVec3, Vec2, Vec3};
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

/// Grey of triangles without a material (as the voxelizer's default).
const DEFAULT_ALBEDO: f32 = 0.8;

struct Ctx<'a> {
    path: &'a Path,
    buffers: Vec<Vec<u8>>,
    warnings: Vec<String>,
}

impl Ctx<'_> {
    fn invalid(&self, element: impl Into<String>, message: impl std::fmt::Display) -> ImportError {
        ImportError::Invalid {
            path: self.path.display().to_string(),
            element: element.into(),
            message: message.to_string(),
        }
    }

    /// Checks that every byte the accessor reads lies inside its view and buffer (the crate
    /// slices without checking).
    fn check_accessor(&self, a: &gltf::Accessor, element: &str) -> Result<(), ImportError> {
        let what = format!("{element}, accessor {}", a.index());
        if a.sparse().is_some() {
            return Err(self.invalid(what, "sparse accessors are not supported"));
        }
        let Some(view) = a.view() else {
            return Err(self.invalid(what, "has no buffer view"));
        };
        let Some(buffer) = self.buffers.get(view.buffer().index()) else {
            return Err(self.invalid(what, "its buffer does not exist"));
        };
        let elem = a.size();
        let stride = view.stride().unwrap_or(elem);
        if stride < elem {
            return Err(self.invalid(what, format!("byte stride {stride} is less than its element size {elem}")));
        }
        let span = match a.count() {
            0 => Some(0),
            n => (n - 1).checked_mul(stride).and_then(|s| s.checked_add(elem)),
        };
        let view_end = view.offset().checked_add(view.length());
        let fits = span.and_then(|s| s.checked_add(a.offset())).is_some_and(|end| end <= view.length())
            && view_end.is_some_and(|e| e <= buffer.len());
        if !fits {
            return Err(self.invalid(
                what,
                format!(
                    "{} elements of {elem} bytes (stride {stride}) at offset {} run past its buffer view ({} bytes at {} of a {}-byte buffer)",
                    a.count(),
                    a.offset(),
                    view.length(),
                    view.offset(),
                    buffer.len()
                ),
            ));
        }
        Ok(())
    }

    fn buffer(&self, b: gltf::Buffer<'_>) -> Option<&[u8]> {
        self.buffers.get(b.index()).map(Vec::as_slice)
    }
}

/// Reads the bytes of a URI: a `data:` URI's base64, or a file beside the glTF.
fn read_uri(path: &Path, uri: &str, limit: u64, what: &'static str) -> Result<Vec<u8>, String> {
    if let Some(rest) = uri.strip_prefix("data:") {
        use base64::Engine;
        let (_, data) = rest.split_once(";base64,").ok_or("a data URI without base64 data")?;
        if data.len() as u64 / 4 * 3 > limit {
            return Err(format!("embedded data larger than {limit} bytes"));
        }
        return base64::engine::general_purpose::STANDARD.decode(data.trim()).map_err(|e| format!("bad base64: {e}"));
    }
    let name = percent_decode(uri);
    let file = path.parent().unwrap_or(Path::new(".")).join(&name);
    crate::input::read_limited(&file, limit, what).map_err(|e| e.to_string())
}

/// URIs escape spaces and other characters as `%XX`.
fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        if b[i] == b'%' && i + 2 < b.len() {
            if let (Some(h), Some(l)) = (hex(b[i + 1]), hex(b[i + 2])) {
                out.push((h * 16 + l) as u8);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Loads a `.gltf` or `.glb` file.
pub fn load(path: &Path) -> Result<Imported, ImportError> {
    let bytes = crate::input::read_limited(path, MAX_GLTF_BYTES, "a glTF file")?;
    let invalid = |element: &str, message: &dyn std::fmt::Display| ImportError::Invalid {
        path: path.display().to_string(),
        element: element.into(),
        message: message.to_string(),
    };
    let mut doc = gltf::Gltf::from_slice(&bytes).map_err(|e| invalid("file", &e))?;
    drop(bytes);
    let mut blob = doc.blob.take();
    let mut ctx = Ctx { path, buffers: Vec::new(), warnings: Vec::new() };
    for b in doc.buffers() {
        let element = format!("buffer {}", b.index());
        let data = match b.source() {
            gltf::buffer::Source::Bin => {
                blob.take().ok_or_else(|| invalid(&element, &"refers to the GLB binary chunk, which the file lacks"))?
            }
            gltf::buffer::Source::Uri(uri) => {
                read_uri(path, uri, MAX_GLTF_BYTES, "a glTF buffer").map_err(|e| invalid(&element, &e))?
            }
        };
        if data.len() < b.length() {
            return Err(invalid(&element, &format!("holds {} bytes but its byteLength is {}", data.len(), b.length())));
        }
        ctx.buffers.push(data);
    }

    // The nodes of the scene, parents first.
    let scene = doc.default_scene().or_else(|| doc.scenes().next());
    let roots: Vec<gltf::Node> = match &scene {
        Some(s) => s.nodes().collect(),
        None => {
            let children: std::collections::HashSet<usize> =
                doc.nodes().flat_map(|n| n.children().map(|c| c.index()).collect::<Vec<_>>()).collect();
            doc.nodes().filter(|n| !children.contains(&n.index())).collect()
        }
    };
    let mut rig = Rig::default();
    let mut node_of: HashMap<usize, usize> = HashMap::new();
    let mut part_of_mesh: HashMap<usize, Option<usize>> = HashMap::new();
    let mut mesh = Mesh::default();
    let mut materials: HashMap<Option<usize>, u32> = HashMap::new();
    let mut texture_bytes = 0u64;
    let mut stack: Vec<(gltf::Node, Option<usize>)> = roots.into_iter().rev().map(|n| (n, None)).collect();
    while let Some((node, parent)) = stack.pop() {
        let name = node.name().map_or_else(|| format!("node {}", node.index()), |n| format!("node '{n}'"));
        if node_of.insert(node.index(), rig.nodes.len()).is_some() {
            return Err(ctx.invalid(name, "is reached twice from the scene (two parents, or a cycle)"));
        }
        if rig.nodes.len() >= 1 << 20 {
            return Err(ctx.invalid(name, "more than 2^20 nodes"));
        }
        let rest = match node.transform() {
            gltf::scene::Transform::Matrix { matrix } => {
                let m = DMat4::from_cols_array_2d(&matrix.map(|c| c.map(f64::from)));
                if !m.is_finite() {
                    return Err(ctx.invalid(name, "its matrix is not finite"));
                }
                if m.row(3) != glam::DVec4::new(0.0, 0.0, 0.0, 1.0) {
                    return Err(ctx.invalid(name, "its matrix is projective (last row is not 0 0 0 1)"));
                }
                Rest::Matrix(DAffine3::from_mat4(m))
            }
            gltf::scene::Transform::Decomposed { translation, rotation, scale } => {
                let t = DVec3::from(translation.map(f64::from));
                let q = DQuat::from_array(rotation.map(f64::from));
                let s = DVec3::from(scale.map(f64::from));
                if !(t.is_finite() && q.is_finite() && s.is_finite()) {
                    return Err(ctx.invalid(name, "its translation, rotation or scale is not finite"));
                }
                let len = q.length();
                if !(len > 1e-6) {
                    return Err(ctx.invalid(name, "its rotation quaternion has zero length"));
                }
                if (len - 1.0).abs() > 1e-3 {
                    ctx.warnings.push(format!("{name}: rotation quaternion of length {len:.4} normalized"));
                }
                Rest::Trs(t, q / len, s)
            }
        };
        if node.skin().is_some() {
            ctx.warnings.push(format!("{name}: skinning ignored (rigid parts only)"));
        }
        let part = match node.mesh() {
            None => None,
            Some(m) => match part_of_mesh.get(&m.index()) {
                Some(&p) => p,
                None => {
                    let p = read_mesh(&mut ctx, &m, &mut mesh, &mut materials, &mut texture_bytes)?;
                    part_of_mesh.insert(m.index(), p);
                    p
                }
            },
        };
        let k = rig.nodes.len();
        rig.nodes.push(Node { name: name.clone(), parent, rest, part });
        for c in node.children().collect::<Vec<_>>().into_iter().rev() {
            stack.push((c, Some(k)));
        }
    }
    if mesh.parts.is_empty() {
        return Err(ctx.invalid("scene", "places no mesh with triangles"));
    }

    for (ai, anim) in doc.animations().enumerate() {
        let clip_name = anim.name().map_or_else(|| format!("animation {ai}"), str::to_string);
        let mut channels = Vec::new();
        for (ci, ch) in anim.channels().enumerate() {
            let element = format!("animation '{clip_name}' channel {ci}");
            let target = ch.target();
            let Some(&node) = node_of.get(&target.node().index()) else {
                ctx.warnings
                    .push(format!("{element}: drives node {} outside the scene; ignored", target.node().index()));
                continue;
            };
            let property = match target.property() {
                gltf::animation::Property::Translation => Property::Translation,
                gltf::animation::Property::Rotation => Property::Rotation,
                gltf::animation::Property::Scale => Property::Scale,
                gltf::animation::Property::MorphTargetWeights => {
                    ctx.warnings.push(format!("{element}: morph target weights ignored (rigid parts only)"));
                    continue;
                }
            };
            if matches!(rig.nodes[node].rest, Rest::Matrix(_)) {
                return Err(ctx.invalid(element, "animates a node given by a matrix (glTF allows only TRS nodes)"));
            }
            let sampler = ch.sampler();
            let interpolation = match sampler.interpolation() {
                gltf::animation::Interpolation::Step => Interpolation::Step,
                gltf::animation::Interpolation::Linear => Interpolation::Linear,
                gltf::animation::Interpolation::CubicSpline => Interpolation::CubicSpline,
            };
            ctx.check_accessor(&sampler.input(), &element)?;
            ctx.check_accessor(&sampler.output(), &element)?;
            let reader = ch.reader(|b| ctx.buffer(b));
            let times: Vec<f64> = reader
                .read_inputs()
                .ok_or_else(|| ctx.invalid(&element, "its key times cannot be read"))?
                .map(f64::from)
                .collect();
            use gltf::animation::util::ReadOutputs;
            let values: Vec<[f64; 4]> = match reader.read_outputs() {
                Some(ReadOutputs::Translations(it)) | Some(ReadOutputs::Scales(it)) => {
                    it.map(|v| [v[0] as f64, v[1] as f64, v[2] as f64, 0.0]).collect()
                }
                Some(ReadOutputs::Rotations(r)) => r.into_f32().map(|v| v.map(f64::from)).collect(),
                _ => return Err(ctx.invalid(&element, "its values cannot be read as its property")),
            };
            let channel = Channel { node, property, interpolation, times, values };
            channel.validate().map_err(|e| ctx.invalid(&element, e))?;
            if property == Property::Rotation {
                let worst =
                    channel.values.iter().map(|v| (DQuat::from_array(*v).length() - 1.0).abs()).fold(0.0, f64::max);
                if worst > 1e-3 && interpolation != Interpolation::CubicSpline {
                    ctx.warnings.push(format!("{element}: rotation keys up to {worst:.4} off unit length, normalized"));
                }
            }
            channels.push(channel);
        }
        rig.clips.push(Clip::new(clip_name, channels));
    }
    mesh.warnings.append(&mut ctx.warnings);
    Ok(Imported { mesh, rig })
}

/// Appends a mesh's triangles as one part; None when it has no triangles (a warning says so).
fn read_mesh(
    ctx: &mut Ctx<'_>,
    m: &gltf::Mesh<'_>,
    mesh: &mut Mesh,
    materials: &mut HashMap<Option<usize>, u32>,
    texture_bytes: &mut u64,
) -> Result<Option<usize>, ImportError> {
    let mesh_name = m.name().map_or_else(|| format!("mesh {}", m.index()), str::to_string);
    let mut triangles = Vec::new();
    for prim in m.primitives() {
        let element = format!("mesh '{mesh_name}' primitive {}", prim.index());
        use gltf::mesh::Mode;
        let mode = prim.mode();
        if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
            ctx.warnings.push(format!("{element}: {mode:?} primitives ignored (only triangles are voxelized)"));
            continue;
        }
        let Some(pos) = prim.get(&gltf::Semantic::Positions) else {
            return Err(ctx.invalid(element, "has no POSITION attribute"));
        };
        ctx.check_accessor(&pos, &element)?;
        if let Some(i) = prim.indices() {
            ctx.check_accessor(&i, &element)?;
        }
        let uv_accessor = prim.get(&gltf::Semantic::TexCoords(0));
        if let Some(a) = &uv_accessor {
            ctx.check_accessor(a, &element)?;
        }
        let material = material_index(ctx, &prim.material(), mesh, materials, texture_bytes)?;
        let reader = prim.reader(|b| ctx.buffer(b));
        let positions: Vec<Vec3> = reader
            .read_positions()
            .ok_or_else(|| ctx.invalid(&element, "its positions cannot be read"))?
            .map(Vec3::from)
            .collect();
        if let Some(bad) = positions.iter().position(|p| !p.is_finite()) {
            return Err(ctx.invalid(&element, format!("vertex {bad} is not finite")));
        }
        // glTF's v runs down the image; voxray's textures follow OBJ (v up).
        let uvs: Option<Vec<Vec2>> = uv_accessor
            .is_some()
            .then(|| reader.read_tex_coords(0).map(|t| t.into_f32().map(|[u, v]| Vec2::new(u, 1.0 - v)).collect()))
            .flatten();
        let indices: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None => (0..positions.len() as u32).collect(),
        };
        if let Some(&bad) = indices.iter().find(|&&i| i as usize >= positions.len()) {
            return Err(ctx.invalid(&element, format!("index {bad} is past its {} vertices", positions.len())));
        }
        let corners: Vec<[u32; 3]> = match mode {
            Mode::Triangles => indices.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
            Mode::TriangleStrip => (2..indices.len())
                .map(|k| {
                    if k % 2 == 0 {
                        [indices[k - 2], indices[k - 1], indices[k]]
                    } else {
                        [indices[k - 1], indices[k - 2], indices[k]]
                    }
                })
                .collect(),
            _ => (2..indices.len()).map(|k| [indices[0], indices[k - 1], indices[k]]).collect(),
        };
        for c in corners {
            let p = c.map(|i| positions[i as usize]);
            if is_degenerate(&p) {
                mesh.degenerate_skipped += 1;
                continue;
            }
            let uv = uvs.as_ref().filter(|u| u.len() == positions.len()).map(|u| c.map(|i| u[i as usize]));
            triangles.push(Triangle { positions: p, uvs: uv, material });
        }
    }
    if triangles.is_empty() {
        ctx.warnings.push(format!("mesh '{mesh_name}' has no triangles; the nodes placing it draw nothing"));
        return Ok(None);
    }
    mesh.parts.push(Part { name: mesh_name, triangles });
    Ok(Some(mesh.parts.len() - 1))
}

/// The voxray material of a glTF material (made on first use).
fn material_index(
    ctx: &mut Ctx<'_>,
    m: &gltf::Material<'_>,
    mesh: &mut Mesh,
    materials: &mut HashMap<Option<usize>, u32>,
    texture_bytes: &mut u64,
) -> Result<u32, ImportError> {
    if let Some(&k) = materials.get(&m.index()) {
        return Ok(k);
    }
    let name =
        m.name().map_or_else(|| m.index().map_or("default".to_string(), |i| format!("material {i}")), str::to_string);
    let element = format!("material '{name}'");
    let material = match m.index() {
        None => Material::new("default", Vec3::splat(DEFAULT_ALBEDO)),
        Some(_) => {
            let pbr = m.pbr_metallic_roughness();
            let factor = pbr.base_color_factor();
            let base = Vec3::new(factor[0], factor[1], factor[2]);
            let metallic = pbr.metallic_factor();
            let roughness = pbr.roughness_factor();
            let emissive = Vec3::from(m.emissive_factor()) * m.emissive_strength().unwrap_or(1.0);
            if !(base.is_finite() && metallic.is_finite() && roughness.is_finite() && emissive.is_finite())
                || base.min_element() < 0.0
                || emissive.min_element() < 0.0
            {
                return Err(ctx.invalid(
                    element,
                    "base colour, metallic, roughness or emissive factor is negative or not finite",
                ));
            }
            let (metallic, roughness) = (metallic.clamp(0.0, 1.0), roughness.clamp(0.0, 1.0));
            let albedo = (base * (1.0 - metallic)).min(Vec3::ONE);
            let f0 = Vec3::splat(0.04).lerp(base.min(Vec3::ONE), metallic);
            let specular = f0.dot(Vec3::new(0.2126, 0.7152, 0.0722)).min((1.0 - albedo.max_element()).max(0.0));
            let alpha = (roughness * roughness).max(1e-3);
            let shininess = (2.0 / (alpha * alpha) - 2.0).clamp(0.0, 10_000.0);
            let mut out =
                Material { name: name.clone(), albedo, emission: emissive, specular, shininess, texture: None };
            if let Some(info) = pbr.base_color_texture() {
                if info.tex_coord() != 0 {
                    ctx.warnings.push(format!(
                        "{element}: base colour texture uses TEXCOORD_{}; read with set 0",
                        info.tex_coord()
                    ));
                }
                match image_bytes(ctx, &info.texture()).and_then(|b| decode_texture(&b, texture_bytes)) {
                    Ok(mut tex) => {
                        for t in &mut tex.texels {
                            *t = (*t * base * (1.0 - metallic)).min(Vec3::ONE);
                        }
                        out.texture = Some(Arc::new(tex));
                    }
                    Err(e) => ctx
                        .warnings
                        .push(format!("{element}: base colour texture not loaded ({e}); its factor is used")),
                }
            }
            if m.emissive_texture().is_some() || m.normal_texture().is_some() || m.occlusion_texture().is_some() {
                ctx.warnings.push(format!("{element}: emissive, normal and occlusion textures are not read"));
            }
            out
        }
    };
    mesh.materials.push(material);
    let k = (mesh.materials.len() - 1) as u32;
    materials.insert(m.index(), k);
    Ok(k)
}

/// The encoded bytes of a texture's image (from a buffer view, a data URI or a file).
fn image_bytes(ctx: &Ctx<'_>, t: &gltf::Texture<'_>) -> Result<Vec<u8>, String> {
    match t.source().source() {
        gltf::image::Source::View { view, .. } => {
            let buffer = ctx.buffers.get(view.buffer().index()).ok_or("its buffer does not exist")?;
            let end = view.offset().checked_add(view.length()).filter(|&e| e <= buffer.len());
            end.map(|e| buffer[view.offset()..e].to_vec())
                .ok_or_else(|| "its buffer view runs past its buffer".to_string())
        }
        gltf::image::Source::Uri { uri, .. } => read_uri(ctx.path, uri, MAX_IMAGE_BYTES, "an image"),
    }
}

/// Decodes an image into linear RGB, refusing huge ones before decoding.
#[cfg(feature = "image-io")]
fn decode_texture(bytes: &[u8], loaded: &mut u64) -> Result<Texture, String> {
    let reader =
        image::ImageReader::new(std::io::Cursor::new(bytes)).with_guessed_format().map_err(|e| e.to_string())?;
    let (w, h) = reader.into_dimensions().map_err(|e| e.to_string())?;
    let most = crate::mesh::MAX_TEXTURE_TEXELS;
    if w as u64 * h as u64 > most {
        return Err(format!("{w}×{h} texels, more than the {most} a texture may have"));
    }
    let texels = w as u64 * h as u64;
    crate::memory::check(
        &format!("a {w}×{h} texture"),
        *loaded + texels * 28,
        "scale the textures down or raise the memory budget",
    )
    .map_err(|e| e.to_string())?;
    *loaded += texels * 12;
    let img = image::load_from_memory(bytes).map_err(|e| e.to_string())?.to_rgb32f();
    let (width, height) = img.dimensions();
    let lin = crate::mesh::srgb_to_linear;
    let texels = img.pixels().map(|p| Vec3::new(lin(p[0]), lin(p[1]), lin(p[2]))).collect();
    Ok(Texture { width, height, texels })
}

#[cfg(not(feature = "image-io"))]
fn decode_texture(_: &[u8], _: &mut u64) -> Result<Texture, String> {
    Err("built without the `image-io` feature".into())
}
