//! Writing frames: PNG (sRGB 8-bit of the linear radiance), EXR (linear float radiance) and
//! the AOVs as `.npy` files (DESIGN.md: `t.npy`, `instance.npy`, `normal.npy`).

use super::Frame;
use crate::svo::format::linear_to_srgb8;
use std::io::Write;
use std::path::Path;

/// Why output could not be written.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// File system failure.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: String,
        /// The error.
        source: std::io::Error,
    },
    /// Encoding failure.
    #[error("{path}: {message}")]
    Encode {
        /// The path.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// Unknown image extension.
    #[error("{0}: unknown image format (use .png or .exr)")]
    Format(String),
}

/// 8-bit sRGB bytes (RGB) of the frame, radiance clamped to [0, 1] (no tone mapping).
pub fn srgb8(frame: &Frame) -> Vec<u8> {
    encode(&frame.radiance, 3)
}

/// [`srgb8`] with an opaque alpha byte after each pixel (RGBA), as a texture upload takes it.
pub fn srgba8(frame: &Frame) -> Vec<u8> {
    encode(&frame.radiance, 4)
}

/// The radiance as sRGB bytes, `channels` (3 or 4) per pixel, the fourth 255. In parallel
/// bands: the demo converts every frame it shows.
fn encode(radiance: &[glam::Vec3], channels: usize) -> Vec<u8> {
    const BAND: usize = 4096;
    let mut out = vec![255u8; radiance.len() * channels];
    let bytes = crate::pool::Disjoint::new(&mut out);
    crate::pool::for_each_index(radiance.len().div_ceil(BAND), |b| {
        let colours = &radiance[b * BAND..((b + 1) * BAND).min(radiance.len())];
        // SAFETY: band b's bytes are this call's alone.
        let px = unsafe { bytes.run(b * BAND * channels, colours.len() * channels) };
        for (px, c) in px.chunks_exact_mut(channels).zip(colours) {
            px[0] = linear_to_srgb8(c.x);
            px[1] = linear_to_srgb8(c.y);
            px[2] = linear_to_srgb8(c.z);
        }
    });
    out
}

/// Writes a file through a temporary sibling that is renamed over `path` once complete, so an
/// interrupted or failed write (Ctrl-C, a full disk) never leaves a truncated file where an
/// earlier one was. `write` gets the temporary's open handle: reopening it by name could
/// recreate it after Ctrl-C's clean-up had removed it.
fn replace_atomically<E>(
    path: &Path,
    write: impl FnOnce(std::fs::File) -> Result<(), E>,
    io: impl Fn(std::io::Error) -> E,
) -> Result<(), E> {
    let name = path.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
    let ext = path.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}.partial-{}{ext}", std::process::id()));
    let (partial, file) = crate::partial::Partial::create(tmp).map_err(&io)?;
    let tmp = partial.path();
    match write(file) {
        Ok(()) => std::fs::rename(tmp, path).map_err(|e| {
            let _ = std::fs::remove_file(tmp);
            io(e)
        }),
        Err(e) => {
            let _ = std::fs::remove_file(tmp);
            Err(e)
        }
    }
}

/// Writes `bytes` to `path` through a temporary sibling renamed into place once complete
/// (records, reports, model files: an interrupted run never leaves one half-written).
pub fn write_file(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    replace_atomically(path, |mut f| f.write_all(bytes), |e| e)
}

/// Writes the frame as PNG or EXR, chosen by the extension (replacing an earlier file only
/// once the new one is complete).
#[cfg(feature = "image-io")]
pub fn write_image(frame: &Frame, path: &Path) -> Result<(), OutputError> {
    let label = path.display().to_string();
    replace_atomically(
        path,
        |file| encode_image(frame, file, path, &label),
        |source| OutputError::Io { path: label.clone(), source },
    )
}

#[cfg(feature = "image-io")]
fn encode_image(frame: &Frame, file: std::fs::File, path: &Path, label: &str) -> Result<(), OutputError> {
    // Errors name the file asked for, not the temporary one.
    let label = label.to_string();
    let enc = |e: image::ImageError| OutputError::Encode { path: label.clone(), message: e.to_string() };
    let size = || OutputError::Encode { path: label.clone(), message: "size mismatch".into() };
    let mut out = std::io::BufWriter::new(file);
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("png") => image::RgbImage::from_raw(frame.width, frame.height, srgb8(frame))
            .ok_or_else(size)?
            .write_to(&mut out, image::ImageFormat::Png)
            .map_err(enc)?,
        Some("exr") => {
            let data: Vec<f32> = frame.radiance.iter().flat_map(|c| [c.x, c.y, c.z]).collect();
            image::Rgb32FImage::from_raw(frame.width, frame.height, data)
                .ok_or_else(size)?
                .write_to(&mut out, image::ImageFormat::OpenExr)
                .map_err(enc)?
        }
        _ => return Err(OutputError::Format(label)),
    }
    out.flush().map_err(|source| OutputError::Io { path: label.clone(), source })
}

/// Writes an animated GIF from 8-bit sRGB RGB frames (looping).
#[cfg(feature = "image-io")]
pub fn write_gif(path: &Path, width: u32, height: u32, fps: f64, frames: Vec<Vec<u8>>) -> Result<(), OutputError> {
    let label = path.display().to_string();
    replace_atomically(
        path,
        |file| encode_gif(file, &label, width, height, fps, frames),
        |source| OutputError::Io { path: label.clone(), source },
    )
}

#[cfg(feature = "image-io")]
fn encode_gif(
    file: std::fs::File,
    label: &str,
    width: u32,
    height: u32,
    fps: f64,
    frames: Vec<Vec<u8>>,
) -> Result<(), OutputError> {
    use image::codecs::gif::{GifEncoder, Repeat};
    let label = label.to_string();
    let enc = |e: image::ImageError| OutputError::Encode { path: label.clone(), message: e.to_string() };
    let mut out = std::io::BufWriter::new(file);
    {
        let mut encoder = GifEncoder::new_with_speed(&mut out, 10);
        encoder.set_repeat(Repeat::Infinite).map_err(enc)?;
        let delay = image::Delay::from_numer_denom_ms((1000.0 / fps).round().max(10.0) as u32, 1);
        for rgb in frames {
            let rgba: Vec<u8> = rgb.chunks_exact(3).flat_map(|c| [c[0], c[1], c[2], 255]).collect();
            let img = image::RgbaImage::from_raw(width, height, rgba)
                .ok_or_else(|| OutputError::Encode { path: label.clone(), message: "size mismatch".into() })?;
            encoder.encode_frame(image::Frame::from_parts(img, 0, 0, delay)).map_err(enc)?;
        }
        // Dropping the encoder writes the GIF trailer.
    }
    // Every byte reaches the file, or the error is reported, before it is renamed into place.
    std::io::Write::flush(&mut out).map_err(|source| OutputError::Io { path: label.clone(), source })
}

/// Writes `t.npy`, `instance.npy` and `normal.npy` into `dir` (created if missing), and
/// `ao.npy` (ambient occlusion, 1 = open) when GI's cones made one.
pub fn write_aovs(frame: &Frame, dir: &Path) -> Result<(), OutputError> {
    let io = |p: &Path| {
        let path = p.display().to_string();
        move |source| OutputError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let (h, w) = (frame.height as usize, frame.width as usize);
    let t: Vec<u8> = frame.t.iter().flat_map(|v| v.to_le_bytes()).collect();
    write_npy(&dir.join("t.npy"), "<f4", &[h, w], &t).map_err(io(&dir.join("t.npy")))?;
    let inst: Vec<u8> = frame.instance.iter().flat_map(|v| v.to_le_bytes()).collect();
    write_npy(&dir.join("instance.npy"), "<i4", &[h, w], &inst).map_err(io(&dir.join("instance.npy")))?;
    let n: Vec<u8> = frame.normal.iter().flat_map(|v| [v.x, v.y, v.z]).flat_map(|v| v.to_le_bytes()).collect();
    write_npy(&dir.join("normal.npy"), "<f4", &[h, w, 3], &n).map_err(io(&dir.join("normal.npy")))?;
    if frame.ao.len() == w * h {
        let ao: Vec<u8> = frame.ao.iter().flat_map(|v| v.to_le_bytes()).collect();
        write_npy(&dir.join("ao.npy"), "<f4", &[h, w], &ao).map_err(io(&dir.join("ao.npy")))?;
    }
    Ok(())
}

/// Writes one array in NumPy's `.npy` format (version 1.0, C order), replacing an earlier
/// file only once the new one is complete.
pub fn write_npy(path: &Path, descr: &str, shape: &[usize], data: &[u8]) -> std::io::Result<()> {
    replace_atomically(path, |file| encode_npy(file, descr, shape, data), |e| e)
}

fn encode_npy(file: std::fs::File, descr: &str, shape: &[usize], data: &[u8]) -> std::io::Result<()> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_s = if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_s}, }}");
    // Magic (6) + version (2) + length (2) + header + '\n' must be a multiple of 64.
    let total = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - total % 64) % 64));
    header.push('\n');
    let mut f = std::io::BufWriter::new(file);
    f.write_all(b"\x93NUMPY\x01\x00")?;
    f.write_all(&(header.len() as u16).to_le_bytes())?;
    f.write_all(header.as_bytes())?;
    f.write_all(data)?;
    f.flush()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every pixel of a frame wider than one band, as the formula encodes it: RGB, and RGBA
    /// with opaque alpha.
    #[test]
    fn frames_encode_pixel_by_pixel() {
        let n = 3 * 4096 + 17;
        let radiance: Vec<glam::Vec3> = (0..n)
            .map(|i| {
                let x = i as f32 / n as f32;
                glam::Vec3::new(x, 1.0 - x, (x * 7.3).fract() * 1.2 - 0.1)
            })
            .collect();
        let frame = Frame { width: n as u32, height: 1, radiance: radiance.clone(), ..Frame::default() };
        let (rgb, rgba) = (srgb8(&frame), srgba8(&frame));
        assert_eq!((rgb.len(), rgba.len()), (3 * n, 4 * n));
        for (i, c) in radiance.iter().enumerate() {
            let want = [c.x, c.y, c.z].map(crate::svo::format::linear_to_srgb8_formula);
            assert_eq!(rgb[3 * i..3 * i + 3], want, "pixel {i}");
            assert_eq!(rgba[4 * i..4 * i + 4], [want[0], want[1], want[2], 255], "pixel {i}");
        }
    }

    /// A write that fails half-way leaves the earlier file as it was and no temporary file;
    /// one that succeeds replaces it whole.
    #[test]
    fn files_are_replaced_only_when_complete() {
        let dir = std::env::temp_dir().join(format!("voxray-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.npy");
        write_npy(&path, "<f4", &[1], &1.0f32.to_le_bytes()).unwrap();
        let before = std::fs::read(&path).unwrap();
        let failed: std::io::Result<()> = replace_atomically(
            &path,
            |mut f| {
                f.write_all(b"half a file")?;
                Err(std::io::Error::other("disk full"))
            },
            |e| e,
        );
        assert!(failed.is_err());
        assert_eq!(std::fs::read(&path).unwrap(), before);
        write_npy(&path, "<f4", &[2], &[0u8; 8]).unwrap();
        assert_ne!(std::fs::read(&path).unwrap(), before);
        let names: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, [std::ffi::OsString::from("t.npy")], "temporary files left behind");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
