//! The `.svo` file format: a fixed header, the child masks, the attribute array, the
//! emissive triangles, and a CRC-32 over everything before it. Links are not stored: loading derives them from the masks, so
//! no stored pointer can be wrong, and checks that the masks describe exactly the stored
//! node, voxel and attribute counts. A corrupted or hostile file gives a typed error instead
//! of a panic or an endless loop. Versions 1 and 2 (Laine–Karras descriptors with far
//! pointers) and 3 (emission as a multiple of the albedo, no emitter list) are converted on
//! load. The byte layout is documented in `docs/svo-format.md`.

use super::emitter::{Emitter, MAX_EMITTERS};
use super::format::{Attr, Cube, Svo, MAX_DEPTH};
use glam::Vec3;
use std::io::{Read, Write};
use std::path::Path;

/// File magic: the first eight bytes of every `.svo` file.
pub const MAGIC: [u8; 8] = *b"VOXRSVO\0";
/// Current format version (4: masks level by level, links derived on load, 12-byte
/// attributes with RGB emission, the emissive triangles). Versions 1 (descriptors, snorm16
/// normals, no specular lobe), 2 (descriptors) and 3 (8-byte attributes, emission a multiple
/// of the albedo) are still read and converted.
pub const VERSION: u32 = 4;
/// Header length in bytes of versions 1–3; version 4 adds the emitter count ([`HEADER_LEN_4`]).
pub const HEADER_LEN: usize = 56;
/// Header length in bytes of version 4.
pub const HEADER_LEN_4: usize = 64;
/// Bytes per emissive triangle in a version 4 file (nine corner and three radiance f32).
pub const EMITTER_BYTES: usize = 48;

/// Header length of a version.
fn header_len(version: u32) -> usize {
    if version >= 4 {
        HEADER_LEN_4
    } else {
        HEADER_LEN
    }
}
/// Bytes per attribute record of a version.
fn attr_bytes(version: u32) -> u64 {
    if version >= 4 {
        12
    } else {
        8
    }
}

/// Why an `.svo` file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum SvoFileError {
    /// Underlying I/O failure.
    #[error("{path}: {source}")]
    Io {
        /// File concerned.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// Not an `.svo` file.
    #[error("not a voxray .svo file (bad magic)")]
    BadMagic,
    /// Written by a newer or unknown version.
    #[error("unsupported .svo version {0}: this build reads versions 1 to {VERSION} (older ones are converted as they load){why}", why = version_hint(*.0))]
    Version(u32),
    /// File shorter or longer than its header says.
    #[error("file is {actual} bytes but its header describes {expected} bytes (truncated or padded)")]
    Length {
        /// Length the header implies.
        expected: u64,
        /// Actual length.
        actual: u64,
    },
    /// The stored checksum does not match the contents.
    #[error("checksum mismatch: stored {stored:#010x}, computed {computed:#010x} (file corrupted)")]
    Checksum {
        /// Checksum in the file.
        stored: u32,
        /// Checksum of the contents.
        computed: u32,
    },
    /// A header field is out of range.
    #[error("invalid header: {0}")]
    Header(String),
    /// A node's mask (or, in a version 1 or 2 file, its descriptor) is inconsistent.
    #[error("invalid node {slot}: {reason}")]
    Node {
        /// Node number (version 3) or slot in the descriptor array (versions 1 and 2).
        slot: usize,
        /// What is wrong.
        reason: String,
    },
}

/// Why a file has a version this build does not read.
fn version_hint(v: u32) -> &'static str {
    if v > VERSION {
        "; a newer voxray wrote it, or it is damaged"
    } else {
        "; no voxray writes version 0, so the file is damaged"
    }
}

/// Serializes an SVO to bytes.
pub fn to_bytes(svo: &Svo) -> Vec<u8> {
    let masks = svo.masks.len().next_multiple_of(4);
    let mut b =
        Vec::with_capacity(HEADER_LEN_4 + masks + 12 * svo.attrs.len() + EMITTER_BYTES * svo.emitters.len() + 4);
    b.extend_from_slice(&MAGIC);
    b.extend_from_slice(&VERSION.to_le_bytes());
    b.extend_from_slice(&svo.depth.to_le_bytes());
    for v in [svo.bounds.min.x, svo.bounds.min.y, svo.bounds.min.z, svo.bounds.size] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b.extend_from_slice(&svo.voxel_count.to_le_bytes());
    b.extend_from_slice(&(svo.masks.len() as u64).to_le_bytes());
    b.extend_from_slice(&(svo.attrs.len() as u64).to_le_bytes());
    b.extend_from_slice(&(svo.emitters.len() as u64).to_le_bytes());
    debug_assert_eq!(b.len(), HEADER_LEN_4);
    b.extend_from_slice(&svo.masks);
    b.resize(HEADER_LEN_4 + masks, 0);
    for a in &svo.attrs {
        b.extend_from_slice(&a.albedo.to_le_bytes());
        b.extend_from_slice(&a.normal.to_le_bytes());
        b.extend_from_slice(&a.emission.to_le_bytes());
    }
    for e in &svo.emitters {
        for v in e.vertices.iter().chain([&e.emission]) {
            for c in v.to_array() {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    let crc = crc32(&b);
    b.extend_from_slice(&crc.to_le_bytes());
    b
}

/// Writes an SVO file atomically (temporary file, then rename), so a crash never leaves a
/// half-written file behind under the final name.
pub fn save(svo: &Svo, path: &Path) -> Result<(), SvoFileError> {
    let io = |source| SvoFileError::Io { path: path.display().to_string(), source };
    let tmp = path.with_extension(format!("svo.tmp{}", std::process::id()));
    let (partial, mut f) = crate::partial::Partial::create(tmp).map_err(io)?;
    let tmp = partial.path();
    let written = f.write_all(&to_bytes(svo)).and_then(|()| f.sync_all());
    match written.and_then(|()| std::fs::rename(tmp, path)) {
        Ok(()) => Ok(()),
        Err(e) => {
            // A full disk or a failed rename leaves no temporary behind either.
            let _ = std::fs::remove_file(tmp);
            Err(io(e))
        }
    }
}

/// Reads and validates an SVO file. The header is read and checked first (magic number,
/// version, and the length it implies against the file's), so a file that is not an `.svo`
/// or does not match its header is refused without reading the rest.
pub fn load(path: &Path) -> Result<Svo, SvoFileError> {
    let io = |source| SvoFileError::Io { path: path.display().to_string(), source };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    let mut bytes = Vec::new();
    (&mut file).take((HEADER_LEN_4 + 4) as u64).read_to_end(&mut bytes).map_err(io)?;
    // What the header says the whole file must be; a short or foreign file fails here.
    let expected = expected_length(&bytes, len)?;
    bytes.reserve_exact((expected - bytes.len() as u64) as usize);
    file.take(expected - bytes.len() as u64).read_to_end(&mut bytes).map_err(io)?;
    from_bytes(&bytes)
}

/// The file length the header at the start of `b` implies, checked against `actual` (the
/// whole file's length): the magic number, the header's own length and the version first.
fn expected_length(b: &[u8], actual: u64) -> Result<u64, SvoFileError> {
    if b.len() < 8 || b[..8] != MAGIC {
        return Err(SvoFileError::BadMagic);
    }
    if b.len() < HEADER_LEN + 4 || actual < (HEADER_LEN + 4) as u64 {
        return Err(SvoFileError::Length { expected: (HEADER_LEN + 4) as u64, actual });
    }
    let version = u32_at(b, 8);
    if !(1..=VERSION).contains(&version) {
        return Err(SvoFileError::Version(version));
    }
    let head = header_len(version);
    if b.len() < head + 4 || actual < (head + 4) as u64 {
        return Err(SvoFileError::Length { expected: (head + 4) as u64, actual });
    }
    let (node_count, attr_count) = (u64_at(b, 40), u64_at(b, 48));
    let emitter_count = if version >= 4 { u64_at(b, 56) } else { 0 };
    // Checked arithmetic: hostile counts must not overflow or trigger a huge allocation.
    let node_bytes = if version >= 3 { node_count.checked_next_multiple_of(4) } else { node_count.checked_mul(8) };
    let expected = node_bytes
        .zip(attr_count.checked_mul(attr_bytes(version)))
        .and_then(|(n, a)| n.checked_add(a))
        .zip(emitter_count.checked_mul(EMITTER_BYTES as u64))
        .and_then(|(n, e)| n.checked_add(e))
        .and_then(|n| n.checked_add(head as u64 + 4));
    match expected {
        Some(e) if e == actual => Ok(e),
        _ => Err(SvoFileError::Length { expected: expected.unwrap_or(u64::MAX), actual }),
    }
}

/// The format version in a file's header, if it is an `.svo` file at all.
pub fn file_version(path: &Path) -> Option<u32> {
    let mut head = [0u8; 12];
    std::fs::File::open(path).ok()?.read_exact(&mut head).ok()?;
    (head[..8] == MAGIC).then(|| u32_at(&head, 8))
}

fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])
}
fn u64_at(b: &[u8], o: usize) -> u64 {
    (u32_at(b, o) as u64) | ((u32_at(b, o + 4) as u64) << 32)
}
fn f32_at(b: &[u8], o: usize) -> f32 {
    f32::from_bits(u32_at(b, o))
}

/// Parses and validates an SVO from bytes (any supported version).
pub fn from_bytes(b: &[u8]) -> Result<Svo, SvoFileError> {
    expected_length(b, b.len() as u64)?;
    let version = u32_at(b, 8);
    let node_count = u64_at(b, 40);
    let attr_count = u64_at(b, 48);
    let emitter_count = if version >= 4 { u64_at(b, 56) } else { 0 };
    let head = header_len(version);
    let node_bytes = if version >= 3 { node_count.checked_next_multiple_of(4) } else { node_count.checked_mul(8) };
    let body = b.len() - 4;
    let stored = u32_at(b, body);
    let computed = crc32(&b[..body]);
    if stored != computed {
        return Err(SvoFileError::Checksum { stored, computed });
    }
    let depth = u32_at(b, 12);
    if depth == 0 || depth > MAX_DEPTH {
        return Err(SvoFileError::Header(format!("depth {depth} outside 1..={MAX_DEPTH}")));
    }
    let min = Vec3::new(f32_at(b, 16), f32_at(b, 20), f32_at(b, 24));
    let size = f32_at(b, 28);
    if !min.is_finite() || !size.is_finite() || size <= 0.0 {
        return Err(SvoFileError::Header(format!("bounds min {min:?} size {size} not finite and positive")));
    }
    // A voxel must be a normal number and larger than the rounding of the stored corner, or
    // the voxels' positions are not what the file says.
    let voxel = size as f64 / (1u64 << depth) as f64;
    let magnitude = min.abs().max((min + Vec3::splat(size)).abs()).max_element() as f64;
    if !(voxel as f32).is_normal() || voxel < magnitude * f32::EPSILON as f64 {
        return Err(SvoFileError::Header(format!(
            "bounds min {min:?} size {size} at depth {depth}: voxels of {voxel:e} are not representable at coordinates of {magnitude:e} in f32"
        )));
    }
    let voxel_count = u64_at(b, 32);
    if node_count == 0 || attr_count == 0 {
        return Err(SvoFileError::Header("no root node".into()));
    }
    let bounds = Cube { min, size };
    let attrs_at = head + node_bytes.unwrap_or(0) as usize;
    let stride = attr_bytes(version) as usize;
    let attrs: Vec<Attr> = (0..attr_count as usize)
        .map(|k| {
            let at = attrs_at + stride * k;
            let (albedo, normal) = (u32_at(b, at), u32_at(b, at + 4));
            match version {
                1 => Attr::from_version1(albedo, normal),
                2 | 3 => Attr::from_version3(albedo, normal),
                _ => Attr { albedo, normal, emission: u32_at(b, at + 8) },
            }
        })
        .collect();
    if version >= 4 {
        if let Some((k, _)) = attrs.iter().enumerate().find(|(_, a)| a.albedo >> 24 != 0) {
            return Err(SvoFileError::Node { slot: k, reason: "attribute's reserved albedo byte is not zero".into() });
        }
    }
    if emitter_count > MAX_EMITTERS as u64 {
        return Err(SvoFileError::Header(format!("{emitter_count} emissive triangles; at most {MAX_EMITTERS}")));
    }
    let emitters_at = attrs_at + stride * attr_count as usize;
    let mut emitters = Vec::with_capacity(emitter_count as usize);
    for k in 0..emitter_count as usize {
        let v = |j: usize| {
            let at = emitters_at + EMITTER_BYTES * k + 12 * j;
            Vec3::new(f32_at(b, at), f32_at(b, at + 4), f32_at(b, at + 8))
        };
        let e = Emitter { vertices: [v(0), v(1), v(2)], emission: v(3) };
        let finite = e.vertices.iter().all(|p| p.is_finite()) && e.emission.is_finite();
        if !finite || e.emission.min_element() < 0.0 || !(e.area() > 0.0) {
            return Err(SvoFileError::Header(format!(
                "emissive triangle {k} is degenerate or has a negative or non-finite value"
            )));
        }
        emitters.push(e);
    }
    if version < 3 {
        let nodes = (0..node_count as usize)
            .map(|k| legacy::Node(u32_at(b, HEADER_LEN + 8 * k), u32_at(b, HEADER_LEN + 8 * k + 4)));
        return legacy::convert(bounds, depth, &nodes.collect::<Vec<_>>(), &attrs, voxel_count);
    }
    let masks = b[head..head + node_count as usize].to_vec();
    if b[head + node_count as usize..attrs_at].iter().any(|&p| p != 0) {
        return Err(SvoFileError::Header("padding after the masks is not zero".into()));
    }
    Ok(Svo { emitters, ..from_masks(bounds, depth, masks, attrs, voxel_count)? })
}

/// Assembles an SVO from its masks (node order) and attributes, deriving the links and level
/// starts, and checks that the masks describe exactly the given node, voxel and attribute
/// counts, so no link can point outside the arrays.
pub fn from_masks(
    bounds: Cube,
    depth: u32,
    masks: Vec<u8>,
    attrs: Vec<Attr>,
    voxel_count: u64,
) -> Result<Svo, SvoFileError> {
    let bad = |slot: usize, reason: String| SvoFileError::Node { slot, reason };
    let n = masks.len() as u64;
    if n + voxel_count > u32::MAX as u64 {
        return Err(SvoFileError::Header(format!("{n} nodes and {voxel_count} voxels exceed 2^32 − 1")));
    }
    let mut links = Vec::with_capacity(masks.len());
    let mut level_start = vec![0u32];
    // Level l holds nodes level_start[l] .. level_start[l + 1]; each node's children follow
    // the children of the nodes before it, numbered from the end of the level (nodes) or
    // from the end of all nodes (voxels, in the attribute array).
    let (mut begin, mut end) = (0u64, 1u64);
    for l in 0..depth {
        if end > n {
            return Err(SvoFileError::Header(format!(
                "the masks above level {l} need at least {end} nodes, the header says {n}"
            )));
        }
        let mut next = if l + 1 < depth { end } else { n };
        let first_next = next;
        for (k, &m) in masks[begin as usize..end as usize].iter().enumerate() {
            if m == 0 {
                return Err(bad(begin as usize + k, "empty child mask".into()));
            }
            links.push(next as u32);
            next += m.count_ones() as u64;
        }
        level_start.push(end as u32);
        if l + 1 == depth {
            if end != n {
                return Err(SvoFileError::Header(format!("{n} nodes stored but the masks describe {end}")));
            }
            let voxels = next - first_next;
            if voxels != voxel_count {
                return Err(SvoFileError::Header(format!("header says {voxel_count} voxels, tree holds {voxels}")));
            }
        }
        (begin, end) = (end, end + (next - first_next));
    }
    if attrs.len() as u64 != n + voxel_count {
        return Err(SvoFileError::Header(format!(
            "{} attributes stored but the tree uses {}",
            attrs.len(),
            n + voxel_count
        )));
    }
    Ok(Svo {
        bounds,
        depth,
        masks,
        links,
        level_start,
        attrs,
        voxel_count,
        emitters: Vec::new(),
        occupied: Default::default(),
    })
}

/// Checks an in-memory SVO: its links and level starts must be the ones its masks imply
/// (see [`from_masks`]).
pub fn validate(svo: &Svo) -> Result<(), SvoFileError> {
    let derived = from_masks(svo.bounds, svo.depth, svo.masks.clone(), svo.attrs.clone(), svo.voxel_count)?;
    if derived.links != svo.links || derived.level_start != svo.level_start {
        let slot = derived.links.iter().zip(&svo.links).position(|(a, b)| a != b).unwrap_or(0);
        return Err(SvoFileError::Node { slot, reason: "link differs from the one its masks imply".into() });
    }
    Ok(())
}

/// Versions 1 and 2: Laine–Karras child descriptors (`ptr:15 | far:1 | valid:8 | leaf:8`)
/// with an attribute base per node, laid out depth first with far-pointer slots.
mod legacy {
    use super::{from_masks, Attr, Cube, Svo, SvoFileError};

    /// One 64-bit slot: the descriptor and the attribute base of the first valid child.
    #[derive(Clone, Copy)]
    pub struct Node(pub u32, pub u32);

    /// Converts a descriptor tree into masks level by level (a breadth-first walk visits
    /// every level's nodes in Morton order, which is the new node order) and its attributes
    /// into the new order, checking every pointer on the way.
    pub fn convert(bounds: Cube, depth: u32, nodes: &[Node], attrs: &[Attr], voxels: u64) -> Result<Svo, SvoFileError> {
        let bad = |slot: usize, reason: String| SvoFileError::Node { slot, reason };
        let len = nodes.len();
        let mut used = vec![false; len];
        used[0] = true;
        let mut masks = Vec::with_capacity(len);
        let mut out = Vec::with_capacity(attrs.len());
        out.push(attrs[0]);
        let mut level = vec![0usize];
        for l in 0..depth {
            let mut next = Vec::new();
            for &slot in &level {
                let Node(desc, attr_base) = nodes[slot];
                let (valid, leaf) = ((desc >> 8) as u8, desc as u8);
                if valid == 0 {
                    return Err(bad(slot, "empty valid mask".into()));
                }
                let deepest = l + 1 == depth;
                if deepest && leaf != valid {
                    return Err(bad(slot, "children at the deepest level must all be leaves".into()));
                }
                if !deepest && leaf != 0 {
                    return Err(bad(
                        slot,
                        format!("leaf above the deepest level {depth} (not supported since version 3)"),
                    ));
                }
                let count = valid.count_ones() as usize;
                let a = attr_base as usize;
                if a == 0 || a + count > attrs.len() {
                    return Err(bad(slot, format!("attribute range {a}+{count} outside 1..{}", attrs.len())));
                }
                masks.push(valid);
                out.extend_from_slice(&attrs[a..a + count]);
                if deepest {
                    continue;
                }
                let ptr = (desc >> 17) as usize;
                let mut group = slot + ptr;
                if ptr == 0 || group >= len {
                    return Err(bad(slot, format!("child pointer {ptr} out of range")));
                }
                if (desc >> 16) & 1 == 1 {
                    if used[group] {
                        return Err(bad(slot, format!("far slot {group} shared or overlapping")));
                    }
                    used[group] = true;
                    let far = nodes[group].0 as usize;
                    if far == 0 || group + far >= len {
                        return Err(bad(slot, format!("far pointer at slot {group} out of range")));
                    }
                    group += far;
                }
                if group + count > len {
                    return Err(bad(slot, format!("child group {group}+{count} exceeds {len} slots")));
                }
                for k in group..group + count {
                    if used[k] {
                        return Err(bad(slot, format!("child slot {k} shared or overlapping")));
                    }
                    used[k] = true;
                    next.push(k);
                }
            }
            level = next;
        }
        if let Some(slot) = used.iter().position(|u| !u) {
            return Err(bad(slot, "slot not reachable from the root".into()));
        }
        if out.len() != attrs.len() {
            return Err(SvoFileError::Header(format!(
                "{} attributes stored but the tree uses {}",
                attrs.len(),
                out.len()
            )));
        }
        from_masks(bounds, depth, masks, out, voxels)
    }
}

/// CRC-32 (IEEE 802.3, reflected, the zlib polynomial).
pub fn crc32(data: &[u8]) -> u32 {
    static TABLE: std::sync::OnceLock<[u32; 256]> = std::sync::OnceLock::new();
    let table = TABLE.get_or_init(|| {
        let mut t = [0u32; 256];
        for (i, e) in t.iter_mut().enumerate() {
            let mut c = i as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
            }
            *e = c;
        }
        t
    });
    let mut c = !0u32;
    for &byte in data {
        c = table[((c ^ byte as u32) & 0xFF) as usize] ^ (c >> 8);
    }
    !c
}

#[cfg(test)]
mod tests {
    #[test]
    fn crc32_known_value() {
        assert_eq!(super::crc32(b"123456789"), 0xCBF4_3926);
    }
}
