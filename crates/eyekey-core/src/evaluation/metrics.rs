//! Image metrics: contrast-invariant legibility (the NCC judge), PSNR, SSIM, and order statistics.

use crate::imaging;
use image::RgbImage;
use rayon::prelude::*;

/// Default legibility threshold: views scoring at or above it are counted as readable.
/// Calibrated against OCR in `docs/legibility-calibration.md`: the lowest legibility at which tesseract, after
/// an attacker's enhancements, read any of 400 simulated PIN views (its 50 % point is 0.60). People read some
/// noisy views below it, so secrecy claims should also be checked at a stricter threshold.
pub const DEFAULT_THRESHOLD: f64 = 0.38;

/// Photopic luminance from LMS: the CIE 2008 physiologically-relevant V(λ) = 0.68990272 L + 0.34832189 M
/// (CIE 170-2:2015; the LMS→XYZ matrix of `data/README.md` §1).
pub fn luminance(lms: &[f32]) -> Vec<f32> {
    lms.chunks_exact(3)
        .map(|p| 0.689_902_7 * p[0] + 0.348_321_9 * p[1])
        .collect()
}

/// Luminance (Rec. 709 / sRGB weights on linear RGB) of an sRGB image, row-major.
pub fn image_luminance(img: &RgbImage) -> Vec<f32> {
    imaging::linear_rgb(img)
        .iter()
        .map(|c| (0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]) as f32)
        .collect()
}

/// Pearson correlation of two equally long images; 0 when either is constant.
pub fn ncc(a: &[f32], b: &[f32]) -> f64 {
    let n = a.len().min(b.len()) as f64;
    let ma = a.iter().map(|v| *v as f64).sum::<f64>() / n;
    let mb = b.iter().map(|v| *v as f64).sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (*x as f64 - ma, *y as f64 - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    if saa <= 1e-30 || sbb <= 1e-30 {
        0.0
    } else {
        sab / (saa * sbb).sqrt()
    }
}

/// Separable Gaussian blur with edge clamping (σ in pixels; σ = 0 returns a copy).
pub fn gaussian_blur(img: &[f32], width: usize, height: usize, sigma: f64) -> Vec<f32> {
    if sigma <= 0.0 {
        return img.to_vec();
    }
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let ks: f64 = k.iter().sum();
    let k: Vec<f32> = k.iter().map(|v| (v / ks) as f32).collect();
    let mut tmp = vec![0f32; img.len()];
    tmp.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        for (x, out) in row.iter_mut().enumerate() {
            let mut s = 0f32;
            for (i, kv) in k.iter().enumerate() {
                let xx = (x as isize + i as isize - r).clamp(0, width as isize - 1) as usize;
                s += kv * img[y * width + xx];
            }
            *out = s;
        }
    });
    let mut out = vec![0f32; img.len()];
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let mut s = 0f32;
            for (i, kv) in k.iter().enumerate() {
                let yy = (y as isize + i as isize - r).clamp(0, height as isize - 1) as usize;
                s += kv * tmp[yy * width + x];
            }
            *o = s;
        }
    });
    out
}

/// Denoising strengths (σ, pixels) an attacker tries before reading.
pub const DENOISE_SIGMAS: [f64; 3] = [0.0, 0.7, 1.5];

/// Contrast-invariant legibility of a view (luminance, row-major) against the document's luminance:
/// max over [`DENOISE_SIGMAS`] of |NCC(G_σ * view, document)|. A negative image is as readable as a positive.
pub fn legibility(view: &[f32], document: &[f32], width: usize, height: usize) -> f64 {
    DENOISE_SIGMAS
        .iter()
        .map(|&s| ncc(&gaussian_blur(view, width, height, s), document).abs())
        .fold(0.0, f64::max)
}

/// PSNR in dB of `a` against reference `b` for a peak value `peak`.
pub fn psnr(a: &[f32], b: &[f32], peak: f64) -> f64 {
    let mse = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len().max(1) as f64;
    if mse <= 1e-30 {
        return 99.0;
    }
    10.0 * (peak * peak / mse).log10()
}

/// Mean SSIM (Wang, Bovik, Sheikh & Simoncelli 2004): Gaussian window σ = 1.5, K1 = 0.01, K2 = 0.03, data
/// range `range`.
pub fn ssim(a: &[f32], b: &[f32], width: usize, height: usize, range: f64) -> f64 {
    let c1 = (0.01 * range).powi(2) as f32;
    let c2 = (0.03 * range).powi(2) as f32;
    let blur = |v: &[f32]| gaussian_blur(v, width, height, 1.5);
    let mu_a = blur(a);
    let mu_b = blur(b);
    let aa: Vec<f32> = a.iter().map(|v| v * v).collect();
    let bb: Vec<f32> = b.iter().map(|v| v * v).collect();
    let ab: Vec<f32> = a.iter().zip(b).map(|(x, y)| x * y).collect();
    let (saa, sbb, sab) = (blur(&aa), blur(&bb), blur(&ab));
    let mut total = 0.0;
    for i in 0..a.len() {
        let (ma, mb) = (mu_a[i], mu_b[i]);
        let va = saa[i] - ma * ma;
        let vb = sbb[i] - mb * mb;
        let cov = sab[i] - ma * mb;
        total += (((2.0 * ma * mb + c1) * (2.0 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2))) as f64;
    }
    total / a.len().max(1) as f64
}

pub(crate) fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let idx = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[idx.min(sorted.len() - 1)]
}

pub(crate) fn median(v: &mut [f64]) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    percentile(v, 0.5)
}

/// The attacker's contrast stretch: each value mapped linearly so that the image's minimum is 0 and its
/// maximum 1 (a constant image maps to 0).
pub fn stretch_to_unit(values: &[f32]) -> Vec<f32> {
    let (lo, hi) = values
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), v| (a.min(*v), b.max(*v)));
    let span = (hi - lo).max(1e-12);
    values.iter().map(|v| (v - lo) / span).collect()
}
