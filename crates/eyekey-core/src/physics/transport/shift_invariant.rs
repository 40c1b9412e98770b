//! The wave-optics operator at the design distance as a sum of per-view convolutions (docs/design.md §2.7):
//! T_n L = Σ_v K_{v,n} ⊛ L_{v,n}.
//!
//! Every block of screen pixels is centred on the line from the design eye through its aperture, so for an
//! eye at the design distance (at any lateral offset e) the light of sample (block b, view v) through the
//! aperture m blocks away enters the pupil at
//!
//! P = u·(1 + d/g) − m·p_h(1 + g/d)·d/g − (d/g)(o_v + j) + d·θ − e   (pinhole; lenslet: u instead of u(1 + d/g)),
//!
//! with u the point in the aperture, o_v the view's offset in its block, j the point in the screen pixel and θ
//! the diffraction angle: nothing depends on where b is. Its retinal landing relative to b's centre,
//! (u − m·p_h) + d·∇W(P) (Eq. 9), does not either. So one kernel per view, traced once with many sub-rays, is
//! every sample's column of T: the operator carries no per-sample jitter noise, and it is built in a fraction
//! of the time a per-sample trace takes. The kernels are expanded into the same CSR layout as a traced T, so
//! the fused products, the adjoint and ∂T/∂W_j are unchanged.

use rayon::prelude::*;

use super::rng::SplitMix64;
use super::trace::{bilinear, finish, Tracer};
use crate::physics::display::Aperture;
use crate::physics::transport::{CsrMatrix, EyePosition, TransportError, TransportMatrix, TransportStats};

/// One tap of a view's kernel: the offset (retinal pixels) from the sample's block origin, its weight and
/// its ∂/∂W_j per derivative term.
struct Tap {
    dx: i32,
    dy: i32,
    w: f32,
    dw: Vec<f32>,
}

/// What one view's kernel trace found.
struct ViewKernel {
    taps: Vec<Tap>,
    traced: u64,
    in_pupil: u64,
}

impl Tracer<'_> {
    /// Traces view (i, j)'s kernel with `rays` sub-rays per neighbouring block, each landing weighted `weight`
    /// (taps keyed relative to the block's first retinal pixel).
    fn view_kernel(&self, i: u32, j: u32, rays: u32, weight: f64) -> ViewKernel {
        let d = self.display;
        let k = self.options.retina_oversample as f64;
        let (pitch, a, p_s) = (d.hole_pitch_mm, d.hole_diameter_mm, d.screen_pixel_pitch_mm);
        let aim = 1.0 + d.gap_mm / d.viewing_distance_mm;
        let off = [
            (i as f64 - (d.views_u as f64 - 1.0) / 2.0) * p_s,
            (j as f64 - (d.views_v as f64 - 1.0) / 2.0) * p_s,
        ];
        let wave = self.options.wave.expect("a wave-optics build");
        let sampler = self.sampler.expect("a wave-optics build");
        let per_block = d.block_shift_at_pupil_mm(self.d_eye);
        let centre = |e: f64| (-e / per_block).round() as i64;
        let nb = wave.neighbour_blocks as i64;
        let (kx, ky) = (centre(self.eye.x_mm), centre(self.eye.y_mm));
        let n_terms = self.term_polys.len();
        let mut entries: Vec<(u64, f64, Vec<f64>)> = Vec::new();
        let (mut traced, mut in_pupil) = (0u64, 0u64);
        let view = (j * d.views_u + i) as u64;
        for my in ky - nb..=ky + nb {
            for mx in kx - nb..=kx + nb {
                let block = ((mx + 64) as u64) << 8 | (my + 64) as u64;
                let mut rng = SplitMix64(self.options.seed ^ (view << 20 | block).wrapping_mul(0x9E37_79B9_7F4A_7C15));
                for _ in 0..rays {
                    traced += 1;
                    let (ux, uy) = match d.aperture {
                        Aperture::Pinhole => {
                            let rho = 0.5 * a * rng.next_f64().sqrt();
                            let (sin, cos) = (std::f64::consts::TAU * rng.next_f64()).sin_cos();
                            (rho * cos, rho * sin)
                        }
                        Aperture::Lenslet => ((rng.next_f64() - 0.5) * a, (rng.next_f64() - 0.5) * a),
                    };
                    let jx = (rng.next_f64() - 0.5) * p_s;
                    let jy = (rng.next_f64() - 0.5) * p_s;
                    let (u1, u2) = (rng.next_f64(), rng.next_f64());
                    let theta = match d.aperture {
                        Aperture::Pinhole => sampler.pinhole_angle(a, wave.wavelength_nm, u1, u2),
                        Aperture::Lenslet => sampler.lenslet_angle(a, wave.wavelength_nm, u1, u2),
                    };
                    // The aperture at the origin, the sample's block m blocks over: num = slope·g.
                    let s = match d.aperture {
                        Aperture::Pinhole => [ux, uy],
                        Aperture::Lenslet => [0.0, 0.0],
                    };
                    let num = [
                        s[0] - mx as f64 * pitch * aim - off[0] - jx,
                        s[1] - my as f64 * pitch * aim - off[1] - jy,
                    ];
                    let px = ux + self.d_eye * (num[0] / d.gap_mm + theta[0]) - self.eye.x_mm;
                    let py = uy + self.d_eye * (num[1] / d.gap_mm + theta[1]) - self.eye.y_mm;
                    let (rx, ry) = (px / self.r_p, py / self.r_p);
                    if rx * rx + ry * ry > 1.0 {
                        continue;
                    }
                    in_pupil += 1;
                    let grad = self.poly.gradient(rx, ry);
                    let f = [
                        (k - 1.0) / 2.0 + (ux - mx as f64 * pitch) / self.grid.pixel_mm + self.shift_per_grad * grad[0],
                        (k - 1.0) / 2.0 + (uy - my as f64 * pitch) / self.grid.pixel_mm + self.shift_per_grad * grad[1],
                    ];
                    let dfs: Vec<[f64; 2]> = self
                        .term_polys
                        .iter()
                        .map(|tp| {
                            let g = tp.gradient(rx, ry);
                            [self.shift_per_grad * g[0], self.shift_per_grad * g[1]]
                        })
                        .collect();
                    let (x0, y0) = (f[0].floor() as i64, f[1].floor() as i64);
                    for corner in 0..4u8 {
                        let (dx, dy) = (x0 + (corner & 1) as i64, y0 + (corner >> 1) as i64);
                        let (w, dwdf) = bilinear(f, corner);
                        let key = ((dy + (1 << 30)) as u64) << 32 | (dx + (1 << 30)) as u64;
                        let dw = dfs.iter().map(|df| weight * (dwdf[0] * df[0] + dwdf[1] * df[1])).collect();
                        entries.push((key, weight * w, dw));
                    }
                }
            }
        }
        entries.sort_unstable_by_key(|e| e.0);
        let mut taps: Vec<Tap> = Vec::new();
        let mut last = u64::MAX;
        for (key, w, dw) in entries {
            if key != last {
                taps.push(Tap {
                    dx: (key & 0xFFFF_FFFF) as i64 as i32 - (1 << 30),
                    dy: (key >> 32) as i64 as i32 - (1 << 30),
                    w: 0.0,
                    dw: vec![0.0; n_terms],
                });
                last = key;
            }
            let t = taps.last_mut().expect("a tap was pushed");
            t.w += w as f32;
            for (a, b) in t.dw.iter_mut().zip(dw) {
                *a += b as f32;
            }
        }
        ViewKernel {
            taps,
            traced,
            in_pupil,
        }
    }

    /// Every view's kernel, each landing weighted so that a plain image is seen at its own intensity from
    /// the design position (the eye adapted to the display; docs/design.md §2.7).
    fn view_kernels(&self, rays: u32) -> Vec<ViewKernel> {
        let d = self.display;
        let views: Vec<(u32, u32)> = (0..d.views_v)
            .flat_map(|j| (0..d.views_u).map(move |i| (i, j)))
            .collect();
        let at_design = self.eye.x_mm == 0.0 && self.eye.y_mm == 0.0;
        let design_count: u64 = if at_design {
            0
        } else {
            let design = Tracer {
                eye: EyePosition::default(),
                term_polys: Vec::new(),
                poly: self.poly.clone(),
                ..*self
            };
            views
                .par_iter()
                .map(|&(i, j)| design.view_kernel(i, j, rays, 1.0).in_pupil)
                .sum()
        };
        let k2 = (self.options.retina_oversample * self.options.retina_oversample) as f64;
        let weight_for = |count: u64| if count > 0 { k2 / count as f64 } else { 0.0 };
        let mut kernels: Vec<ViewKernel> = views
            .par_iter()
            .map(|&(i, j)| self.view_kernel(i, j, rays, 1.0))
            .collect();
        let count = if at_design {
            kernels.iter().map(|k| k.in_pupil).sum()
        } else {
            design_count
        };
        let w = weight_for(count) as f32;
        for k in &mut kernels {
            for t in &mut k.taps {
                t.w *= w;
                t.dw.iter_mut().for_each(|v| *v *= w);
            }
        }
        kernels
    }
}

impl TransportMatrix {
    /// Builds a wave-optics T at the design distance from per-view kernels traced with `rays` sub-rays per
    /// view and neighbouring block (see the module's documentation); `tracer` carries the geometry.
    pub(super) fn build_shift_invariant(tracer: &Tracer<'_>, rays: u32) -> Result<Self, TransportError> {
        let d = tracer.display;
        let kernels = tracer.view_kernels(rays);
        let grid = tracer.grid;
        let k = tracer.options.retina_oversample as i64;
        let n_terms = tracer.term_polys.len();
        let n_cols = d.n_samples_per_band();
        let (w, h) = (grid.width as i64, grid.height as i64);
        // Tᵀ row by row (one row per light-field sample, in frame order).
        let rows: Vec<(Vec<u32>, Vec<f32>, Vec<f32>)> = (0..n_cols)
            .into_par_iter()
            .map(|p| {
                let (x, y, i, j) = d.sample_coords(p);
                let kernel = &kernels[(j * d.views_u + i) as usize];
                let (ox, oy) = (x as i64 * k, y as i64 * k);
                let mut cols = Vec::with_capacity(kernel.taps.len());
                let mut vals = Vec::with_capacity(kernel.taps.len());
                let mut dvals = Vec::with_capacity(kernel.taps.len() * n_terms);
                for t in &kernel.taps {
                    let (gx, gy) = (ox + t.dx as i64, oy + t.dy as i64);
                    if gx < 0 || gy < 0 || gx >= w || gy >= h {
                        continue;
                    }
                    cols.push((gy * w + gx) as u32);
                    vals.push(t.w);
                    dvals.extend_from_slice(&t.dw);
                }
                (cols, vals, dvals)
            })
            .collect();
        let nnz: usize = rows.iter().map(|r| r.0.len()).sum();
        if nnz >= u32::MAX as usize {
            return Err(TransportError::TooLarge(nnz));
        }
        let mut indptr = Vec::with_capacity(n_cols + 1);
        let mut indices = Vec::with_capacity(nnz);
        let mut values = Vec::with_capacity(nnz);
        let mut t_dvalues: Vec<Vec<f32>> = vec![Vec::with_capacity(nnz); n_terms];
        indptr.push(0u32);
        for (cols, vals, dvals) in rows {
            indices.extend_from_slice(&cols);
            values.extend_from_slice(&vals);
            for (e, _) in cols.iter().enumerate() {
                for (t, dv) in t_dvalues.iter_mut().enumerate() {
                    dv.push(dvals[e * n_terms + t]);
                }
            }
            indptr.push(indices.len() as u32);
        }
        let stats = TransportStats {
            sub_rays_traced: kernels.iter().map(|k| k.traced).sum(),
            sub_rays_in_pupil: kernels.iter().map(|k| k.in_pupil).sum(),
            holes_seen: u64::from(d.holes_x * d.holes_y) * u64::from(kernels.iter().any(|k| k.in_pupil > 0)),
            sub_rays_off_grid: 0,
        };
        let adjoint = CsrMatrix {
            n_rows: n_cols,
            n_cols: grid.len(),
            indptr,
            indices,
            values,
        };
        Ok(finish(grid, adjoint, t_dvalues, tracer.options.derivative_terms.clone(), stats))
    }
}
