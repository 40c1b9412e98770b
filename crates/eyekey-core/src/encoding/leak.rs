//! The leak penalty (docs/design.md §3, "Leak penalty"): what a decoy must not see is not a particular noise
//! image but the document, as the attackers look for it.
//!
//! Both attackers start by correlating a view with the document: the legibility score with the document's
//! luminance inside its ink box after denoising (`evaluation::metrics`), the known-font attacker with each
//! character cell's candidate glyphs after denoising and ±1 px shifts (`evaluation::known_font`). A decoy's view
//! `v = A_k L` leaks along a direction `q` (unit norm, zero mean where it is non-zero) by the projection `q·v_a`
//! of each LMS channel `a`. The penalty of a decoy is
//!
//! ```text
//! P_k(L) = Σ_q Σ_a (q · v_a)²,   ∇_L P_k = 2 A_kᵀ g,   g[r·3 + a] = Σ_q (q · v_a) q[r]
//! ```
//!
//! a quadratic form of rank at most 3·|Q| per decoy: unlike a noise target it leaves every other direction of the
//! decoy's view free. The directions are
//! * the document's luminance in its ink box, plain and blurred by σ = 1 and 2 px (the legibility score and the
//!   denoised views both attackers read);
//! * when the text is known, each secret cell's discriminant (its true glyph's template minus the mean of the
//!   other candidates', [`KnownFontAttacker::discriminants`]) at every ±1 px shift: what gives the true glyph
//!   its edge in the attacker's arg-max;
//! * when asked (`leak_learned_reader`) and a learned reader was trained on the document's layout
//!   ([`LearnedReader`]), each secret cell's W_true − W_d for every other digit d: what gives the true digit its
//!   lead in that reader's arg-max.
//!
//! Mean removal makes every direction orthogonal to a flat view, so the penalty never asks a decoy for darkness,
//! only for the absence of the document's pattern.

use crate::evaluation::{gaussian_blur, image_luminance, ink_box, KnownFontAttacker, LearnedReader, INK_MARGIN};
use crate::imaging;

/// The leak directions of one document on one retinal grid.
#[derive(Clone, Debug)]
pub struct LeakPatterns {
    /// Unit-norm, zero-mean directions on the grid, row-major luminance (applied to each LMS channel).
    directions: Vec<Vec<f32>>,
    n_pixels: usize,
}

/// Blurs of the document's luminance whose ink-box patterns are penalised (grid pixels; 0 = unblurred).
pub const LEAK_BLURS: [f64; 3] = [0.0, 1.0, 2.0];

impl LeakPatterns {
    /// The directions for `document` seen on a `width`×`height` grid, with `attacker`'s cell discriminants when
    /// the document's text is known, and with `learned` the lead directions of the learned reader trained on its
    /// layout, where there is one.
    pub fn new(
        document: &image::RgbImage,
        width: u32,
        height: u32,
        attacker: Option<&KnownFontAttacker>,
        learned: bool,
    ) -> Self {
        let (w, h) = (width as usize, height as usize);
        let lum = image_luminance(&imaging::resize(document, width, height));
        let (x0, y0, x1, y1) = ink_box(&lum, w, h, INK_MARGIN);
        let mut directions = Vec::new();
        for sigma in LEAK_BLURS {
            let blurred = gaussian_blur(&lum, w, h, sigma);
            let mut q = vec![0f32; w * h];
            for y in y0..y1 {
                for x in x0..x1 {
                    q[y * w + x] = blurred[y * w + x];
                }
            }
            directions.extend(unit_zero_mean(q, |i| {
                (x0..x1).contains(&(i % w)) && (y0..y1).contains(&(i / w))
            }));
        }
        let glyphs = attacker.map(|a| a.discriminants()).unwrap_or_default();
        // The learned reader's too, where one was trained on this layout (`evaluation::learned`).
        let learned = attacker
            .filter(|_| learned)
            .and_then(|a| LearnedReader::for_document(a, (width, height)))
            .map(|r| r.discriminants())
            .unwrap_or_default();
        // The known-font attacker reads each glyph at every ±1 px shift; the learned reader at its own cells.
        let shifts: Vec<(isize, isize)> = (-1isize..=1)
            .flat_map(|dy| (-1isize..=1).map(move |dx| (dx, dy)))
            .collect();
        let placed = glyphs
            .iter()
            .flat_map(|g| shifts.iter().map(move |s| (g, *s)))
            .chain(learned.iter().map(|g| (g, (0, 0))));
        for (((cx, cy, cw, ch), d), (dx, dy)) in placed {
            let (sx, sy) = (*cx as isize + dx, *cy as isize + dy);
            if sx < 0 || sy < 0 || sx as usize + cw > w || sy as usize + ch > h {
                continue;
            }
            let (sx, sy) = (sx as usize, sy as usize);
            let mut q = vec![0f32; w * h];
            for j in 0..*ch {
                for i in 0..*cw {
                    q[(sy + j) * w + sx + i] = d[j * cw + i];
                }
            }
            let inside = |k: usize| (sx..sx + cw).contains(&(k % w)) && (sy..sy + ch).contains(&(k / w));
            directions.extend(unit_zero_mean(q, inside));
        }
        Self {
            directions,
            n_pixels: w * h,
        }
    }

    /// Number of directions (each applied to 3 LMS channels).
    pub fn len(&self) -> usize {
        self.directions.len()
    }

    /// Whether there is no direction at all (a flat document with no text).
    pub fn is_empty(&self) -> bool {
        self.directions.is_empty()
    }

    /// The projections `q·v_a` of an LMS view `[r·3 + a]`, `[q·3 + a]`.
    pub fn project(&self, view: &[f32]) -> Vec<f64> {
        assert_eq!(view.len(), self.n_pixels * 3, "view size");
        let mut out = Vec::with_capacity(self.directions.len() * 3);
        for q in &self.directions {
            let mut c = [0f64; 3];
            for (r, &qr) in q.iter().enumerate() {
                if qr != 0.0 {
                    for (a, ca) in c.iter_mut().enumerate() {
                        *ca += qr as f64 * view[r * 3 + a] as f64;
                    }
                }
            }
            out.extend_from_slice(&c);
        }
        out
    }

    /// The penalty `Σ (q·v_a)²` of a view.
    pub fn penalty(&self, view: &[f32]) -> f64 {
        self.project(view).iter().map(|c| c * c).sum()
    }

    /// Adds `scale · Σ_q c[q·3 + a] q` to the LMS image `out` (the penalty's gradient image for `scale` = 2 and
    /// `c` the view's projections).
    pub fn accumulate(&self, c: &[f64], scale: f64, out: &mut [f32]) {
        assert_eq!(out.len(), self.n_pixels * 3, "image size");
        for (q, cq) in self.directions.iter().zip(c.chunks_exact(3)) {
            let k = [(scale * cq[0]) as f32, (scale * cq[1]) as f32, (scale * cq[2]) as f32];
            for (r, &qr) in q.iter().enumerate() {
                if qr != 0.0 {
                    for a in 0..3 {
                        out[r * 3 + a] += k[a] * qr;
                    }
                }
            }
        }
    }
}

/// `q` with its mean over the pixels where `inside` holds removed there, scaled to unit norm; none when it is
/// flat.
fn unit_zero_mean(mut q: Vec<f32>, inside: impl Fn(usize) -> bool) -> Option<Vec<f32>> {
    let idx: Vec<usize> = (0..q.len()).filter(|&i| inside(i)).collect();
    if idx.is_empty() {
        return None;
    }
    let mean = idx.iter().map(|&i| q[i] as f64).sum::<f64>() / idx.len() as f64;
    for &i in &idx {
        q[i] -= mean as f32;
    }
    let norm = q.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
    if norm < 1e-6 {
        return None;
    }
    q.iter_mut().for_each(|v| *v = (*v as f64 / norm) as f32);
    Some(q)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluation::DocumentText;
    use crate::imaging::glyphs;

    fn pin() -> (image::RgbImage, KnownFontAttacker) {
        pin_at(4)
    }

    /// The slip "PIN 3907" at font `scale` on a 128×128 page, and its known-font attacker on a 32×32 grid.
    fn pin_at(scale: u32) -> (image::RgbImage, KnownFontAttacker) {
        let text = DocumentText {
            lines: vec!["PIN".into(), "3907".into()],
            scale,
            alphabet: "0123456789".into(),
        };
        let doc = glyphs::render_text(&["PIN", "3907"], 128, 128, scale);
        let attacker = KnownFontAttacker::new(&text, 128, 128, 32, 32).unwrap();
        (doc, attacker)
    }

    #[test]
    fn directions_are_unit_and_blind_to_flat_views() {
        let (doc, attacker) = pin();
        let p = LeakPatterns::new(&doc, 32, 32, Some(&attacker), true);
        // 3 blurs of the ink box, 4 cells at 9 shifts each (all inside a 32×32 grid here) and, this being the
        // `secure` slip the shipped learned reader was trained on, its 9 lead directions per cell when asked.
        assert_eq!(p.len(), 3 + 4 * 9 + 4 * 9);
        assert_eq!(LeakPatterns::new(&doc, 32, 32, Some(&attacker), false).len(), 3 + 4 * 9);
        // Another layout gets no learned reader's directions.
        let (small, other) = pin_at(3);
        assert_eq!(LeakPatterns::new(&small, 32, 32, Some(&other), true).len(), 3 + 4 * 9);
        for q in &p.directions {
            let n: f64 = q.iter().map(|v| (*v as f64).powi(2)).sum();
            assert!((n - 1.0).abs() < 1e-5, "norm² {n}");
        }
        // A flat view, of any colour, projects to zero: mean removal.
        let flat: Vec<f32> = (0..32 * 32).flat_map(|_| [0.3f32, 0.7, 0.1]).collect();
        assert!(p.penalty(&flat) < 1e-8, "{}", p.penalty(&flat));
        // The document itself leaks: its own unblurred ink-box direction alone gives the squared norm of its
        // centred luminance in the box, channel by channel.
        let lum = image_luminance(&imaging::resize(&doc, 32, 32));
        let view: Vec<f32> = lum.iter().flat_map(|&v| [v, 0.0, 0.0]).collect();
        let (x0, y0, x1, y1) = ink_box(&lum, 32, 32, INK_MARGIN);
        let inside: Vec<f64> = (y0..y1)
            .flat_map(|y| (x0..x1).map(move |x| (y, x)))
            .map(|(y, x)| lum[y * 32 + x] as f64)
            .collect();
        let mean = inside.iter().sum::<f64>() / inside.len() as f64;
        let centred: f64 = inside.iter().map(|v| (v - mean).powi(2)).sum();
        let c = p.project(&view);
        assert!(
            (c[0] * c[0] - centred).abs() < 1e-4 * centred,
            "{} vs {centred}",
            c[0] * c[0]
        );
        assert!(c[1].abs() < 1e-9 && c[2].abs() < 1e-9, "other channels see nothing");
    }

    #[test]
    fn the_gradient_image_is_the_penalty_derivative() {
        let (doc, attacker) = pin();
        let p = LeakPatterns::new(&doc, 32, 32, Some(&attacker), true);
        let mut s = 7u64;
        let mut rnd = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        let v: Vec<f32> = (0..32 * 32 * 3).map(|_| rnd()).collect();
        let mut g = vec![0f32; v.len()];
        p.accumulate(&p.project(&v), 2.0, &mut g);
        for &i in &[5usize, 400, 1501, 3000] {
            let h = 1e-2f32;
            let (mut a, mut b) = (v.clone(), v.clone());
            a[i] += h;
            b[i] -= h;
            let fd = (p.penalty(&a) - p.penalty(&b)) / (2.0 * h as f64);
            assert!(
                (fd - g[i] as f64).abs() < 1e-3 * (1.0 + fd.abs()),
                "pixel {i}: {fd} vs {}",
                g[i]
            );
        }
    }
}
