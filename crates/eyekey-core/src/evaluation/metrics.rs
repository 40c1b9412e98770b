//! Image metrics: contrast-invariant legibility (the NCC judge), PSNR, SSIM, and order statistics.

use crate::imaging;
use image::RgbImage;
use rayon::prelude::*;

/// Default legibility threshold: views scoring at or above it are counted as readable (somebody *might* read
/// them). Calibrated against the known-font attacker in `docs/legibility-calibration.md`: the lowest legibility at
/// which it read any of 1,300 simulated PIN views in six fonts and four layouts under wave optics (0.228, rounded
/// down; its 50 % point is 0.54). Where the document's text is known, the attacker itself is the judge.
pub const DEFAULT_THRESHOLD: f64 = 0.22;

/// The bar a target's view must clear to be called *read* where the document's text is not known (no known-font
/// attacker): the lowest legibility from which the known-font attacker reads at least 99 % of the calibration
/// views in every font and of those within 0.1 above it (docs/legibility-calibration.md: 1,300 views in six fonts
/// and four layouts; from 0.70, 98.3 % are read, and the 0.7–0.8 band 90 %). The judge is asymmetric on purpose: everybody else is held under
/// [`DEFAULT_THRESHOLD`], the level at which somebody *might* read, while the target must reach the level at which
/// a reader almost surely *does*. A target view between the two is neither secret nor read.
pub const READS_THRESHOLD: f64 = 0.80;

/// Pixels the box around the document's ink is grown by ([`ink_box`]): a denoised glyph spreads this far.
pub const INK_MARGIN: usize = 2;

/// Photopic luminance from LMS: the CIE 2008 physiologically-relevant V(λ) = 0.68990272 L + 0.34832189 M
/// (CIE 170-2:2015; the LMS→XYZ matrix of `data/README.md` §1).
pub fn luminance(lms: &[f32]) -> Vec<f32> {
    lms.chunks_exact(3)
        .map(|p| 0.689_902_7 * p[0] + 0.348_321_9 * p[1])
        .collect()
}

/// [`luminance`] of one LMS triple (a viewer's display white, say).
pub fn luminance_of(lms: [f64; 3]) -> f64 {
    0.689_902_7 * lms[0] + 0.348_321_9 * lms[1]
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
/// max over [`DENOISE_SIGMAS`] of |NCC(G_σ * view, document)| inside the box around the document's ink
/// ([`ink_box`], grown by [`INK_MARGIN`]): an attacker looks where the text is, so noise elsewhere in the frame
/// does not dilute the score. A negative image is as readable as a positive.
pub fn legibility(view: &[f32], document: &[f32], width: usize, height: usize) -> f64 {
    legibility_in(
        view,
        document,
        width,
        height,
        ink_box(document, width, height, INK_MARGIN),
    )
}

/// The box (x0, y0, x1, y1, exclusive ends) around the document's ink: pixels more than 0.05 from the
/// document's median luminance, grown by `margin` pixels and clipped to the grid; the whole grid for a flat
/// document.
pub fn ink_box(document: &[f32], width: usize, height: usize, margin: usize) -> (usize, usize, usize, usize) {
    let mut sorted: Vec<f32> = document.to_vec();
    sorted.sort_by(f32::total_cmp);
    let background = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for y in 0..height {
        for x in 0..width {
            if (document[y * width + x] - background).abs() > 0.05 {
                (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
            }
        }
    }
    if x0 == usize::MAX {
        return (0, 0, width, height);
    }
    (
        x0.saturating_sub(margin),
        y0.saturating_sub(margin),
        (x1 + margin).min(width),
        (y1 + margin).min(height),
    )
}

/// The view denoised at each of [`DENOISE_SIGMAS`], in that order: what every attacker starts from.
pub fn denoised(view: &[f32], width: usize, height: usize) -> Vec<Vec<f32>> {
    DENOISE_SIGMAS
        .iter()
        .map(|&s| gaussian_blur(view, width, height, s))
        .collect()
}

/// [`legibility`] in a given box of the grid (x0, y0, x1, y1, exclusive ends): the view is denoised whole, then
/// correlated with the document inside the box only.
pub fn legibility_in(
    view: &[f32],
    document: &[f32],
    width: usize,
    height: usize,
    b: (usize, usize, usize, usize),
) -> f64 {
    legibility_of_denoised(&denoised(view, width, height), document, width, b)
}

/// [`legibility_in`] of a view already denoised ([`denoised`]); `width` is the grid's.
pub fn legibility_of_denoised(
    denoised: &[Vec<f32>],
    document: &[f32],
    width: usize,
    b: (usize, usize, usize, usize),
) -> f64 {
    let crop = |img: &[f32]| -> Vec<f32> {
        (b.1..b.3)
            .flat_map(|y| (b.0..b.2).map(move |x| (x, y)))
            .map(|(x, y)| img[y * width + x])
            .collect()
    };
    let doc = crop(document);
    denoised.iter().map(|v| ncc(&crop(v), &doc).abs()).fold(0.0, f64::max)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ink_box_surrounds_the_text_grown_by_the_margin() {
        // A 20×10 white document with ink at (5..8, 3..5): the box is those pixels grown by 2, clipped.
        let (w, h) = (20, 10);
        let mut doc = vec![1.0f32; w * h];
        for y in 3..5 {
            for x in 5..8 {
                doc[y * w + x] = 0.0;
            }
        }
        assert_eq!(ink_box(&doc, w, h, 2), (3, 1, 10, 7));
        assert_eq!(ink_box(&doc, w, h, 4), (1, 0, 12, 9));
        assert_eq!(ink_box(&vec![0.5; w * h], w, h, 2), (0, 0, w, h));
    }

    #[test]
    fn noise_away_from_the_text_does_not_dilute_legibility() {
        // The view is the document inside the ink box and strong noise everywhere else: legibility in the box
        // is 1 (the view's ink region is an exact copy, σ = 0), while the frame-wide NCC falls well below it.
        let (w, h) = (40, 40);
        let mut doc = vec![1.0f32; w * h];
        for y in 15..25 {
            for x in 12..28 {
                if (x + y) % 3 == 0 {
                    doc[y * w + x] = 0.0;
                }
            }
        }
        let b = ink_box(&doc, w, h, INK_MARGIN);
        let mut state = 12345u64;
        let view: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if x >= b.0 && x < b.2 && y >= b.1 && y < b.3 {
                    doc[i]
                } else {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    (state >> 40) as f32 / (1u64 << 24) as f32 * 8.0
                }
            })
            .collect();
        assert!((legibility(&view, &doc, w, h) - 1.0).abs() < 1e-6);
        assert!(ncc(&view, &doc).abs() < 0.5, "{}", ncc(&view, &doc));
    }
}
