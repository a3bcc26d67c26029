//! The `.svo` file format: a fixed header, the node and attribute arrays, and a CRC-32 over
//! everything before it. Loading checks the checksum and then every pointer and mask, so a
//! corrupted or hostile file gives a typed error instead of a panic or an endless loop.
//! The byte layout is documented in `docs/svo-format.md`.

use super::format::{Attr, Cube, Node, Svo, MAX_DEPTH};
use glam::Vec3;
use std::io::{Read, Write};
use std::path::Path;

/// File magic: the first eight bytes of every `.svo` file.
pub const MAGIC: [u8; 8] = *b"VOXRSVO\0";
/// Current format version. Version 1 (snorm16 normals, no specular lobe) is still read: its
/// normals are re-encoded on load.
pub const VERSION: u32 = 2;
/// Header length in bytes.
pub const HEADER_LEN: usize = 56;

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
    #[error("unsupported .svo version {0} (this build reads version {VERSION})")]
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
    /// A node descriptor, pointer or mask is inconsistent.
    #[error("invalid node at slot {slot}: {reason}")]
    Node {
        /// Slot index in the node array.
        slot: usize,
        /// What is wrong.
        reason: String,
    },
}

/// Serializes an SVO to bytes.
pub fn to_bytes(svo: &Svo) -> Vec<u8> {
    let mut b = Vec::with_capacity(HEADER_LEN + 8 * (svo.nodes.len() + svo.attrs.len()) + 4);
    b.extend_from_slice(&MAGIC);
    b.extend_from_slice(&VERSION.to_le_bytes());
    b.extend_from_slice(&svo.depth.to_le_bytes());
    for v in [svo.bounds.min.x, svo.bounds.min.y, svo.bounds.min.z, svo.bounds.size] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b.extend_from_slice(&svo.voxel_count.to_le_bytes());
    b.extend_from_slice(&(svo.nodes.len() as u64).to_le_bytes());
    b.extend_from_slice(&(svo.attrs.len() as u64).to_le_bytes());
    debug_assert_eq!(b.len(), HEADER_LEN);
    for n in &svo.nodes {
        b.extend_from_slice(&n.desc.to_le_bytes());
        b.extend_from_slice(&n.attr_base.to_le_bytes());
    }
    for a in &svo.attrs {
        b.extend_from_slice(&a.albedo.to_le_bytes());
        b.extend_from_slice(&a.normal.to_le_bytes());
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
    let mut f = std::fs::File::create(&tmp).map_err(io)?;
    f.write_all(&to_bytes(svo)).map_err(io)?;
    f.sync_all().map_err(io)?;
    drop(f);
    std::fs::rename(&tmp, path).map_err(io)
}

/// Reads and validates an SVO file.
pub fn load(path: &Path) -> Result<Svo, SvoFileError> {
    let io = |source| SvoFileError::Io { path: path.display().to_string(), source };
    let mut bytes = Vec::new();
    std::fs::File::open(path).map_err(io)?.read_to_end(&mut bytes).map_err(io)?;
    from_bytes(&bytes)
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

/// Parses and validates an SVO from bytes.
pub fn from_bytes(b: &[u8]) -> Result<Svo, SvoFileError> {
    if b.len() < 8 || b[..8] != MAGIC {
        return Err(SvoFileError::BadMagic);
    }
    if b.len() < HEADER_LEN + 4 {
        return Err(SvoFileError::Length { expected: (HEADER_LEN + 4) as u64, actual: b.len() as u64 });
    }
    let version = u32_at(b, 8);
    if version != VERSION && version != 1 {
        return Err(SvoFileError::Version(version));
    }
    let node_count = u64_at(b, 40);
    let attr_count = u64_at(b, 48);
    // Checked arithmetic: hostile counts must not overflow or trigger a huge allocation.
    let expected = node_count
        .checked_add(attr_count)
        .and_then(|n| n.checked_mul(8))
        .and_then(|n| n.checked_add(HEADER_LEN as u64 + 4));
    if expected != Some(b.len() as u64) {
        return Err(SvoFileError::Length { expected: expected.unwrap_or(u64::MAX), actual: b.len() as u64 });
    }
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
    let voxel_count = u64_at(b, 32);
    if node_count == 0 || attr_count == 0 {
        return Err(SvoFileError::Header("no root node".into()));
    }
    let mut o = HEADER_LEN;
    let mut nodes = Vec::with_capacity(node_count as usize);
    for _ in 0..node_count {
        nodes.push(Node { desc: u32_at(b, o), attr_base: u32_at(b, o + 4) });
        o += 8;
    }
    let mut attrs = Vec::with_capacity(attr_count as usize);
    for _ in 0..attr_count {
        let (albedo, normal) = (u32_at(b, o), u32_at(b, o + 4));
        attrs.push(if version == 1 { Attr::from_version1(albedo, normal) } else { Attr { albedo, normal } });
        o += 8;
    }
    let svo = Svo { bounds: Cube { min, size }, depth, nodes, attrs, voxel_count };
    validate(&svo)?;
    Ok(svo)
}

/// Checks every descriptor reachable from the root: pointers in range and pointing forward
/// (so no cycles), far slots in range, leaf ⊆ valid, leaves only where the depth allows,
/// attribute ranges in bounds, every slot used exactly once, and the voxel count.
pub fn validate(svo: &Svo) -> Result<(), SvoFileError> {
    let n = svo.nodes.len();
    let bad = |slot: usize, reason: String| SvoFileError::Node { slot, reason };
    let mut used = vec![false; n];
    let mut voxels = 0u64;
    let mut attrs_used = 1u64; // the root's
                               // (slot, level) pairs; pointers only go forward, so each slot is pushed at most once if
                               // the `used` check passes, which bounds the loop by the node count.
    let mut stack = vec![(0usize, 0u32)];
    used[0] = true;
    while let Some((slot, level)) = stack.pop() {
        let node = svo.nodes[slot];
        let (valid, leaf) = (node.valid(), node.leaf());
        if valid == 0 {
            return Err(bad(slot, "empty valid mask".into()));
        }
        if leaf & !valid != 0 {
            return Err(bad(slot, format!("leaf mask {leaf:#04x} not within valid mask {valid:#04x}")));
        }
        let child_level = level + 1;
        if child_level == svo.depth && leaf != valid {
            return Err(bad(slot, format!("children at the deepest level {child_level} must all be leaves")));
        }
        let count = valid.count_ones() as u64;
        if node.attr_base as u64 + count > svo.attrs.len() as u64 || node.attr_base == 0 {
            return Err(bad(
                slot,
                format!("attribute range {}+{count} outside 1..{}", node.attr_base, svo.attrs.len()),
            ));
        }
        attrs_used += count;
        for oct in 0..8 {
            if leaf & (1 << oct) != 0 {
                voxels += 1u64 << (3 * (svo.depth - child_level));
            }
        }
        let inner = valid & !leaf;
        if inner == 0 {
            continue;
        }
        let p = slot as u64 + node.ptr() as u64;
        if node.ptr() == 0 || p >= n as u64 {
            return Err(bad(slot, format!("child pointer {} out of range", node.ptr())));
        }
        let group = if node.far() {
            let fs = p as usize;
            if used[fs] {
                return Err(bad(slot, format!("far slot {fs} shared or overlapping")));
            }
            used[fs] = true;
            let g = fs as u64 + svo.nodes[fs].desc as u64;
            if svo.nodes[fs].desc == 0 || g >= n as u64 {
                return Err(bad(slot, format!("far pointer at slot {fs} out of range")));
            }
            g as usize
        } else {
            p as usize
        };
        let m = inner.count_ones() as usize;
        if group + m > n {
            return Err(bad(slot, format!("child group {group}+{m} exceeds {n} slots")));
        }
        for k in 0..m {
            if used[group + k] {
                return Err(bad(slot, format!("child slot {} shared or overlapping", group + k)));
            }
            used[group + k] = true;
            stack.push((group + k, child_level));
        }
    }
    if let Some(slot) = used.iter().position(|u| !u) {
        return Err(bad(slot, "slot not reachable from the root".into()));
    }
    if attrs_used != svo.attrs.len() as u64 {
        return Err(SvoFileError::Header(format!(
            "{} attributes stored but the tree uses {attrs_used}",
            svo.attrs.len()
        )));
    }
    if voxels != svo.voxel_count {
        return Err(SvoFileError::Header(format!("header says {} voxels, tree holds {voxels}", svo.voxel_count)));
    }
    Ok(())
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
