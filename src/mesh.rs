//! Triangle meshes split into parts, with Lambertian materials; OBJ/MTL loading through tobj
//! (feature `obj`). Each OBJ object or group is a part; a part sits at the identity
//! transform, so a multi-part OBJ renders in place as the mesh would.

use glam::{Vec2, Vec3};
use std::sync::Arc;

pub mod polygon;

/// A diffuse texture in linear RGB.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Row-major texels, row 0 at the top of the image, linear RGB.
    pub texels: Vec<Vec3>,
}

impl Texture {
    /// Bilinear sample with wrapping; OBJ's v runs bottom to top.
    pub fn sample(&self, uv: Vec2) -> Vec3 {
        let (w, h) = (self.width as i64, self.height as i64);
        if w == 0 || h == 0 || !uv.is_finite() {
            return Vec3::splat(0.5);
        }
        let x = uv.x as f64 * w as f64 - 0.5;
        let y = (1.0 - uv.y as f64) * h as f64 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let at = |xi: f64, yi: f64| {
            let xi = (xi as i64).rem_euclid(w) as usize;
            let yi = (yi as i64).rem_euclid(h) as usize;
            self.texels[yi * w as usize + xi]
        };
        let top = at(x0, y0).lerp(at(x0 + 1.0, y0), fx);
        let bottom = at(x0, y0 + 1.0).lerp(at(x0 + 1.0, y0 + 1.0), fx);
        top.lerp(bottom, fy)
    }
}

/// An sRGB-encoded channel value in [0, 1] as linear light (textures, palettes).
pub fn srgb_to_linear(s: f32) -> f32 {
    if s <= 0.040_45 {
        s / 12.92
    } else {
        ((s + 0.055) / 1.055).powf(2.4)
    }
}

/// A two-sided material: Lambertian diffuse plus an optional Phong lobe
/// ([`crate::render::brdf`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Name from the MTL file.
    pub name: String,
    /// Linear albedo (MTL `Kd`).
    pub albedo: Vec3,
    /// Emitted radiance (MTL `Ke`).
    pub emission: Vec3,
    /// Specular reflectance in [0, 1] (luminance of MTL `Ks`, limited so that
    /// `max(Kd) + ks ≤ 1`); 0 for a diffuse-only material.
    pub specular: f32,
    /// Phong exponent (MTL `Ns`, ≥ 0).
    pub shininess: f32,
    /// Diffuse texture (MTL `map_Kd`); replaces `albedo` where present.
    pub texture: Option<Arc<Texture>>,
}

impl Material {
    /// A plain material.
    pub fn new(name: &str, albedo: Vec3) -> Self {
        Material { name: name.into(), albedo, emission: Vec3::ZERO, specular: 0.0, shininess: 1.0, texture: None }
    }
    /// Glossiness in [0, 1] of [`Material::shininess`] ([`crate::render::brdf::gloss_of_shininess`]).
    pub fn gloss(&self) -> f32 {
        crate::render::brdf::gloss_of_shininess(self.shininess)
    }
    /// Albedo at a texture coordinate (the texture if there is one and `uv` is given).
    pub fn albedo_at(&self, uv: Option<Vec2>) -> Vec3 {
        match (&self.texture, uv) {
            (Some(t), Some(uv)) => t.sample(uv),
            _ => self.albedo,
        }
    }
}

/// One triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Triangle {
    /// Vertex positions.
    pub positions: [Vec3; 3],
    /// Texture coordinates, if the OBJ gave them.
    pub uvs: Option<[Vec2; 3]>,
    /// Index into [`Mesh::materials`].
    pub material: u32,
}

/// A named rigid part: the unit that gets its own SVO.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Part {
    /// OBJ object/group name (or file stem).
    pub name: String,
    /// Its triangles.
    pub triangles: Vec<Triangle>,
}

/// Parts plus the materials they index.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Mesh {
    /// Parts in file order.
    pub parts: Vec<Part>,
    /// Materials; triangles index into this.
    pub materials: Vec<Material>,
    /// Triangles dropped because they had (numerically) zero area.
    pub degenerate_skipped: usize,
    /// Non-fatal problems met while loading (a missing texture, a part with no triangle).
    pub warnings: Vec<String>,
}

impl Mesh {
    /// Drops every material's specular lobe (MTL `Ks`/`Ns`), leaving them purely Lambertian
    /// as the shared conventions have it (for comparing images with other renderers).
    pub fn make_lambertian(&mut self) {
        for m in &mut self.materials {
            m.specular = 0.0;
        }
    }

    /// Total triangle count.
    pub fn triangle_count(&self) -> usize {
        self.parts.iter().map(|p| p.triangles.len()).sum()
    }
    /// Appends another mesh's parts and materials (material indices are rebased).
    pub fn append(&mut self, other: Mesh) {
        let base = self.materials.len() as u32;
        self.materials.extend(other.materials);
        for mut p in other.parts {
            for t in &mut p.triangles {
                t.material += base;
            }
            self.parts.push(p);
        }
        self.degenerate_skipped += other.degenerate_skipped;
        self.warnings.extend(other.warnings);
    }
}

/// Whether a triangle has numerically zero area (relative to its edge lengths).
pub fn is_degenerate(p: &[Vec3; 3]) -> bool {
    let (a, b, c) = (p[0].as_dvec3(), p[1].as_dvec3(), p[2].as_dvec3());
    let cross = (b - a).cross(c - a).length_squared();
    let scale = (b - a).length_squared().max((c - a).length_squared()).max((c - b).length_squared());
    !(cross > 1e-24 * scale * scale)
}

/// Most texels a `map_Kd` texture may have (4096², 192 MiB once loaded as linear RGB).
pub const MAX_TEXTURE_TEXELS: u64 = 4096 * 4096;

/// Why a mesh could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The file does not exist.
    #[error("{path}: file not found")]
    NotFound {
        /// The path.
        path: String,
    },
    /// Reading failed.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: String,
        /// The error.
        source: std::io::Error,
    },
    /// The file is larger than an OBJ/MTL file may be.
    #[error(transparent)]
    TooLarge(crate::input::InputError),
    /// Malformed OBJ/MTL content.
    #[error("{path}{}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
    Parse {
        /// The file.
        path: String,
        /// 1-based line, when known.
        line: Option<usize>,
        /// What is wrong.
        message: String,
    },
    /// A vertex coordinate is NaN or infinite.
    #[error("{path}:{line}: non-finite coordinate in object '{object}': {text}")]
    NonFinite {
        /// The file.
        path: String,
        /// 1-based line.
        line: usize,
        /// Object/group the vertex was declared in.
        object: String,
        /// The offending line.
        text: String,
    },
    /// No usable triangle at all.
    #[error("{path}: no non-degenerate triangles (empty mesh)")]
    Empty {
        /// The file.
        path: String,
    },
}

#[cfg(feature = "obj")]
pub use obj::{load_obj, load_obj_text};

#[cfg(feature = "obj")]
mod obj {
    use super::*;
    use std::path::Path;

    /// Loads an OBJ file (with its MTL files and textures, relative to the OBJ's folder).
    pub fn load_obj(path: &Path) -> Result<Mesh, MeshError> {
        let label = path.display().to_string();
        let text = crate::input::read_limited(path, crate::input::MAX_OBJ_BYTES, "an OBJ file").map_err(mesh_error)?;
        let text = String::from_utf8_lossy(&text);
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let read_mtl = |name: &Path| -> Result<String, MeshError> {
            let p = dir.join(name);
            crate::input::read_text_limited(&p, crate::input::MAX_MTL_BYTES, "an MTL file").map_err(mesh_error)
        };
        load_obj_text(&text, &label, &stem, Some(&dir), &read_mtl)
    }

    /// The mesh error of a failed limited read.
    fn mesh_error(e: crate::input::InputError) -> MeshError {
        use crate::input::InputError;
        match e {
            InputError::NotFound { path } => MeshError::NotFound { path },
            InputError::Io { path, source } => MeshError::Io { path, source },
            e @ InputError::TooLarge { .. } => MeshError::TooLarge(e),
        }
    }

    /// Loads OBJ text. `label` names the source in errors, `default_name` names parts that
    /// have no `o`/`g`, `texture_dir` is where `map_Kd` paths are resolved (None: textures
    /// are not loaded and a warning says so), and `read_mtl` supplies MTL files by name.
    pub fn load_obj_text(
        text: &str,
        label: &str,
        default_name: &str,
        texture_dir: Option<&Path>,
        read_mtl: &dyn Fn(&Path) -> Result<String, MeshError>,
    ) -> Result<Mesh, MeshError> {
        let usemtl = prescan(text, label)?;
        let mut mtl_error: std::cell::RefCell<Option<MeshError>> = Default::default();
        let opts =
            // Faces are triangulated here (ear clipping), not by tobj's fan.
            tobj::LoadOptions { triangulate: false, single_index: false, ignore_points: true, ignore_lines: true };
        let (models, materials) = tobj::load_obj_buf(&mut text.as_bytes(), &opts, |p| {
            let src = match read_mtl(p) {
                Ok(s) => s,
                Err(e) => {
                    mtl_error.borrow_mut().get_or_insert(e);
                    return Err(tobj::LoadError::OpenFileFailed);
                }
            };
            if let Err(e) = prescan_mtl(&src, &p.display().to_string()) {
                mtl_error.borrow_mut().get_or_insert(e);
                return Err(tobj::LoadError::MaterialParseError);
            }
            tobj::load_mtl_buf(&mut src.as_bytes()).inspect_err(|e| {
                mtl_error.borrow_mut().get_or_insert(MeshError::Parse {
                    path: p.display().to_string(),
                    line: None,
                    message: format!("MTL: {e}"),
                });
            })
        })
        .map_err(|e| MeshError::Parse { path: label.into(), line: None, message: e.to_string() })?;
        if let Some(e) = mtl_error.get_mut().take() {
            return Err(e);
        }
        let materials = materials.unwrap_or_default();
        let mut mesh = Mesh::default();
        // Bytes of the textures loaded so far (they stay in memory together).
        let mut texture_bytes = 0u64;
        for m in &materials {
            mesh.materials.push(convert_material(m, texture_dir, &mut mesh.warnings, &mut texture_bytes)?);
        }
        for (line, name) in usemtl {
            if !mesh.materials.iter().any(|m| m.name == name) {
                mesh.warnings.push(format!(
                    "{label}:{line}: usemtl '{name}' names no material of the MTL files; its faces use the default grey"
                ));
            }
        }
        let default_mat = mesh.materials.len() as u32;
        mesh.materials.push(Material::new("default", Vec3::splat(0.7)));

        let mut fanned = 0usize;
        for model in &models {
            let name = if model.name.is_empty() || model.name == "unnamed_object" {
                default_name.to_string()
            } else {
                model.name.clone()
            };
            // tobj starts a new model at every material change; merge them back by name.
            let idx = match mesh.parts.iter().position(|p| p.name == name) {
                Some(i) => i,
                None => {
                    mesh.parts.push(Part { name: name.clone(), triangles: Vec::new() });
                    mesh.parts.len() - 1
                }
            };
            let m = &model.mesh;
            let material = m.material_id.map_or(default_mat, |i| i.min(default_mat as usize) as u32);
            let pos = |i: u32| {
                let i = i as usize * 3;
                Vec3::new(m.positions[i], m.positions[i + 1], m.positions[i + 2])
            };
            let has_uv = !m.texcoords.is_empty() && m.texcoord_indices.len() == m.indices.len();
            // Vertex counts of the faces (none listed: all triangles).
            let arities = if m.face_arities.is_empty() { vec![3; m.indices.len() / 3] } else { m.face_arities.clone() };
            let mut start = 0usize;
            for arity in arities {
                let end = (start + arity as usize).min(m.indices.len());
                let face = &m.indices[start..end];
                let corners: Vec<Vec3> = face.iter().map(|&i| pos(i)).collect();
                let split = polygon::triangulate(&corners);
                fanned += split.fanned as usize;
                for [a, b, c] in split.triangles {
                    let positions = [corners[a], corners[b], corners[c]];
                    if is_degenerate(&positions) {
                        mesh.degenerate_skipped += 1;
                        continue;
                    }
                    let uvs = has_uv.then(|| {
                        let ti = [start + a, start + b, start + c].map(|k| m.texcoord_indices[k]);
                        ti.map_or_uv(&m.texcoords)
                    });
                    mesh.parts[idx].triangles.push(Triangle { positions, uvs, material });
                }
                start = end;
            }
        }
        if fanned > 0 {
            mesh.warnings.push(format!(
                "{label}: {fanned} polygon face(s) cross themselves, are flat as a line or have more than {} vertices; \
                 they were split as a fan from their first corner, which may cover notches",
                polygon::MAX_EAR_CLIPPED
            ));
        }
        mesh.parts.retain(|p| {
            if p.triangles.is_empty() {
                mesh.warnings.push(format!("{label}: part '{}' has no non-degenerate triangle; skipped", p.name));
            }
            !p.triangles.is_empty()
        });
        if mesh.parts.is_empty() {
            return Err(MeshError::Empty { path: label.into() });
        }
        Ok(mesh)
    }

    trait UvLookup {
        fn map_or_uv(&self, texcoords: &[f32]) -> [Vec2; 3];
    }
    impl UvLookup for [u32; 3] {
        fn map_or_uv(&self, tc: &[f32]) -> [Vec2; 3] {
            let at = |i: u32| {
                let i = i as usize * 2;
                Vec2::new(tc.get(i).copied().unwrap_or(0.0), tc.get(i + 1).copied().unwrap_or(0.0))
            };
            [at(self[0]), at(self[1]), at(self[2])]
        }
    }

    fn convert_material(
        m: &tobj::Material,
        dir: Option<&Path>,
        warnings: &mut Vec<String>,
        texture_bytes: &mut u64,
    ) -> Result<Material, MeshError> {
        let albedo = m.diffuse.map_or(Vec3::splat(0.7), Vec3::from);
        let emission = m.emissive.map_or(Vec3::ZERO, Vec3::from);
        let bad = |what: &str| MeshError::Parse {
            path: format!("material '{}'", m.name),
            line: None,
            message: format!("{what} must be finite and non-negative"),
        };
        if !albedo.is_finite() || albedo.min_element() < 0.0 {
            return Err(bad("Kd"));
        }
        if !emission.is_finite() || emission.min_element() < 0.0 {
            return Err(bad("Ke"));
        }
        if emission.max_element() > crate::svo::MAX_EMISSION {
            return Err(MeshError::Parse {
                path: format!("material '{}'", m.name),
                line: None,
                message: format!(
                    "Ke {emission} is above the largest emitted radiance a voxel holds ({}); scale the scene's lights down",
                    crate::svo::MAX_EMISSION
                ),
            });
        }
        if albedo.max_element() > 1.0 {
            // A surface cannot reflect more than it receives; the voxel stores at most 1.
            warnings.push(format!("material '{}': Kd {albedo} above 1 is stored as {}", m.name, albedo.min(Vec3::ONE)));
        }
        let ks = m.specular.map_or(Vec3::ZERO, Vec3::from);
        if !ks.is_finite() || ks.min_element() < 0.0 {
            return Err(bad("Ks"));
        }
        let shininess = m.shininess.unwrap_or(1.0);
        if !shininess.is_finite() || shininess < 0.0 {
            return Err(bad("Ns"));
        }
        // A grey lobe of Ks's luminance; limited so the surface reflects at most what it
        // receives (many exporters write Ks 0.5 next to a bright Kd).
        let wanted = ks.dot(Vec3::new(0.2126, 0.7152, 0.0722));
        let room = (1.0 - albedo.max_element()).max(0.0);
        let specular = wanted.min(room).min(1.0);
        if wanted > specular + 1e-3 {
            warnings.push(format!(
                "material '{}': specular Ks {wanted:.3} lowered to {specular:.3} so that Kd + Ks stays at most 1",
                m.name
            ));
        }
        let mut out = Material { name: m.name.clone(), albedo, emission, specular, shininess, texture: None };
        if let Some(tex) = &m.diffuse_texture {
            match dir {
                None => warnings
                    .push(format!("material '{}': texture '{tex}' not loaded (no folder to resolve it)", m.name)),
                Some(d) => match load_texture(&d.join(tex), texture_bytes) {
                    Ok(t) => out.texture = Some(Arc::new(t)),
                    Err(e) => warnings.push(format!("material '{}': texture ignored, using Kd: {e}", m.name)),
                },
            }
        }
        Ok(out)
    }

    #[cfg(feature = "image-io")]
    fn load_texture(path: &Path, loaded: &mut u64) -> Result<Texture, String> {
        // The header first: a small compressed file can decode to gigabytes.
        let (w, h) = image::image_dimensions(path).map_err(|e| format!("{}: {e}", path.display()))?;
        if w as u64 * h as u64 > MAX_TEXTURE_TEXELS {
            return Err(format!(
                "{}: {w}×{h} texels, more than the {} a texture may have (12 bytes each once loaded); scale it down",
                path.display(),
                MAX_TEXTURE_TEXELS
            ));
        }
        // Decoding holds the file's texels, their f32 copy and the linear ones (28 bytes a
        // texel); the textures before this one stay (12 bytes a texel).
        let texels = w as u64 * h as u64;
        crate::memory::check(
            &format!("{}: {w}×{h} texels after {} of textures", path.display(), crate::memory::size(*loaded)),
            *loaded + texels * 28,
            "scale the textures down or raise the memory budget",
        )
        .map_err(|e| e.to_string())?;
        *loaded += texels * 12;
        let img = image::open(path).map_err(|e| format!("{}: {e}", path.display()))?.to_rgb32f();
        let (width, height) = img.dimensions();
        // 8-bit images are sRGB-encoded; to_rgb32f only rescales, so decode here.
        let texels =
            img.pixels().map(|p| Vec3::new(srgb_to_linear(p[0]), srgb_to_linear(p[1]), srgb_to_linear(p[2]))).collect();
        Ok(Texture { width, height, texels })
    }

    #[cfg(not(feature = "image-io"))]
    fn load_texture(path: &Path, _: &mut u64) -> Result<Texture, String> {
        Err(format!("{}: built without the `image-io` feature", path.display()))
    }

    /// Checks vertex, normal and face lines before tobj sees them, so errors carry a line
    /// number and the object name (tobj reports neither), and returns the `usemtl` names with
    /// the line of their first use.
    fn prescan(text: &str, label: &str) -> Result<Vec<(usize, String)>, MeshError> {
        let mut object = String::from("(none)");
        let (mut nv, mut nvt, mut nvn) = (0i64, 0i64, 0i64);
        let mut usemtl: Vec<(usize, String)> = Vec::new();
        for (i, raw) in text.lines().enumerate() {
            let line = i + 1;
            let l = raw.trim();
            let mut it = l.split_whitespace();
            let parse_err = |message: String| MeshError::Parse { path: label.into(), line: Some(line), message };
            match it.next() {
                Some("o") | Some("g") => object = it.collect::<Vec<_>>().join(" "),
                Some("usemtl") => {
                    let name = it.collect::<Vec<_>>().join(" ");
                    if !usemtl.iter().any(|(_, n)| *n == name) {
                        usemtl.push((line, name));
                    }
                }
                Some("vn") => {
                    let vals: Vec<&str> = it.take(3).collect();
                    if vals.len() < 3 || vals.iter().any(|v| !v.parse::<f32>().is_ok_and(f32::is_finite)) {
                        return Err(parse_err(format!("'vn' needs 3 finite numbers: {l}")));
                    }
                    nvn += 1
                }
                Some(kw @ ("v" | "vt")) => {
                    let want = if kw == "v" { 3 } else { 1 };
                    let vals: Vec<&str> = it.collect();
                    if vals.len() < want {
                        return Err(parse_err(format!("'{kw}' needs {want} numbers: {l}")));
                    }
                    for v in &vals[..vals.len().min(if kw == "v" { 3 } else { 2 })] {
                        let x: f32 = v.parse().map_err(|_| parse_err(format!("'{v}' is not a number: {l}")))?;
                        if !x.is_finite() {
                            return Err(MeshError::NonFinite {
                                path: label.into(),
                                line,
                                object: object.clone(),
                                text: l.into(),
                            });
                        }
                    }
                    if kw == "v" {
                        nv += 1
                    } else {
                        nvt += 1
                    }
                }
                Some("f") => {
                    let verts: Vec<&str> = it.collect();
                    if verts.len() < 3 {
                        return Err(parse_err(format!("a face needs at least 3 vertices: {l}")));
                    }
                    for v in verts {
                        let mut refs = v.split('/');
                        for (k, count) in [(0, nv), (1, nvt), (2, nvn)] {
                            let Some(s) = refs.next() else { break };
                            if s.is_empty() && k > 0 {
                                continue;
                            }
                            let idx: i64 =
                                s.parse().map_err(|_| parse_err(format!("bad vertex reference '{v}': {l}")))?;
                            let ok = (idx > 0 && idx <= count) || (idx < 0 && -idx <= count);
                            if !ok {
                                return Err(parse_err(format!(
                                    "vertex reference '{v}' out of range ({count} {} declared so far): {l}",
                                    ["vertices", "texture coordinates", "normals"][k]
                                )));
                            }
                        }
                    }
                }
                _ => {}
            }
        }
        Ok(usemtl)
    }

    /// Checks MTL text line by line: the numbers of the statements voxray reads must parse
    /// and be finite (tobj's MTL errors name no line).
    fn prescan_mtl(text: &str, label: &str) -> Result<(), MeshError> {
        for (i, raw) in text.lines().enumerate() {
            let l = raw.trim();
            let mut it = l.split_whitespace();
            let Some(kw) = it.next() else { continue };
            // tobj reads three numbers of a colour (and panicked on fewer) and one of a scalar.
            let want = match kw {
                "Ka" | "Kd" | "Ks" | "Ke" | "Tf" => 3,
                "Ns" | "Ni" | "d" | "Tr" | "illum" => 1,
                _ => continue,
            };
            let err = |message: String| MeshError::Parse { path: label.into(), line: Some(i + 1), message };
            let vals: Vec<&str> = it.take(want).collect();
            if vals.len() < want {
                let what = if want == 3 { "3 numbers (r g b)" } else { "a number" };
                return Err(err(format!("'{kw}' needs {what}: {l}")));
            }
            for v in vals {
                let x: f32 = v.parse().map_err(|_| err(format!("'{v}' is not a number: {l}")))?;
                if !x.is_finite() {
                    return Err(err(format!("'{v}' is not finite: {l}")));
                }
            }
        }
        Ok(())
    }
}
