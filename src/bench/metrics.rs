//! Image error of a frame against a reference frame of the same view: what a quality knob
//! (here the level of detail) costs in picture, to set against what it saves in time.

use crate::render::Frame;

/// How far a frame is from its reference.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
pub struct ImageError {
    /// Root-mean-square difference of the displayed (sRGB 8-bit) images, in [0, 1] units
    /// over all pixels and channels.
    pub rmse: f64,
    /// Fraction of pixels whose coverage differs: hit in one and miss in the other, or a
    /// different instance hit.
    pub mismatch: f64,
    /// Mean relative hit-distance difference |t − t_ref| / t_ref over pixels both hit the
    /// same instance.
    pub depth_rel: f64,
    /// Mean FLIP error of the displayed images (NVIDIA's perceptual metric, 0 = identical,
    /// 1 = maximal), when computed (the `flip` feature).
    #[cfg_attr(feature = "json", serde(default))]
    pub flip: Option<f64>,
}

/// How much GI's indirect light changes from frame to frame of a clip on the pixels whose
/// geometry stayed the same (a still instance hit at the same t in consecutive frames).
/// Light that follows a moving object changes smoothly and has a small second difference;
/// cells popping as voxels cross them do not.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "json", derive(serde::Serialize, serde::Deserialize))]
pub struct Flicker {
    /// Mean |I(k+1) − I(k)| per channel, linear radiance, over the still pixels.
    pub change: f64,
    /// Mean |I(k+1) − 2 I(k) + I(k−1)| per channel over the pixels still in three frames.
    pub jerk: f64,
    /// Mean fraction of the pixels that were still (of three consecutive frames).
    pub still: f64,
}

/// Why two frames cannot be compared.
#[derive(Debug, thiserror::Error)]
#[error("frames differ in size: {0}×{1} vs reference {2}×{3}")]
pub struct SizeMismatch(pub u32, pub u32, pub u32, pub u32);

/// Compares `frame` with `reference` (same camera and size).
pub fn compare(frame: &Frame, reference: &Frame) -> Result<ImageError, SizeMismatch> {
    if (frame.width, frame.height) != (reference.width, reference.height) {
        return Err(SizeMismatch(frame.width, frame.height, reference.width, reference.height));
    }
    let (a, b) = (crate::render::output::srgb8(frame), crate::render::output::srgb8(reference));
    let sq: f64 = a
        .iter()
        .zip(&b)
        .map(|(&x, &y)| {
            let d = (x as f64 - y as f64) / 255.0;
            d * d
        })
        .sum();
    let n = frame.instance.len().max(1) as f64;
    let mut mismatch = 0usize;
    let (mut depth, mut both) = (0.0f64, 0usize);
    for i in 0..frame.instance.len() {
        let (ia, ib) = (frame.instance[i], reference.instance[i]);
        if ia != ib {
            mismatch += 1;
        } else if ia >= 0 && reference.t[i] > 0.0 {
            depth += ((frame.t[i] - reference.t[i]) as f64 / reference.t[i] as f64).abs();
            both += 1;
        }
    }
    Ok(ImageError {
        rmse: (sq / a.len().max(1) as f64).sqrt(),
        mismatch: mismatch as f64 / n,
        depth_rel: depth / both.max(1) as f64,
        flip: flip_mean(frame, reference),
    })
}

/// Mean FLIP error between the displayed (sRGB 8-bit) images, at FLIP's default viewing
/// conditions (0.7 m from a 0.7 m wide 4K monitor, 67 pixels per degree).
#[cfg(feature = "flip")]
pub fn flip_mean(frame: &Frame, reference: &Frame) -> Option<f64> {
    if (frame.width, frame.height) != (reference.width, reference.height) || frame.width == 0 || frame.height == 0 {
        return None;
    }
    let (w, h) = (frame.width, frame.height);
    let img = |f: &Frame| nv_flip::FlipImageRgb8::with_data(w, h, &crate::render::output::srgb8(f));
    let err = nv_flip::flip(img(reference), img(frame), nv_flip::DEFAULT_PIXELS_PER_DEGREE);
    Some(nv_flip::FlipPool::from_image(&err).mean() as f64)
}

/// Without the `flip` feature there is no FLIP.
#[cfg(not(feature = "flip"))]
pub fn flip_mean(_frame: &Frame, _reference: &Frame) -> Option<f64> {
    None
}
