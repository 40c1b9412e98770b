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
//! of the time a per-sample trace takes. T is held as the kernels themselves and applied as stencils
//! ([`super::stencil`]): a few hundred KiB where the expanded sparse form takes hundreds of MiB.

use rayon::prelude::*;

use super::byte_cache::ByteBoundedCache;
use super::rng::{SubRayDraws, RAY_BATCH, SUB_RAY_DIMS};
use super::stencil::{StencilOperator, ViewStencil};
use super::trace::{bilinear, floor, sin_cos_turns, Tracer};
use crate::physics::diffraction::{airy_intensity, sinc2, AiryTable};
use crate::physics::display::{Aperture, DisplayGeometry};
use crate::physics::transport::{EyePosition, TransportMatrix, TransportStats};
use crate::physics::zernike::GRADIENT_BATCH;

/// One tap of a view's kernel: the offset (retinal pixels) from the sample's block origin, its weight and
/// its ∂/∂W_j per derivative term.
pub(super) struct Tap {
    pub(super) dx: i32,
    pub(super) dy: i32,
    pub(super) w: f32,
    pub(super) dw: Vec<f32>,
}

/// What one view's kernel trace found.
pub(super) struct ViewKernel {
    pub(super) taps: Vec<Tap>,
    pub(super) traced: u64,
    pub(super) in_pupil: u64,
    /// The light that entered the pupil, in sub-rays' worth (each weighted by its sampling weight).
    pub(super) power: f64,
}

/// Points spread evenly over the unit pupil disc (a sunflower pattern: radius √((r + ½)/N), golden-angle
/// steps), with the landing shift per point (retinal pixels) and per derivative term: the pupil-sampled
/// kernels use point r for their r-th sub-ray of every view and block, so the wavefront's gradient is
/// evaluated once per point, not once per sub-ray.
struct PupilTable {
    points: Vec<[f64; 2]>,
    shift: Vec<[f64; 2]>,
    /// `n_terms` per point.
    term_shift: Vec<[f64; 2]>,
    /// The largest |shift| component over the table, retinal pixels.
    max_shift: f64,
}

impl PupilTable {
    fn new(tracer: &Tracer<'_>, n: usize) -> Self {
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let points: Vec<[f64; 2]> = (0..n)
            .map(|r| {
                let rho = ((r as f64 + 0.5) / n as f64).sqrt();
                let (s, c) = (golden * r as f64).sin_cos();
                [rho * c, rho * s]
            })
            .collect();
        let k = tracer.shift_per_grad;
        let shift: Vec<[f64; 2]> = points
            .iter()
            .map(|p| {
                let g = tracer.poly.gradient(p[0], p[1]);
                [k * g[0], k * g[1]]
            })
            .collect();
        let term_shift = points
            .iter()
            .flat_map(|p| {
                tracer.term_polys.iter().map(move |tp| {
                    let g = tp.gradient(p[0], p[1]);
                    [k * g[0], k * g[1]]
                })
            })
            .collect();
        let max_shift = shift.iter().fold(0f64, |m, s| m.max(s[0].abs()).max(s[1].abs()));
        Self {
            points,
            shift,
            term_shift,
            max_shift,
        }
    }
}

/// One axis of where the undiffracted sub-ray from point `u` of the aperture (`s`: u for a pinhole, 0 for the
/// collimating lenslet) meets the pupil plane, from a block `aimed` = m·p_h(1 + g/d) over, the view's offset `off`
/// and the point in the screen pixel `jitter` (the module's equation for P without the diffraction angle), for
/// an eye `eye` aside at `d_eye`: [`Tracer::ray_start`]'s and [`PinholeBatch`]'s.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn chief_axis(u: f64, s: f64, aimed: f64, off: f64, jitter: f64, d_eye: f64, gap: f64, eye: f64) -> f64 {
    let num = s - aimed - off - jitter;
    u + d_eye * num / gap - eye
}

/// What a pinhole's pupil-sampled sub-rays need of the geometry, for [`PinholeBatch::trace`].
struct PinholeBatch<'a> {
    airy: &'a AiryTable,
    half_a: f64,
    p_s: f64,
    /// 1 + g/d.
    aim: f64,
    pitch: f64,
    gap: f64,
    d_eye: f64,
    eye: [f64; 2],
    /// The view's offset in its block.
    off: [f64; 2],
    r_p: f64,
    per_distance: f64,
    /// π·a/λ: the Airy argument per radian.
    x_per_theta: f64,
    /// (k − 1)/2, the block's first retinal pixel's centre.
    origin: f64,
    pixel: f64,
}

/// A batch's landings before the wavefront's shift (retinal pixels), Airy arguments and the table's
/// intensities there ([`AiryTable::interpolate`]: meaningful where the table covers the argument).
struct PinholeLandings {
    f: [[f64; RAY_BATCH]; 2],
    x: [f64; RAY_BATCH],
    intensity: [f64; RAY_BATCH],
}

impl Default for PinholeLandings {
    fn default() -> Self {
        Self {
            f: [[0.0; RAY_BATCH]; 2],
            x: [0.0; RAY_BATCH],
            intensity: [0.0; RAY_BATCH],
        }
    }
}

impl PinholeBatch<'_> {
    /// Sub-rays from block `m` with uniforms `u` (point in the aperture, point in the screen pixel) through
    /// the pupil points `points` (unit disc): what [`Tracer::ray_start`] and the pupil-sampled loop compute one
    /// sub-ray at a time, the same operations in the same order but for the disc angle's sine and cosine
    /// ([`sin_cos_turns`]).
    #[inline(always)]
    fn trace_any(&self, u: &[[f64; RAY_BATCH]; 4], points: &[[f64; 2]], m: [i64; 2], out: &mut PinholeLandings) {
        let block = [m[0] as f64 * self.pitch, m[1] as f64 * self.pitch];
        let aimed = [block[0] * self.aim, block[1] * self.aim];
        for (b, p) in points.iter().enumerate().take(RAY_BATCH) {
            let rho = self.half_a * u[0][b].sqrt();
            let (sin, cos) = sin_cos_turns(u[1][b]);
            let at = [rho * cos, rho * sin];
            let mut t2 = 0.0;
            for n in 0..2 {
                let jitter = (u[2 + n][b] - 0.5) * self.p_s;
                let chief = chief_axis(
                    at[n],
                    at[n],
                    aimed[n],
                    self.off[n],
                    jitter,
                    self.d_eye,
                    self.gap,
                    self.eye[n],
                );
                let theta = (p[n] * self.r_p - chief) * self.per_distance;
                t2 += theta * theta;
                out.f[n][b] = self.origin + (at[n] - block[n]) / self.pixel;
            }
            out.x[b] = self.x_per_theta * t2.sqrt();
        }
        for (i, x) in out.intensity.iter_mut().zip(&out.x).take(points.len()) {
            *i = self.airy.interpolate(*x);
        }
    }

    fn trace(&self, u: &[[f64; RAY_BATCH]; 4], points: &[[f64; 2]], m: [i64; 2], out: &mut PinholeLandings) {
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        fn avx2(
            g: &PinholeBatch,
            u: &[[f64; RAY_BATCH]; 4],
            points: &[[f64; 2]],
            m: [i64; 2],
            out: &mut PinholeLandings,
        ) {
            g.trace_any(u, points, m, out)
        }
        #[cfg(target_arch = "x86_64")]
        if super::stencil::has_avx2_fma() {
            // SAFETY: the CPU has the features `avx2` is compiled for.
            return unsafe { avx2(self, u, points, m, out) };
        }
        self.trace_any(u, points, m, out)
    }
}

/// A view's kernel accumulated on a dense box of retinal offsets, with a sorted overflow list for the rare
/// landing outside it.
pub(super) struct KernelBox {
    x0: i64,
    y0: i64,
    width: i64,
    height: i64,
    n_terms: usize,
    w: Vec<f64>,
    dw: Vec<f64>,
    overflow: Vec<(i64, i64, f64, Vec<f64>)>,
}

impl KernelBox {
    pub(super) fn new(x: (i64, i64), y: (i64, i64), n_terms: usize) -> Self {
        let (width, height) = (x.1 - x.0 + 1, y.1 - y.0 + 1);
        let cells = (width * height) as usize;
        Self {
            x0: x.0,
            y0: y.0,
            width,
            height,
            n_terms,
            w: vec![0.0; cells],
            dw: vec![0.0; cells * n_terms],
            overflow: Vec::new(),
        }
    }

    /// Splats a landing at `f` (offset pixels) of weight `weight` with landing derivatives `df` (per term).
    #[inline]
    fn splat(&mut self, f: [f64; 2], weight: f64, df: &[[f64; 2]]) {
        let (lx, ly) = (floor(f[0]), floor(f[1]));
        let (cx, cy) = (lx as i64 - self.x0, ly as i64 - self.y0);
        if df.is_empty() && cx >= 0 && cy >= 0 && cx + 1 < self.width && cy + 1 < self.height {
            // Every corner in the box and no derivative terms (nearly every landing of a viewer's kernels): the
            // bilinear weights of `bilinear` with its arithmetic, without its per-corner floors and checks.
            let (tx, ty) = (f[0] - lx, f[1] - ly);
            let (cell, w) = ((cy * self.width + cx) as usize, self.width as usize);
            self.w[cell] += weight * ((1.0 - tx) * (1.0 - ty));
            self.w[cell + 1] += weight * (tx * (1.0 - ty));
            self.w[cell + w] += weight * ((1.0 - tx) * ty);
            self.w[cell + w + 1] += weight * (tx * ty);
            return;
        }
        self.splat_corners(f, weight, df);
    }

    /// [`Self::splat`] corner by corner, with the overflow list for corners outside the box.
    fn splat_corners(&mut self, f: [f64; 2], weight: f64, df: &[[f64; 2]]) {
        let (fx, fy) = (floor(f[0]) as i64, floor(f[1]) as i64);
        for corner in 0..4u8 {
            let (dx, dy) = (fx + (corner & 1) as i64, fy + (corner >> 1) as i64);
            let (w, dwdf) = bilinear(f, corner);
            let (cx, cy) = (dx - self.x0, dy - self.y0);
            if cx >= 0 && cy >= 0 && cx < self.width && cy < self.height {
                let cell = (cy * self.width + cx) as usize;
                self.w[cell] += weight * w;
                for (t, d) in df.iter().enumerate() {
                    self.dw[cell * self.n_terms + t] += weight * (dwdf[0] * d[0] + dwdf[1] * d[1]);
                }
            } else {
                let dw = df.iter().map(|d| weight * (dwdf[0] * d[0] + dwdf[1] * d[1])).collect();
                self.overflow.push((dx, dy, weight * w, dw));
            }
        }
    }

    /// Adds weight `w` and derivative weights `dw` (per term) at offset (x, y).
    #[inline]
    pub(super) fn add(&mut self, x: i64, y: i64, w: f64, dw: &[f64]) {
        let (cx, cy) = (x - self.x0, y - self.y0);
        if cx >= 0 && cy >= 0 && cx < self.width && cy < self.height {
            let cell = (cy * self.width + cx) as usize;
            self.w[cell] += w;
            for (acc, d) in self.dw[cell * self.n_terms..(cell + 1) * self.n_terms]
                .iter_mut()
                .zip(dw)
            {
                *acc += d;
            }
        } else {
            self.overflow.push((x, y, w, dw.to_vec()));
        }
    }

    /// Adds the outer product `scale`·wx ⊗ wy with its first tap at (x, y), without derivative terms: row by row
    /// where the block lies inside the box, else tap by tap ([`Self::add`]).
    #[inline]
    pub(super) fn add_outer(&mut self, x: i64, y: i64, wx: &[f64], wy: &[f64], scale: f64) {
        let (cx, cy) = (x - self.x0, y - self.y0);
        let (nx, ny) = (wx.len() as i64, wy.len() as i64);
        if cx >= 0 && cy >= 0 && cx + nx <= self.width && cy + ny <= self.height && self.n_terms == 0 {
            for (b, wyb) in wy.iter().enumerate() {
                let row = ((cy + b as i64) * self.width + cx) as usize;
                let s = scale * wyb;
                for (acc, wxa) in self.w[row..row + wx.len()].iter_mut().zip(wx) {
                    *acc += s * wxa;
                }
            }
            return;
        }
        for (b, wyb) in wy.iter().enumerate() {
            for (a, wxa) in wx.iter().enumerate() {
                self.add(x + a as i64, y + b as i64, scale * wxa * wyb, &[]);
            }
        }
    }

    /// The non-zero taps, sorted by (dy, dx).
    pub(super) fn taps(self) -> Vec<Tap> {
        let n_terms = self.n_terms;
        let mut taps: Vec<Tap> = Vec::new();
        for cy in 0..self.height {
            for cx in 0..self.width {
                let cell = (cy * self.width + cx) as usize;
                let dw = &self.dw[cell * n_terms..(cell + 1) * n_terms];
                if self.w[cell] != 0.0 || dw.iter().any(|v| *v != 0.0) {
                    taps.push(Tap {
                        dx: (cx + self.x0) as i32,
                        dy: (cy + self.y0) as i32,
                        w: self.w[cell] as f32,
                        dw: dw.iter().map(|v| *v as f32).collect(),
                    });
                }
            }
        }
        for (dx, dy, w, dw) in self.overflow {
            match taps.iter_mut().find(|t| t.dx == dx as i32 && t.dy == dy as i32) {
                Some(t) => {
                    t.w += w as f32;
                    t.dw.iter_mut().zip(&dw).for_each(|(a, b)| *a += *b as f32);
                }
                None => taps.push(Tap {
                    dx: dx as i32,
                    dy: dy as i32,
                    w: w as f32,
                    dw: dw.iter().map(|v| *v as f32).collect(),
                }),
            }
        }
        taps.sort_by_key(|t| (t.dy, t.dx));
        taps
    }
}

/// One angle-sampled sub-ray, as much of its trace as does not depend on the eye's aberrations: where it lands
/// relative to its block's first retinal pixel before the wavefront moves it (retinal pixels), where it crosses
/// the pupil plane (mm from the pupil's centre), and the power it carries.
#[derive(Clone, Copy)]
struct AimedRay {
    f0: [f32; 2],
    p: [f32; 2],
    w: f32,
}

/// Every view's angle-sampled sub-rays for one display geometry, wavelength, eye position, seed and sampling
/// pupil: aimed at a pupil of radius `r_s` and weighted by the power they carry there, so that the kernels of
/// every eye at that position whose pupil is no wider are the same rays with the ones outside its own pupil
/// dropped (an unbiased restriction) and each landing moved by its own wavefront. Tracing them is most of a
/// kernel's cost; sharing them across the people of an evaluation is why they are held apart.
struct RayBundle {
    views: Vec<Vec<AimedRay>>,
    traced: Vec<u64>,
    /// Blocks on each side of the eye's that the rays come from.
    nb: i64,
}

impl RayBundle {
    /// The bytes the bundle holds (its vectors' capacity, which the cache's bound counts).
    fn bytes(&self) -> usize {
        self.views
            .iter()
            .map(|v| v.capacity() * std::mem::size_of::<AimedRay>())
            .sum::<usize>()
            + self.traced.capacity() * std::mem::size_of::<u64>()
            + std::mem::size_of::<Self>()
    }
}

/// Sampling pupils come in steps of this radius (mm): an eye's rays are those of the next step up.
pub const SAMPLING_PUPIL_STEP_MM: f64 = 0.25;

/// How much memory the process's ray bundles may hold; the oldest go first.
pub const RAY_BUNDLE_CACHE_BYTES: usize = 160 << 20;

/// The smallest pupil radius (mm) whose kernels at `distance_mm` and `wavelength_nm` are made of angle-sampled ray
/// bundles ([`Tracer::samples_angle`]): behind pinholes the radius of the diffraction pattern's first dark ring at
/// the pupil, 1.22·λ·d/a (a pattern wider than the pupil is sampled through the pupil instead); behind lenslets 0,
/// every pupil.
pub fn angle_sampling_radius_mm(display: &DisplayGeometry, wavelength_nm: f64, distance_mm: f64) -> f64 {
    match display.aperture {
        Aperture::Lenslet => 0.0,
        Aperture::Pinhole => 1.22 * wavelength_nm * 1e-6 * distance_mm / display.hole_diameter_mm,
    }
}

fn bundle_cache() -> &'static ByteBoundedCache<RayBundle> {
    static CACHE: std::sync::OnceLock<ByteBoundedCache<RayBundle>> = std::sync::OnceLock::new();
    CACHE.get_or_init(|| ByteBoundedCache::new(RAY_BUNDLE_CACHE_BYTES))
}

impl Tracer<'_> {
    /// View (i, j)'s screen pixel relative to its block's centre, mm.
    pub(super) fn view_offset(&self, i: u32, j: u32) -> [f64; 2] {
        let d = self.display;
        [
            (i as f64 - (d.views_u as f64 - 1.0) / 2.0) * d.screen_pixel_pitch_mm,
            (j as f64 - (d.views_v as f64 - 1.0) / 2.0) * d.screen_pixel_pitch_mm,
        ]
    }

    /// The sub-ray draws of view `view` from the block (`mx`, `my`) over, seeded from the job's seed, the view
    /// and the block.
    fn block_draws(&self, view: u64, mx: i64, my: i64) -> SubRayDraws {
        let block = ((mx + 64) as u64) << 8 | (my + 64) as u64;
        SubRayDraws::new(
            self.options.seed ^ (view << 20 | block).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            self.options.sequence,
        )
    }

    /// A sub-ray of the view at screen offset `off` through the aperture at the origin, from the block `m`
    /// blocks over, from the first four of its uniforms `r`: its point in the aperture (relative to the
    /// aperture's centre) and where the undiffracted ray meets the pupil plane (mm from the pupil's centre).
    fn ray_start(&self, r: &[f64; SUB_RAY_DIMS], m: [i64; 2], off: [f64; 2]) -> ([f64; 2], [f64; 2]) {
        let d = self.display;
        let (a, p_s) = (d.hole_diameter_mm, d.screen_pixel_pitch_mm);
        let aim = 1.0 + d.gap_mm / d.viewing_distance_mm;
        let u = match d.aperture {
            Aperture::Pinhole => {
                let rho = 0.5 * a * r[0].sqrt();
                let (sin, cos) = (std::f64::consts::TAU * r[1]).sin_cos();
                [rho * cos, rho * sin]
            }
            Aperture::Lenslet => [(r[0] - 0.5) * a, (r[1] - 0.5) * a],
        };
        let jitter = [(r[2] - 0.5) * p_s, (r[3] - 0.5) * p_s];
        // The lenslet collimates: its rays leave with the chief ray's slope. num = slope·g.
        let s = match d.aperture {
            Aperture::Pinhole => u,
            Aperture::Lenslet => [0.0, 0.0],
        };
        let eye = [self.eye.x_mm, self.eye.y_mm];
        let chief = std::array::from_fn(|n| {
            chief_axis(
                u[n],
                s[n],
                m[n] as f64 * d.hole_pitch_mm * aim,
                off[n],
                jitter[n],
                self.d_eye,
                d.gap_mm,
                eye[n],
            )
        });
        (u, chief)
    }

    /// The sampling pupil's radius for this eye: its own, rounded up to the next step.
    fn sampling_radius(&self) -> f64 {
        (self.r_p / SAMPLING_PUPIL_STEP_MM - 1e-9).ceil().max(1.0) * SAMPLING_PUPIL_STEP_MM
    }

    /// The bundle of angle-sampled rays this eye's kernels are made of (traced, or the process's copy).
    fn ray_bundle(&self, rays: u32) -> std::sync::Arc<RayBundle> {
        let d = self.display;
        let wave = self.options.wave.expect("a wave-optics build");
        let r_s = self.sampling_radius();
        let nb = wave.neighbour_blocks.max(crate::physics::observer::neighbour_blocks(
            d,
            wave.wavelength_nm,
            2.0 * r_s,
            self.eye,
        ));
        let key = format!(
            "{:?} {} {} {} {} {} {} {}|{} {} {} {}|{} {} {} {} {} {:?}",
            d.aperture,
            d.hole_pitch_mm,
            d.hole_diameter_mm,
            d.views_u,
            d.views_v,
            d.screen_pixel_pitch_mm,
            d.gap_mm,
            d.viewing_distance_mm,
            wave.wavelength_nm,
            self.eye.x_mm,
            self.eye.y_mm,
            self.d_eye,
            rays,
            self.options.seed,
            r_s,
            self.grid.pixel_mm,
            nb,
            self.options.sequence,
        );
        bundle_cache().get_or_make(
            key,
            || {
                let views: Vec<(u32, u32)> = (0..d.views_v)
                    .flat_map(|j| (0..d.views_u).map(move |i| (i, j)))
                    .collect();
                let traced: Vec<(Vec<AimedRay>, u64)> = views
                    .par_iter()
                    .map(|&(i, j)| self.aimed_rays(i, j, rays, r_s, nb as i64))
                    .collect();
                let (views, traced) = traced.into_iter().unzip();
                RayBundle {
                    views,
                    traced,
                    nb: nb as i64,
                }
            },
            RayBundle::bytes,
        )
    }

    /// View (i, j)'s sub-rays, `rays` per block for the blocks whose light can reach the pupil (fewer for the
    /// blocks whose light mostly misses it), each with a diffraction angle drawn among those that enter the
    /// sampling pupil of radius `r_s` and weighted by the power they carry (`DiffractionSampler::*_into_pupil`);
    /// returns them with the number traced.
    fn aimed_rays(&self, i: u32, j: u32, rays: u32, r_s: f64, nb: i64) -> (Vec<AimedRay>, u64) {
        let d = self.display;
        let k = self.options.retina_oversample as f64;
        let (pitch, a, p_s) = (d.hole_pitch_mm, d.hole_diameter_mm, d.screen_pixel_pitch_mm);
        let aim = 1.0 + d.gap_mm / d.viewing_distance_mm;
        let off = self.view_offset(i, j);
        let wave = self.options.wave.expect("a wave-optics build");
        let sampler = self.sampler.expect("a wave-optics build");
        let per_block = d.block_shift_at_pupil_mm(self.d_eye);
        let centre = |e: f64| (-e / per_block).round() as i64;
        let (kx, ky) = (centre(self.eye.x_mm), centre(self.eye.y_mm));
        let view = (j * d.views_u + i) as u64;
        // How far a sub-ray's undiffracted crossing of the pupil plane strays from its block's nominal one (the
        // point in the aperture and in the screen pixel).
        let stray = match d.aperture {
            Aperture::Pinhole => 0.5 * a * (1.0 + self.d_eye / d.gap_mm),
            Aperture::Lenslet => 0.5 * a,
        } + 0.5 * p_s * self.d_eye / d.gap_mm;
        let mut out = Vec::new();
        let mut traced = 0u64;
        for my in ky - nb..=ky + nb {
            for mx in kx - nb..=kx + nb {
                let mut draws = self.block_draws(view, mx, my);
                // Rays in proportion to an upper bound on the block's power in the pupil (from the stray
                // crossing nearest the pupil's centre), at least 16: every block keeps at least as many rays in
                // the pupil as draws of the whole pattern would have put there, and each carries its power times
                // the draws it stands for (`rays` / `block_rays`), so that a thinned block is not dimmed.
                let nominal = |m: i64, o: f64, e: f64| self.d_eye * (-(m as f64) * pitch * aim - o) / d.gap_mm - e;
                let nearest = |c: f64| c.signum() * (c.abs() - stray).max(0.0);
                let bound = sampler.pupil_power_bound(
                    d.aperture == Aperture::Lenslet,
                    a,
                    wave.wavelength_nm,
                    self.d_eye,
                    [
                        nearest(nominal(mx, off[0], self.eye.x_mm)),
                        nearest(nominal(my, off[1], self.eye.y_mm)),
                    ],
                    r_s,
                );
                let block_rays = ((rays as f64 * bound).ceil() as u32).clamp(16.min(rays), rays);
                // Fewer rays stand for the block's `rays`: each carries their share of its power.
                let thinned = rays as f64 / block_rays as f64;
                for _ in 0..block_rays {
                    traced += 1;
                    let r = draws.next_ray();
                    let ([ux, uy], chief) = self.ray_start(&r, [mx, my], off);
                    let (u1, u2) = (r[4], r[5]);
                    let (lambda, d_eye) = (wave.wavelength_nm, self.d_eye);
                    let drawn = match d.aperture {
                        Aperture::Pinhole => sampler.pinhole_angle_into_pupil(a, lambda, d_eye, chief, r_s, u1, u2),
                        Aperture::Lenslet => sampler.lenslet_angle_into_pupil(a, lambda, d_eye, chief, r_s, u1, u2),
                    };
                    let Some((theta, w)) = drawn else {
                        continue;
                    };
                    out.push(AimedRay {
                        f0: [
                            ((k - 1.0) / 2.0 + (ux - mx as f64 * pitch) / self.grid.pixel_mm) as f32,
                            ((k - 1.0) / 2.0 + (uy - my as f64 * pitch) / self.grid.pixel_mm) as f32,
                        ],
                        p: [
                            (chief[0] + self.d_eye * theta[0]) as f32,
                            (chief[1] + self.d_eye * theta[1]) as f32,
                        ],
                        w: (w * thinned) as f32,
                    });
                }
            }
        }
        // The vector grew by doubling: up to twice the rays' bytes, held for as long as the bundle is cached.
        out.shrink_to_fit();
        (out, traced)
    }

    /// Traces view (i, j)'s kernel with `rays` sub-rays per neighbouring block (taps keyed relative to the
    /// block's first retinal pixel), from `bundle` where the angle is sampled; with `power_only`, only the light
    /// entering the pupil is counted and no taps are made. With `batched`, a pinhole's pupil-sampled sub-rays
    /// are traced in batches ([`PinholeBatch`]), the same kernel to rounding; without, one at a time.
    #[allow(clippy::too_many_arguments)]
    fn view_kernel(
        &self,
        i: u32,
        j: u32,
        rays: u32,
        table: &PupilTable,
        bundle: Option<&RayBundle>,
        power_only: bool,
        batched: bool,
    ) -> ViewKernel {
        let d = self.display;
        let k = self.options.retina_oversample as f64;
        let (pitch, a) = (d.hole_pitch_mm, d.hole_diameter_mm);
        let off = self.view_offset(i, j);
        let wave = self.options.wave.expect("a wave-optics build");
        let per_block = d.block_shift_at_pupil_mm(self.d_eye);
        let centre = |e: f64| (-e / per_block).round() as i64;
        let nb = bundle.map_or(wave.neighbour_blocks as i64, |b| b.nb);
        let (kx, ky) = (centre(self.eye.x_mm), centre(self.eye.y_mm));
        let n_terms = self.term_polys.len();
        let lambda_mm = wave.wavelength_nm * 1e-6;
        // The pattern's angular density: Airy π·a²/(4λ²)·[2J₁(x)/x]², x = π·a·θ/λ (it integrates to 1 over the
        // plane of angles); sinc² per axis, (A/λ)²·sinc²(Aθ_x/λ)·sinc²(Aθ_y/λ).
        // The Airy factor from its table (this is the pupil-sampled kernels' inner loop).
        let airy = self.sampler.expect("a wave-optics build").airy_table();
        let (x_per_theta, airy_peak) = (
            std::f64::consts::PI * a / lambda_mm,
            std::f64::consts::PI * a * a / (4.0 * lambda_mm * lambda_mm),
        );
        let density = |t: [f64; 2]| match d.aperture {
            Aperture::Pinhole => airy_peak * airy.intensity(x_per_theta * (t[0] * t[0] + t[1] * t[1]).sqrt()),
            Aperture::Lenslet => (a / lambda_mm).powi(2) * sinc2(a * t[0] / lambda_mm) * sinc2(a * t[1] / lambda_mm),
        };
        let pupil_solid_angle = std::f64::consts::PI * self.r_p * self.r_p / (self.d_eye * self.d_eye);
        let (mut traced, mut in_pupil, mut power) = (0u64, 0u64, 0f64);
        // The box holding every landing: the window's blocks, the aperture, and the largest aberration shift
        // (with a margin for angle-sampled pupil points between the table's).
        let reach = 1.25 * table.max_shift + 2.0;
        let bounds = |kc: i64| {
            let lo = (k - 1.0) / 2.0 + (-0.5 * a - (kc + nb) as f64 * pitch) / self.grid.pixel_mm - reach;
            let hi = (k - 1.0) / 2.0 + (0.5 * a - (kc - nb) as f64 * pitch) / self.grid.pixel_mm + reach;
            (lo.floor() as i64, hi.ceil() as i64 + 1)
        };
        let mut kernel = KernelBox::new(bounds(kx), bounds(ky), n_terms);
        let mut dfs: Vec<[f64; 2]> = vec![[0.0; 2]; n_terms];
        let view = (j * d.views_u + i) as u64;
        if let Some(bundle) = bundle {
            // Angle-sampled: the bundle's rays that enter this eye's pupil, each moved by its wavefront (Eq. 9).
            let v = view as usize;
            traced = bundle.traced[v];
            let r2 = self.r_p * self.r_p;
            // The rays that enter, a batch at a time, their wavefront gradients evaluated side by side
            // (`ZernikePolynomial::gradients`), then splatted one by one in the bundle's order.
            let (mut xs, mut ys) = ([0.0; GRADIENT_BATCH], [0.0; GRADIENT_BATCH]);
            let mut batch: [Option<&AimedRay>; GRADIENT_BATCH] = [None; GRADIENT_BATCH];
            let mut grads = [[0.0; 2]; GRADIENT_BATCH];
            let mut filled = 0;
            let mut flush = |filled: usize,
                             xs: &[f64; GRADIENT_BATCH],
                             ys: &[f64; GRADIENT_BATCH],
                             batch: &[Option<&AimedRay>; GRADIENT_BATCH],
                             kernel: &mut KernelBox| {
                self.poly.gradients(xs, ys, &mut grads);
                for b in 0..filled {
                    let ray = batch[b].expect("a filled slot");
                    for (df, tp) in dfs.iter_mut().zip(&self.term_polys) {
                        let g = tp.gradient(xs[b], ys[b]);
                        *df = [self.shift_per_grad * g[0], self.shift_per_grad * g[1]];
                    }
                    let g = grads[b];
                    let f = [
                        ray.f0[0] as f64 + self.shift_per_grad * g[0],
                        ray.f0[1] as f64 + self.shift_per_grad * g[1],
                    ];
                    kernel.splat(f, ray.w as f64, &dfs);
                }
            };
            for ray in &bundle.views[v] {
                let (px, py) = (ray.p[0] as f64, ray.p[1] as f64);
                if px * px + py * py > r2 {
                    continue;
                }
                in_pupil += 1;
                power += ray.w as f64;
                if power_only {
                    continue;
                }
                (xs[filled], ys[filled], batch[filled]) = (px / self.r_p, py / self.r_p, Some(ray));
                filled += 1;
                if filled == GRADIENT_BATCH {
                    flush(filled, &xs, &ys, &batch, &mut kernel);
                    filled = 0;
                }
            }
            if filled > 0 {
                flush(filled, &xs, &ys, &batch, &mut kernel);
            }
            return ViewKernel {
                taps: kernel.taps(),
                traced,
                in_pupil,
                power,
            };
        }
        // Pupil-sampled (a pattern wider than the pupil): uniform pupil points from the table, each weighted by
        // the pattern's density at the angle that reaches it.
        let per_distance = 1.0 / self.d_eye;
        let aim = 1.0 + d.gap_mm / d.viewing_distance_mm;
        // A sub-ray through pupil point p landing at `f` before the wavefront's shift, with weight `ray_weight`.
        let mut land = |p: usize, f: [f64; 2], ray_weight: f64| {
            if ray_weight == 0.0 {
                return;
            }
            in_pupil += 1;
            power += ray_weight;
            if power_only {
                return;
            }
            dfs.copy_from_slice(&table.term_shift[p * n_terms..(p + 1) * n_terms]);
            let shift = table.shift[p];
            kernel.splat([f[0] + shift[0], f[1] + shift[1]], ray_weight, &dfs);
        };
        if batched && d.aperture == Aperture::Pinhole && table.points.len() >= rays as usize {
            // The same sub-rays a batch at a time: positions, angles, the Airy argument and the table's value
            // there in loops the compiler vectorises (`PinholeBatch`), then the splats one by one (and the
            // formula where the table does not reach).
            let geometry = PinholeBatch {
                airy,
                half_a: 0.5 * a,
                p_s: d.screen_pixel_pitch_mm,
                aim,
                pitch,
                gap: d.gap_mm,
                d_eye: self.d_eye,
                eye: [self.eye.x_mm, self.eye.y_mm],
                off,
                r_p: self.r_p,
                per_distance,
                x_per_theta,
                origin: (k - 1.0) / 2.0,
                pixel: self.grid.pixel_mm,
            };
            let mut u = [[0.0; RAY_BATCH]; 4];
            let mut out = PinholeLandings::default();
            for my in ky - nb..=ky + nb {
                for mx in kx - nb..=kx + nb {
                    let mut draws = self.block_draws(view, mx, my);
                    for first in (0..rays as usize).step_by(RAY_BATCH) {
                        let len = RAY_BATCH.min(rays as usize - first);
                        draws.next_batch(len, &mut u);
                        geometry.trace(&u, &table.points[first..first + len], [mx, my], &mut out);
                        for b in 0..len {
                            traced += 1;
                            let x = out.x[b];
                            let intensity = if airy.covers(x) {
                                out.intensity[b]
                            } else {
                                airy_intensity(x)
                            };
                            let ray_weight = airy_peak * intensity * pupil_solid_angle;
                            land(first + b, [out.f[0][b], out.f[1][b]], ray_weight);
                        }
                    }
                }
            }
        } else {
            for my in ky - nb..=ky + nb {
                for mx in kx - nb..=kx + nb {
                    let mut draws = self.block_draws(view, mx, my);
                    for ray in 0..rays as usize {
                        traced += 1;
                        // The last two uniforms (the angle-sampled rays' diffraction angle) are not used: the
                        // pupil point comes from the table.
                        let ([ux, uy], chief) = self.ray_start(&draws.next_ray(), [mx, my], off);
                        let p = ray % table.points.len();
                        let [rx, ry] = table.points[p];
                        let theta = [
                            (rx * self.r_p - chief[0]) * per_distance,
                            (ry * self.r_p - chief[1]) * per_distance,
                        ];
                        let f = [
                            (k - 1.0) / 2.0 + (ux - mx as f64 * pitch) / self.grid.pixel_mm,
                            (k - 1.0) / 2.0 + (uy - my as f64 * pitch) / self.grid.pixel_mm,
                        ];
                        land(p, f, density(theta) * pupil_solid_angle);
                    }
                }
            }
        }
        ViewKernel {
            taps: kernel.taps(),
            traced,
            in_pupil,
            power,
        }
    }

    /// How this eye's kernels find the pupil: by drawing the diffraction angle among those that enter it (from a
    /// shared [`RayBundle`]; best when the pattern is narrower than the pupil: lenslets, larger holes), or, when
    /// the pattern is wider than the pupil (small holes), by drawing the pupil point uniformly and weighting the
    /// sub-ray by the pattern's density at the angle that reaches it, times the pupil's solid angle. Both are
    /// the same expectation, importance-sampled two ways.
    fn samples_angle(&self) -> bool {
        let lambda_nm = self.options.wave.expect("a wave-optics build").wavelength_nm;
        angle_sampling_radius_mm(self.display, lambda_nm, self.d_eye) <= self.r_p
    }

    /// This eye's tracer at the design position, without derivative terms: the kernels' brightness is counted
    /// there.
    pub(super) fn at_design_position(&self) -> Self {
        Tracer {
            eye: EyePosition::default(),
            term_polys: Vec::new(),
            poly: self.poly.clone(),
            ..*self
        }
    }

    /// Scales every kernel so that `power` (the light a plain image sends into the pupil from the design
    /// position) is seen as k² per pixel: the eye adapted to the display (docs/design.md §2.7).
    pub(super) fn normalise(&self, kernels: &mut [ViewKernel], power: f64) {
        let k2 = (self.options.retina_oversample * self.options.retina_oversample) as f64;
        let w = if power > 0.0 { (k2 / power) as f32 } else { 0.0 };
        for k in kernels {
            for t in &mut k.taps {
                t.w *= w;
                t.dw.iter_mut().for_each(|v| *v *= w);
            }
        }
    }

    /// Every view's kernel, each landing weighted so that a plain image is seen at its own intensity from
    /// the design position (the eye adapted to the display; docs/design.md §2.7).
    fn view_kernels(&self, rays: u32) -> Vec<ViewKernel> {
        if self.uses_quadrature() {
            return self.quadrature_kernels();
        }
        let d = self.display;
        let views: Vec<(u32, u32)> = (0..d.views_v)
            .flat_map(|j| (0..d.views_u).map(move |i| (i, j)))
            .collect();
        let at_design = self.eye.x_mm == 0.0 && self.eye.y_mm == 0.0;
        let table = PupilTable::new(self, rays as usize);
        let design_power: f64 = if at_design {
            0.0
        } else {
            let design = self.at_design_position();
            let bundle = design.samples_angle().then(|| design.ray_bundle(rays));
            views
                .par_iter()
                .map(|&(i, j)| {
                    design
                        .view_kernel(i, j, rays, &table, bundle.as_deref(), true, true)
                        .power
                })
                .sum()
        };
        let bundle = self.samples_angle().then(|| self.ray_bundle(rays));
        let mut kernels: Vec<ViewKernel> = views
            .par_iter()
            .map(|&(i, j)| self.view_kernel(i, j, rays, &table, bundle.as_deref(), false, true))
            .collect();
        let power = if at_design {
            kernels.iter().map(|k| k.power).sum()
        } else {
            design_power
        };
        self.normalise(&mut kernels, power);
        kernels
    }
}

impl TransportMatrix {
    /// Builds a wave-optics T at the design distance from per-view kernels traced with `rays` sub-rays per
    /// view and neighbouring block (see the module's documentation), held as per-view stencils; `tracer`
    /// carries the geometry.
    pub(super) fn build_shift_invariant(tracer: &Tracer<'_>, rays: u32) -> Self {
        let d = tracer.display;
        let mut kernels = tracer.view_kernels(rays);
        let n_terms = tracer.term_polys.len();
        let stats = TransportStats {
            sub_rays_traced: kernels.iter().map(|k| k.traced).sum(),
            sub_rays_in_pupil: kernels.iter().map(|k| k.in_pupil).sum(),
            holes_seen: u64::from(d.holes_x * d.holes_y) * u64::from(kernels.iter().any(|k| k.in_pupil > 0)),
            sub_rays_off_grid: 0,
        };
        if tracer.options.tracked {
            kernels = tracked(d, tracer.eye, tracer.options.retina_oversample, kernels);
        }
        let views = kernels
            .iter()
            .map(|kernel| {
                let taps: Vec<(i64, i64, f32, &[f32])> = kernel
                    .taps
                    .iter()
                    .map(|t| (t.dx as i64, t.dy as i64, t.w, t.dw.as_slice()))
                    .collect();
                ViewStencil::from_taps(&taps, n_terms)
            })
            .collect();
        TransportMatrix {
            grid: tracer.grid,
            derivative_terms: tracer.options.derivative_terms.clone(),
            stats,
            repr: super::Repr::Stencil(StencilOperator::new(d, tracer.options.retina_oversample, views)),
        }
    }
}

/// The kernels of T·R for frames re-indexed for `eye` ([`crate::physics::tracking::retarget`]): R puts into view
/// (i, j) of block b the light of view (σ_u(i), σ_v(j)) of block b + (δ_u(i), δ_v(j)), so the eye's image
/// Σ_b Σ_(i,j) K_(i,j)(r − o_b)·L(b + δ, σ) is Σ_b' Σ_(i,j) K_(i,j)(r − o_b' + δ·k)·L(b', σ) (o_b the block's
/// first retinal pixel, k retinal pixels per hole pitch): view σ's kernel is view (i, j)'s moved by −δ·k.
/// Views nothing is re-indexed from are dark. At the display's edge T·R also passes the light of blocks
/// re-indexed from beyond it, which R leaves dark: the view differs there, as far in as the kernels reach.
fn tracked(
    d: &crate::physics::display::DisplayGeometry,
    eye: EyePosition,
    k: u32,
    kernels: Vec<ViewKernel>,
) -> Vec<ViewKernel> {
    let (mu, mv) = crate::physics::tracking::view_shift(d, eye);
    let (u, v) = (d.views_u as usize, d.views_v as usize);
    let mut out: Vec<ViewKernel> = (0..kernels.len())
        .map(|_| ViewKernel {
            taps: Vec::new(),
            traced: 0,
            in_pupil: 0,
            power: 0.0,
        })
        .collect();
    for (at, mut kernel) in kernels.into_iter().enumerate() {
        let (i, j) = (at % u, at / u);
        let along_u = crate::physics::tracking::view_source(d, i as i64, mu, d.views_u);
        let along_v = crate::physics::tracking::view_source(d, j as i64, mv, d.views_v);
        let (Some((bu, si)), Some((bv, sj))) = (along_u, along_v) else {
            continue;
        };
        for t in &mut kernel.taps {
            t.dx -= (bu * i64::from(k)) as i32;
            t.dy -= (bv * i64::from(k)) as i32;
        }
        out[sj as usize * u + si as usize] = kernel;
    }
    debug_assert!(out.len() == u * v);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::transport::rng::SplitMix64;

    /// The splat's fast path (every corner in the box, no derivative terms) gives the corner-by-corner
    /// splat's weights bit for bit, over landings inside, on and past the box's edges.
    #[test]
    fn the_fast_splat_is_the_corner_by_corner_splat() {
        let mut rng = SplitMix64(7);
        let (mut fast, mut corners) = (KernelBox::new((-3, 4), (-2, 5), 0), KernelBox::new((-3, 4), (-2, 5), 0));
        for _ in 0..2000 {
            let f = [rng.next_f64() * 10.0 - 4.5, rng.next_f64() * 10.0 - 3.5];
            let weight = rng.next_f64();
            fast.splat(f, weight, &[]);
            corners.splat_corners(f, weight, &[]);
        }
        assert!(fast.w.iter().all(|w| *w > 0.0), "every cell is reached");
        assert!(!fast.overflow.is_empty(), "some landings reach past the box");
        assert_eq!(fast.w, corners.w);
        assert_eq!(fast.overflow, corners.overflow);
    }

    /// A ray bundle holds no more than its rays (its vectors trimmed when traced, so the cache's bound counts what
    /// is held), and no more than the admission model allows a bundle
    /// (`footprint::*BUNDLE_BYTES_PER_KERNEL_RAY` per view and kernel ray), for the widest pupil a profile may
    /// have, at the shortest and longest wavelengths, on `secure`'s and `lenslet`'s lenslets and `pinhole`'s
    /// pinholes.
    #[test]
    fn a_ray_bundle_holds_its_rays_and_no_more_than_admission_counts() {
        use crate::encoding::footprint::{BUNDLE_BYTES_PER_KERNEL_RAY, PINHOLE_BUNDLE_BYTES_PER_KERNEL_RAY};
        use crate::physics::diffraction::DiffractionSampler;
        use crate::physics::display::DisplayGeometry;
        use crate::physics::transport::{RetinalGrid, TransportOptions, WaveSampling};
        use crate::physics::zernike::ZernikeCoefficients;
        let rays = 682; // `KERNEL_RAYS_PER_SUB_RAY` × 16 sub-rays / 3 wavelengths a band
        for display in [
            DisplayGeometry::secure(),
            DisplayGeometry::lenslet(),
            DisplayGeometry::pinhole(),
        ] {
            for wavelength_nm in [440.0, 650.0] {
                let wavefront = ZernikeCoefficients::new(9.0, vec![0.0; 15]).unwrap();
                let options = TransportOptions {
                    wave: Some(WaveSampling {
                        wavelength_nm,
                        neighbour_blocks: 1,
                        kernel_rays: rays,
                    }),
                    seed: 77,
                    ..Default::default()
                };
                let grid = RetinalGrid::for_display(&display, options.retina_oversample);
                let r_p = wavefront.pupil_radius_mm();
                let tracer = Tracer {
                    display: &display,
                    eye: EyePosition::default(),
                    options: &options,
                    d_eye: display.viewing_distance_mm,
                    grid,
                    r_p,
                    poly: wavefront.polynomial(),
                    term_polys: Vec::new(),
                    shift_per_grad: display.viewing_distance_mm * 1e-3 / grid.pixel_mm / r_p,
                    sampler: Some(DiffractionSampler::shared()),
                    wave_weight: 0.0,
                };
                assert!(tracer.samples_angle(), "a 9 mm pupil samples angles here");
                let bundle = tracer.ray_bundle(rays);
                let held: usize = bundle.views.iter().map(|v| v.len()).sum();
                assert!(held > 0);
                assert!(bundle.views.iter().all(|v| v.capacity() == v.len()));
                assert_eq!(
                    bundle.bytes(),
                    held * std::mem::size_of::<AimedRay>() + bundle.traced.len() * 8 + std::mem::size_of::<RayBundle>()
                );
                let views = (display.views_u * display.views_v) as usize;
                let per_ray = match display.aperture {
                    Aperture::Lenslet => BUNDLE_BYTES_PER_KERNEL_RAY,
                    Aperture::Pinhole => PINHOLE_BUNDLE_BYTES_PER_KERNEL_RAY,
                };
                let allowed = per_ray as usize * views * rays as usize;
                assert!(bundle.bytes() <= allowed, "{} of {allowed}", bundle.bytes());
            }
        }
    }

    /// A pinhole's pupil-sampled kernels traced in batches are those traced one sub-ray at a time, but for the
    /// disc angle's sine and cosine (within 2 ulp): every view's taps at the same offsets, weights and
    /// derivative weights within 1e-6 of the largest (the taps are f32), and the same counts of sub-rays.
    #[test]
    fn batched_pinhole_kernels_are_the_one_at_a_time_kernels() {
        use crate::physics::diffraction::DiffractionSampler;
        use crate::physics::display::DisplayGeometry;
        use crate::physics::transport::{RetinalGrid, TransportOptions, WaveSampling};
        use crate::physics::zernike::{ZernikeCoefficients, ZernikePolynomial};
        let display = DisplayGeometry::paper();
        let mut c = vec![0.0; 28];
        (c[4], c[7], c[8], c[12]) = (0.4, 0.15, -0.1, 0.12);
        let wavefront = ZernikeCoefficients::new(4.5, c).unwrap();
        let options = TransportOptions {
            derivative_terms: vec![4, 7],
            wave: Some(WaveSampling {
                wavelength_nm: 550.0,
                neighbour_blocks: 2,
                kernel_rays: 200,
            }),
            ..Default::default()
        };
        // Aside and at the design position: the eye's offset enters the chief ray.
        for eye in [
            EyePosition::default(),
            EyePosition {
                x_mm: 1.7,
                y_mm: -0.6,
                dz_mm: 0.0,
            },
        ] {
            let grid = RetinalGrid::for_display(&display, options.retina_oversample);
            let r_p = wavefront.pupil_radius_mm();
            let tracer = Tracer {
                display: &display,
                eye,
                options: &options,
                d_eye: display.viewing_distance_mm,
                grid,
                r_p,
                poly: wavefront.polynomial(),
                term_polys: [4, 7].iter().map(|&j| ZernikePolynomial::single_term(j)).collect(),
                shift_per_grad: display.viewing_distance_mm * 1e-3 / grid.pixel_mm / r_p,
                sampler: Some(DiffractionSampler::shared()),
                wave_weight: 0.0,
            };
            assert!(!tracer.samples_angle(), "the paper preset's pinholes are pupil-sampled");
            // 200 rays: three whole batches and a short one.
            let table = PupilTable::new(&tracer, 200);
            for (i, j) in [(0, 0), (2, 3), (4, 4)] {
                let one = tracer.view_kernel(i, j, 200, &table, None, false, false);
                let batch = tracer.view_kernel(i, j, 200, &table, None, false, true);
                assert_eq!((one.traced, one.in_pupil), (batch.traced, batch.in_pupil));
                assert!(
                    (one.power - batch.power).abs() <= 1e-12 * one.power,
                    "{} {}",
                    one.power,
                    batch.power
                );
                assert!(one.in_pupil > 0 && one.taps.len() > 10, "a kernel worth comparing");
                assert_eq!(one.taps.len(), batch.taps.len());
                let largest = one.taps.iter().fold(0f32, |m, t| m.max(t.w.abs()));
                for (a, b) in one.taps.iter().zip(&batch.taps) {
                    assert_eq!((a.dx, a.dy), (b.dx, b.dy));
                    assert!((a.w - b.w).abs() <= 1e-6 * largest, "{} {}", a.w, b.w);
                    for (da, db) in a.dw.iter().zip(&b.dw) {
                        assert!((da - db).abs() <= 1e-6 * (largest + da.abs()), "{da} {db}");
                    }
                }
            }
        }
    }
}
