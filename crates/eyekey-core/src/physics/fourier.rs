//! An independent wave-optics model of what one view of one aperture puts on the retina, by Fourier optics
//! (docs/design.md §2.7). It shares nothing with the ray tracer but the display's geometry and the eye's
//! wavefront, and validates the tracer's ray-space approximation of diffraction.
//!
//! A screen point q behind an aperture sends a field U(s) through it: for a pinhole of diameter a, the
//! paraxial spherical wave exp(iπ|s − q|²/(λg)) over the hole; for a lenslet of side A with the screen at its
//! focal plane, the plane wave exp(i2π s·(h − q)/(λf)) over its square. The eye at distance d, focused on the
//! aperture plane, forms (in display-plane coordinates) the coherent image
//!
//! U_r(x) = F⁻¹{ F{U · exp(iπ|s|²/(λd))}(ν) · P(λdν − e) · exp(i2π W(λdν − e)/λ) }(x),
//!
//! Fresnel propagation to the pupil and back through the eye's lens (Goodman, *Introduction to Fourier
//! Optics*, 3rd ed., §4.2 and §6.1), with P the pupil disc centred at the eye's offset e and W the wavefront
//! error. The screen pixel is an incoherent source: |U_r|² is averaged over points spread across it. The
//! intensity is then filtered by the same bilinear tent the tracer splats with and sampled at retinal pixel
//! centres, so the two models' kernels are compared like for like.

use rayon::prelude::*;
use rustfft::num_complex::Complex64;
use rustfft::FftPlanner;

use crate::physics::display::{Aperture, DisplayGeometry};
use crate::physics::observer::neighbour_blocks;
use crate::physics::profile::{ProfileError, VisionProfile};
use crate::physics::spectral::coupling;
use crate::physics::transport::{EyePosition, RetinalGrid};
use crate::physics::zernike::ZernikeCoefficients;

/// Sampling of the Fourier-optics computation.
#[derive(Clone, Copy, Debug)]
pub struct FourierSampling {
    /// Samples per side of the aperture-plane grid (a power of two is fastest).
    pub n: usize,
    /// Side of the aperture-plane grid, mm: it must hold the aperture and the blurred image of it.
    pub extent_mm: f64,
    /// Source points per side spread over the screen pixel.
    pub source_points: u32,
}

/// One view's light on the retina by Fourier optics.
#[derive(Clone, Debug)]
pub struct FourierKernel {
    /// The fraction of the light leaving the aperture that enters the pupil.
    pub power: f64,
    /// (dx, dy, weight): retinal pixels relative to the sample's block origin, as in the transport operator,
    /// the weights summing to `power`.
    pub taps: Vec<(i32, i32, f64)>,
}

/// What is computed: view (i, j) of the block `block` apertures over from the aperture it shines through,
/// seen by an eye with wavefront `wavefront` at `eye` (design distance), at `wavelength_nm`.
#[derive(Clone, Debug)]
pub struct FourierView<'a> {
    /// The display.
    pub display: &'a DisplayGeometry,
    /// The eye's wavefront at the viewing pupil (its pupil radius is the pupil's).
    pub wavefront: &'a ZernikeCoefficients,
    /// Wavelength, nm.
    pub wavelength_nm: f64,
    /// Where the pupil is.
    pub eye: EyePosition,
    /// The view (i, j).
    pub view: (u32, u32),
    /// The sample's block relative to the aperture (m_x, m_y).
    pub block: (i32, i32),
    /// Retinal pixels per hole pitch.
    pub retina_oversample: u32,
}

impl FourierView<'_> {
    /// The screen point's position relative to the aperture's centre, mm, for source point (a, b) of
    /// `per_side` across the pixel.
    fn source(&self, a: u32, b: u32, per_side: u32) -> [f64; 2] {
        let d = self.display;
        let aim = 1.0 + d.gap_mm / d.viewing_distance_mm;
        let p_s = d.screen_pixel_pitch_mm;
        let off = |i: u32, views: u32| (i as f64 - (views as f64 - 1.0) / 2.0) * p_s;
        let jit = |k: u32| ((k as f64 + 0.5) / per_side as f64 - 0.5) * p_s;
        [
            self.block.0 as f64 * d.hole_pitch_mm * aim + off(self.view.0, d.views_u) + jit(a),
            self.block.1 as f64 * d.hole_pitch_mm * aim + off(self.view.1, d.views_v) + jit(b),
        ]
    }

    /// The field leaving the aperture (centred on the grid) from screen point `q`, times the Fresnel factor
    /// exp(iπ|s|²/(λd)).
    fn aperture_field(&self, q: [f64; 2], s: &FourierSampling) -> Vec<Complex64> {
        let d = self.display;
        let lambda = self.wavelength_nm * 1e-6;
        let delta = s.extent_mm / s.n as f64;
        let half = d.hole_diameter_mm / 2.0;
        let mut u = vec![Complex64::new(0.0, 0.0); s.n * s.n];
        for r in 0..s.n {
            let y = (r as f64 - s.n as f64 / 2.0) * delta;
            for c in 0..s.n {
                let x = (c as f64 - s.n as f64 / 2.0) * delta;
                let (inside, phase) = match d.aperture {
                    Aperture::Pinhole => (
                        x * x + y * y <= half * half,
                        ((x - q[0]).powi(2) + (y - q[1]).powi(2)) / (lambda * d.gap_mm),
                    ),
                    Aperture::Lenslet => (
                        x.abs() <= half && y.abs() <= half,
                        -2.0 * (x * q[0] + y * q[1]) / (lambda * d.gap_mm),
                    ),
                };
                if inside {
                    let fresnel = (x * x + y * y) / (lambda * d.viewing_distance_mm);
                    u[r * s.n + c] = Complex64::from_polar(1.0, std::f64::consts::PI * (phase + fresnel));
                }
            }
        }
        u
    }

    /// The pupil's transmission P·exp(i2πW/λ) at every frequency of the FFT grid (its natural order).
    fn pupil(&self, s: &FourierSampling) -> Vec<Complex64> {
        let d = self.display;
        let lambda_mm = self.wavelength_nm * 1e-6;
        let r_p = self.wavefront.pupil_radius_mm();
        let poly = self.wavefront.polynomial();
        let mut h = vec![Complex64::new(0.0, 0.0); s.n * s.n];
        let freq = |k: usize| {
            let k = if k < s.n / 2 { k as f64 } else { k as f64 - s.n as f64 };
            k / s.extent_mm
        };
        for r in 0..s.n {
            let py = lambda_mm * d.viewing_distance_mm * freq(r) - self.eye.y_mm;
            for c in 0..s.n {
                let px = lambda_mm * d.viewing_distance_mm * freq(c) - self.eye.x_mm;
                let (ux, uy) = (px / r_p, py / r_p);
                if ux * ux + uy * uy <= 1.0 {
                    // W in µm, λ in µm. A positive W (a myopic eye's c₂⁰) converges the light more: in this
                    // phase convention (a diverging wave is exp(+iπr²/(λz))) that is exp(−i2πW/λ).
                    let w_um = poly.value(ux, uy);
                    h[r * s.n + c] =
                        Complex64::from_polar(1.0, -2.0 * std::f64::consts::PI * w_um / (self.wavelength_nm * 1e-3));
                }
            }
        }
        h
    }

    /// The retinal intensity on the aperture-plane grid (row-major, centred), averaged over the pixel's
    /// source points, and the fraction of the light that entered the pupil.
    pub fn intensity(&self, s: &FourierSampling) -> (Vec<f64>, f64) {
        let n = s.n;
        let mut planner = FftPlanner::new();
        let fft = planner.plan_fft_forward(n);
        let ifft = planner.plan_fft_inverse(n);
        let pupil = self.pupil(s);
        let mut intensity = vec![0f64; n * n];
        let (mut passed, mut total) = (0.0, 0.0);
        for b in 0..s.source_points {
            for a in 0..s.source_points {
                let mut u = self.aperture_field(self.source(a, b, s.source_points), s);
                shift_centre(&mut u, n);
                fft2(&mut u, n, fft.as_ref());
                total += u.iter().map(|z| z.norm_sqr()).sum::<f64>();
                for (z, p) in u.iter_mut().zip(&pupil) {
                    *z *= p;
                }
                passed += u.iter().map(|z| z.norm_sqr()).sum::<f64>();
                fft2(&mut u, n, ifft.as_ref());
                shift_centre(&mut u, n);
                for (i, z) in intensity.iter_mut().zip(&u) {
                    *i += z.norm_sqr();
                }
            }
        }
        let power = if total > 0.0 { passed / total } else { 0.0 };
        let sum: f64 = intensity.iter().sum();
        if sum > 0.0 {
            intensity.iter_mut().for_each(|v| *v *= power / sum);
        }
        (intensity, power)
    }

    /// The view's kernel on the retinal grid: the intensity tent-filtered at retinal pixel centres, keyed
    /// like the transport operator's columns (pixels relative to the sample's block origin).
    pub fn kernel(&self, s: &FourierSampling) -> FourierKernel {
        let (intensity, power) = self.intensity(s);
        let d = self.display;
        let k = self.retina_oversample.max(1) as f64;
        let pixel = d.hole_pitch_mm / k;
        let delta = s.extent_mm / s.n as f64;
        let mut taps: std::collections::BTreeMap<(i32, i32), f64> = Default::default();
        for r in 0..s.n {
            for c in 0..s.n {
                let v = intensity[r * s.n + c];
                if v == 0.0 {
                    continue;
                }
                let x = (c as f64 - s.n as f64 / 2.0) * delta;
                let y = (r as f64 - s.n as f64 / 2.0) * delta;
                // The tracer's landing coordinate: (k − 1)/2 + (x − m·p_h)/pixel.
                let f = [
                    (k - 1.0) / 2.0 + (x - self.block.0 as f64 * d.hole_pitch_mm) / pixel,
                    (k - 1.0) / 2.0 + (y - self.block.1 as f64 * d.hole_pitch_mm) / pixel,
                ];
                let (x0, y0) = (f[0].floor(), f[1].floor());
                let (tx, ty) = (f[0] - x0, f[1] - y0);
                for (dx, dy, w) in [
                    (0, 0, (1.0 - tx) * (1.0 - ty)),
                    (1, 0, tx * (1.0 - ty)),
                    (0, 1, (1.0 - tx) * ty),
                    (1, 1, tx * ty),
                ] {
                    *taps.entry((y0 as i32 + dy, x0 as i32 + dx)).or_default() += w * v;
                }
            }
        }
        FourierKernel {
            power,
            taps: taps.into_iter().map(|((y, x), w)| (x, y, w)).collect(),
        }
    }
}

/// What `profile` sees of light field `l` (band-interleaved, [`crate::physics::transport`]) from the design
/// position, entirely by Fourier optics: every view's kernel through the aperture and its neighbouring blocks'
/// (as many as [`neighbour_blocks`] finds), per band at its centroid wavelength with the eye's chromatic
/// defocus, normalised as the transport operator is (a plain image seen at its own intensity), convolved
/// with the light field and mixed by the person's spectral coupling. Returns `[r·3 + a]` LMS on the retinal
/// grid with `retina_oversample` pixels per pitch.
pub fn view_lms(
    display: &DisplayGeometry,
    profile: &VisionProfile,
    l: &[f32],
    sampling: FourierSampling,
    retina_oversample: u32,
) -> Result<Vec<f32>, ProfileError> {
    profile.validate()?;
    let k = retina_oversample.max(1);
    let grid = RetinalGrid::for_display(display, k);
    let n_bands = display.n_bands();
    let c = coupling(&display.projectors, &profile.cone_fundamentals()).c;
    let mut out = vec![0f32; grid.len() * 3];
    for (n, projector) in display.projectors.iter().enumerate() {
        let lambda = projector.centroid_nm();
        let wavefront = profile.wavefront_at(lambda)?;
        let nb = neighbour_blocks(
            display,
            lambda,
            2.0 * wavefront.pupil_radius_mm(),
            EyePosition::default(),
        ) as i32;
        let jobs: Vec<((u32, u32), (i32, i32))> = (0..display.views_v)
            .flat_map(|j| (0..display.views_u).map(move |i| (i, j)))
            .flat_map(|v| (-nb..=nb).flat_map(move |my| (-nb..=nb).map(move |mx| (v, (mx, my)))))
            .collect();
        let kernels: Vec<((u32, u32), FourierKernel)> = jobs
            .par_iter()
            .map(|&(view, block)| {
                let fv = FourierView {
                    display,
                    wavefront: &wavefront,
                    wavelength_nm: lambda,
                    eye: EyePosition::default(),
                    view,
                    block,
                    retina_oversample: k,
                };
                (view, fv.kernel(&sampling))
            })
            .collect();
        let total: f64 = kernels.iter().map(|(_, kr)| kr.power).sum();
        let scale = if total > 0.0 { (k * k) as f64 / total } else { 0.0 };
        let band = convolve(display, &grid, &kernels, l, n_bands, n, scale);
        for (r, v) in band.iter().enumerate() {
            for a in 0..3 {
                out[r * 3 + a] += (c[n][a] * v) as f32;
            }
        }
    }
    Ok(out)
}

/// S_n(r) = Σ_(b, v) L_n(b, v) · K_v(r − b·k) · scale, summed over every kernel of every view.
fn convolve(
    display: &DisplayGeometry,
    grid: &RetinalGrid,
    kernels: &[((u32, u32), FourierKernel)],
    l: &[f32],
    n_bands: usize,
    band: usize,
    scale: f64,
) -> Vec<f64> {
    let k = (grid.width / display.holes_x) as i64;
    let (w, h) = (grid.width as i64, grid.height as i64);
    let mut out = vec![0f64; grid.len()];
    for (view, kernel) in kernels {
        for by in 0..display.holes_y {
            for bx in 0..display.holes_x {
                let value = l[display.sample_index(bx, by, view.0, view.1) * n_bands + band] as f64 * scale;
                if value == 0.0 {
                    continue;
                }
                for &(dx, dy, wt) in &kernel.taps {
                    let (gx, gy) = (bx as i64 * k + dx as i64, by as i64 * k + dy as i64);
                    if gx >= 0 && gy >= 0 && gx < w && gy < h {
                        out[(gy * w + gx) as usize] += value * wt;
                    }
                }
            }
        }
    }
    out
}

/// Swaps quadrants so that the grid's centre sample moves to index 0 (and back: n is even).
fn shift_centre(u: &mut [Complex64], n: usize) {
    let h = n / 2;
    for r in 0..h {
        for c in 0..n {
            let (a, b) = (r * n + c, (r + h) * n + (c + h) % n);
            u.swap(a, b);
        }
    }
}

/// A 2-D FFT in place: rows, then columns.
pub(crate) fn fft2(u: &mut [Complex64], n: usize, fft: &dyn rustfft::Fft<f64>) {
    for row in u.chunks_exact_mut(n) {
        fft.process(row);
    }
    let mut col = vec![Complex64::new(0.0, 0.0); n];
    for c in 0..n {
        for r in 0..n {
            col[r] = u[r * n + c];
        }
        fft.process(&mut col);
        for r in 0..n {
            u[r * n + c] = col[r];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::transport::{TransportMatrix, TransportOptions, WaveSampling};

    /// The eye of the comparison: 0.4 µm of defocus, 0.15 µm of astigmatism and 0.1 µm of coma over `pupil_mm`.
    fn eye(pupil_mm: f64) -> ZernikeCoefficients {
        let mut c = vec![0.0; 28];
        c[4] = 0.4;
        c[5] = 0.15;
        c[7] = 0.1;
        ZernikeCoefficients::new(pupil_mm, c).unwrap()
    }

    /// A kernel normalised to sum 1: ((dx, dy), weight).
    type Shape = Vec<((i32, i32), f64)>;

    /// The traced kernel of view `view` of an interior sample: (power relative to `reference`'s, taps
    /// normalised to sum 1, keyed like [`FourierKernel::taps`]).
    fn traced(t: &TransportMatrix, d: &DisplayGeometry, view: (u32, u32), k: i32) -> (f64, Shape) {
        let (bx, by) = (d.holes_x / 2, d.holes_y / 2);
        let p = d.sample_index(bx, by, view.0, view.1);
        let w = t.grid.width as i32;
        let taps: Vec<((i32, i32), f64)> = t
            .column(d, p)
            .into_iter()
            .map(|(row, value)| {
                let row = row as i32;
                ((row % w - bx as i32 * k, row / w - by as i32 * k), value as f64)
            })
            .collect();
        let sum: f64 = taps.iter().map(|t| t.1).sum();
        (sum, taps.into_iter().map(|(key, v)| (key, v / sum)).collect())
    }

    /// Σ |a − b| over the union of two normalised kernels (0: identical, 2: disjoint).
    fn l1(a: &[((i32, i32), f64)], b: &[((i32, i32), f64)]) -> f64 {
        let mut m: std::collections::BTreeMap<(i32, i32), f64> = Default::default();
        for (key, v) in a {
            *m.entry(*key).or_default() += v;
        }
        for (key, v) in b {
            *m.entry(*key).or_default() -= v;
        }
        m.values().map(|v| v.abs()).sum()
    }

    fn compare(
        d: &DisplayGeometry,
        pupil_mm: f64,
        sampling: FourierSampling,
        views: &[(u32, u32)],
    ) -> Vec<(f64, f64, f64)> {
        let w = eye(pupil_mm);
        let k = 2;
        let opts = TransportOptions {
            retina_oversample: k,
            wave: Some(WaveSampling {
                wavelength_nm: 550.0,
                neighbour_blocks: 0,
                kernel_rays: 65_536,
            }),
            ..Default::default()
        };
        let t = TransportMatrix::build(d, &w, EyePosition::default(), &opts).unwrap();
        let centre = (d.views_u / 2, d.views_v / 2);
        let fourier = |view: (u32, u32)| {
            FourierView {
                display: d,
                wavefront: &w,
                wavelength_nm: 550.0,
                eye: EyePosition::default(),
                view,
                block: (0, 0),
                retina_oversample: k,
            }
            .kernel(&sampling)
        };
        let (p_ref, _) = traced(&t, d, centre, k as i32);
        let f_ref = fourier(centre).power;
        views
            .iter()
            .map(|&v| {
                let (p, shape) = traced(&t, d, v, k as i32);
                let f = fourier(v);
                let f_shape: Vec<((i32, i32), f64)> = f.taps.iter().map(|&(x, y, w)| ((x, y), w / f.power)).collect();
                (p / p_ref, f.power / f_ref, l1(&shape, &f_shape))
            })
            .collect()
    }

    #[test]
    fn the_fourier_optics_kernel_of_a_lenslet_view_agrees_with_the_traced_one() {
        // A 1 mm lenslet (the `lenslet` preset's optics) seen by an aberrated eye with a 4 mm pupil: views 0.6 mm
        // apart at the pupil, the central one well inside it, one at 1.8 mm cut by the pupil's edge. The two
        // models must agree on how much of each view enters (relative to the central view) and on where its
        // light lands. The ray-space sampling of diffraction ignores the interference of the field across
        // the aperture (the Fresnel number A²/(λd) is 3.6): the Fourier image has ripples at its edges that
        // the traced one lacks. Measured: powers within 5.4 % (0.649 against 0.684 for the cut view), shapes
        // 0.084 and 0.092 apart in L1 of 2. With the wavefront's sign flipped the shapes are 0.8 and 1.8 apart.
        let d = DisplayGeometry {
            holes_x: 8,
            holes_y: 8,
            ..DisplayGeometry::lenslet()
        };
        let sampling = FourierSampling {
            n: 256,
            extent_mm: 4.0,
            source_points: 4,
        };
        for (v, (traced_power, fourier_power, shape)) in
            [(4, 4), (1, 4)]
                .iter()
                .zip(compare(&d, 4.0, sampling, &[(4, 4), (1, 4)]))
        {
            assert!(
                (traced_power / fourier_power - 1.0).abs() < 0.08,
                "view {v:?}: power {traced_power} vs {fourier_power}"
            );
            assert!(shape < 0.15, "view {v:?}: L1 {shape}");
        }
    }

    #[test]
    fn the_fourier_optics_kernel_of_a_pinhole_view_agrees_with_the_traced_one() {
        // The paper's 80 µm holes: the Airy pattern (4.2 mm to its first zero at the pupil) is far wider than
        // the views' 1.2 mm spacing, so every view sends part of its light into a 6 mm pupil: the corner view
        // a third of the central one's. Measured: powers within 1.2 %, shapes 0.07 to 0.19 apart in L1 (the
        // corner view's image is the one the pupil's edge cuts most).
        let d = DisplayGeometry {
            holes_x: 8,
            holes_y: 8,
            ..DisplayGeometry::paper()
        };
        let sampling = FourierSampling {
            n: 512,
            extent_mm: 2.0,
            source_points: 3,
        };
        for (v, (traced_power, fourier_power, shape)) in
            [(2, 2), (0, 2), (0, 0)]
                .iter()
                .zip(compare(&d, 6.0, sampling, &[(2, 2), (0, 2), (0, 0)]))
        {
            assert!(
                (traced_power / fourier_power - 1.0).abs() < 0.04,
                "view {v:?}: power {traced_power} vs {fourier_power}"
            );
            assert!(shape < 0.25, "view {v:?}: L1 {shape}");
        }
    }

    #[test]
    fn a_perfect_3_mm_pupil_images_a_point_with_the_airy_width_1_03_lambda_over_d() {
        // A 10 µm hole is a point for a 3 mm pupil at 500 mm (its diffraction pattern is flat across the
        // pupil), so the retinal image is the eye's own PSF: FWHM 1.029·λ/D (Born & Wolf §8.5.2), on the display
        // plane 1.029 · 550e-6 · 500 / 3 = 0.0943 mm, which a 3.9 µm grid resolves. The transport operator's
        // retinal pixels (≥ 0.3 mm) cannot show it; this checks the Fourier model's imaging itself.
        let d = DisplayGeometry {
            hole_diameter_mm: 0.01,
            ..DisplayGeometry::paper()
        };
        let w = ZernikeCoefficients::zero(3.0);
        let v = FourierView {
            display: &d,
            wavefront: &w,
            wavelength_nm: 550.0,
            eye: EyePosition::default(),
            view: (2, 2),
            block: (0, 0),
            retina_oversample: 1,
        };
        let s = FourierSampling {
            n: 1024,
            extent_mm: 4.0,
            source_points: 1,
        };
        let (intensity, _) = v.intensity(&s);
        let row = &intensity[s.n / 2 * s.n..(s.n / 2 + 1) * s.n];
        let (peak_at, peak) = row
            .iter()
            .enumerate()
            .fold((0, 0.0), |(i, m), (j, &x)| if x > m { (j, x) } else { (i, m) });
        // Half-maximum crossings on either side, linearly interpolated.
        let crossing = |step: i64| {
            let mut j = peak_at as i64;
            while row[(j + step) as usize] > peak / 2.0 {
                j += step;
            }
            let (a, b) = (row[j as usize], row[(j + step) as usize]);
            j as f64 + step as f64 * (a - peak / 2.0) / (a - b)
        };
        let fwhm = (crossing(1) - crossing(-1)) * s.extent_mm / s.n as f64;
        let expected = 1.029 * 550e-6 * 500.0 / 3.0;
        assert!(
            (fwhm / expected - 1.0).abs() < 0.03,
            "FWHM {fwhm} mm against {expected} mm"
        );
    }
}
