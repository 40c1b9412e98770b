//! Head tracking by re-indexing views: frames encoded for the design eye position, shown to an eye that has
//! moved sideways, without encoding again.
//!
//! At the design distance view i of every aperture crosses the pupil plane at P = −(i − c)·s (c the central
//! view, s = p_s·d/g the view spacing; docs/design.md §2), and the light of the block k over through the same
//! aperture at P − k·T, where T = p_h(1 + g/d)·d/g is the block period at the pupil. An eye moved by e = m·s
//! therefore sees, at each point of its pupil, view i − m where the design eye saw view i: the frames
//! L'(b, i) = L(b, i + m) give it the design eye's retinal image. The m views a block vacates are seen through
//! the same aperture as the neighbouring block's light, T/s views along; they get the design views that part of
//! the moved pupil needs, L'(b, i) = L(b ± 1, i + m ∓ T/s), with T/s rounded to whole screen pixels (the residue
//! is under half a view). Offsets are rounded to whole views (±s/2, 0.3 mm on the `lenslet` preset).
//!
//! What the moved eye sees is then the design view wherever the pupil meets views of the own block (exactly) or
//! of the neighbouring ones (to the rounding of T/s); what it cannot restore is the light of the design views
//! that fall into the gaps between blocks (T − U·s at the pupil, 1 mm of 6.4 mm on the `lenslet` preset). A
//! pupil as wide as the block period sees nearly every view from anywhere, so there the gain is modest (the
//! test below measures it).

use crate::physics::display::DisplayGeometry;
use crate::physics::transport::EyePosition;

/// Views by which frames must be re-indexed for an eye at `eye` (at the design distance): (m_u, m_v) =
/// round(e/s).
pub fn view_shift(display: &DisplayGeometry, eye: EyePosition) -> (i64, i64) {
    let s = display.view_spacing_at_pupil_mm();
    ((eye.x_mm / s).round() as i64, (eye.y_mm / s).round() as i64)
}

/// Screen pixels per block period along an axis: p_h(1 + g/d)/p_s, rounded.
fn period_in_views(display: &DisplayGeometry) -> i64 {
    let aim = 1.0 + display.gap_mm / display.viewing_distance_mm;
    (display.hole_pitch_mm * aim / display.screen_pixel_pitch_mm).round() as i64
}

/// The source (block, view) along one axis of target (block `b`, view `i`) for a shift of `m` views; None
/// where the source lies in a gap between blocks or outside the display.
fn source(b: i64, i: i64, m: i64, views: i64, blocks: i64, period: i64) -> Option<(i64, i64)> {
    let (db, sj) = source_in_blocks(i, m, views, period)?;
    let sb = b + db;
    (0..blocks).contains(&sb).then_some((sb, sj))
}

/// Along one axis, the blocks over (−1, 0 or 1) and the view whose light re-indexing for a shift of `m` views
/// puts into view `i`; None where that would lie in a gap between blocks.
fn source_in_blocks(i: i64, m: i64, views: i64, period: i64) -> Option<(i64, i64)> {
    let j = i + m;
    let (db, sj) = if (0..views).contains(&j) {
        (0, j)
    } else if j >= views {
        (1, j - period)
    } else {
        (-1, j + period)
    };
    (0..views).contains(&sj).then_some((db, sj))
}

/// [`source_in_blocks`] on `display` (`views` along the axis, the block period rounded to whole screen pixels).
pub(crate) fn view_source(display: &DisplayGeometry, i: i64, m: i64, views: u32) -> Option<(i64, i64)> {
    source_in_blocks(i, m, i64::from(views), period_in_views(display))
}

/// Frames `l` (encoded for the design eye position) re-indexed for an eye at `eye` (see the module's
/// documentation); views with no source are dark.
pub fn retarget(display: &DisplayGeometry, l: &[f32], eye: EyePosition) -> Vec<f32> {
    let n = display.n_bands();
    let (mu, mv) = view_shift(display, eye);
    if (mu, mv) == (0, 0) {
        return l.to_vec();
    }
    let period = period_in_views(display);
    let (u, v) = (display.views_u as i64, display.views_v as i64);
    let (bx, by) = (display.holes_x as i64, display.holes_y as i64);
    let mut out = vec![0f32; l.len()];
    for y in 0..by {
        for j in 0..v {
            let Some((sy, sj)) = source(y, j, mv, v, by, period) else {
                continue;
            };
            for x in 0..bx {
                for i in 0..u {
                    let Some((sx, si)) = source(x, i, mu, u, bx, period) else {
                        continue;
                    };
                    let to = display.sample_index(x as u32, y as u32, i as u32, j as u32) * n;
                    let from = display.sample_index(sx as u32, sy as u32, si as u32, sj as u32) * n;
                    out[to..to + n].copy_from_slice(&l[from..from + n]);
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::observer::{Observer, Optics};
    use crate::physics::profile::VisionProfile;
    use crate::physics::transport::{TransportCache, TransportOptions};
    use rand::{Rng, SeedableRng};

    #[test]
    fn a_tracked_eye_past_its_blocks_views_sees_from_off_its_residual() {
        // An eye 4.8 mm right (m = 8 views of 0.6 mm: residual 0) with a 3 mm pupil lies past its own block's views
        // (±2.7 mm): it sees the neighbouring block's light from 3.7 mm on, re-indexed with the block period
        // rounded to 11 screen pixels (0.2 mm off) and meant for 4.6 mm less: −0.9…1.7 mm, centred 0.4 mm from
        // the seat. Wave-optics views of re-indexed frames against design-frame eyes, over the view's central half.
        let (d, cache, topts, mut p) = bench();
        p.pupil_diameter_mm = 3.0;
        let l = zero_mean_frames(&d, 5);
        let at = |x_mm: f64| EyePosition {
            x_mm,
            y_mm: 0.0,
            dz_mm: 0.0,
        };
        let look = |x_mm: f64| Observer::new(&d, &p, at(x_mm), &topts, Optics::Wave, &cache).unwrap();
        let g = look(0.0).grid();
        let centre = |o: &Observer, l: &[f32]| -> Vec<f32> {
            let lum = crate::evaluation::luminance(&o.view(l));
            let (w, h) = (g.width as usize, g.height as usize);
            (h / 4..3 * h / 4)
                .flat_map(|y| lum[y * w + w / 4..y * w + 3 * w / 4].to_vec())
                .collect()
        };
        assert_eq!(view_shift(&d, at(4.8)).0, 8);
        let tracked = centre(&look(4.8), &retarget(&d, &l, at(4.8)));
        let like = |x_mm: f64| crate::evaluation::ncc(&tracked, &centre(&look(x_mm), &l));
        // Measured: 0.977 from 0.4 mm, 0.922 from the residual, 0.841 from −0.2 mm.
        let (off, residual) = (like(0.4), like(0.0));
        assert!(off > 0.95 && off > residual + 0.03, "0.4 mm {off}, 0 mm {residual}");
    }

    /// A 16×16 `lenslet` display, 8 sub-rays, and a perfect eye with 0.15 µm of coma.
    fn bench() -> (DisplayGeometry, TransportCache, TransportOptions, VisionProfile) {
        let d = DisplayGeometry {
            holes_x: 16,
            holes_y: 16,
            ..DisplayGeometry::lenslet()
        };
        let topts = TransportOptions {
            sub_rays: 8,
            ..Default::default()
        };
        let mut p = VisionProfile::perfect();
        p.zernike_um[7] = 0.15;
        (d, TransportCache::default(), topts, p)
    }

    /// Frames whose views differ while every aperture's mean is the same (0.5 in every band): what an eye sees
    /// is which views enter its pupil, nothing else.
    fn zero_mean_frames(d: &DisplayGeometry, seed: u64) -> Vec<f32> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let n = d.n_bands();
        let mut l: Vec<f32> = (0..d.n_samples_per_band() * n).map(|_| rng.gen::<f32>()).collect();
        let views = (d.views_u * d.views_v) as usize;
        for h in 0..(d.holes_x * d.holes_y) {
            let (x, y) = (h % d.holes_x, h / d.holes_x);
            for band in 0..n {
                let idx = |k: usize| {
                    d.sample_index(x, y, (k % d.views_u as usize) as u32, (k / d.views_u as usize) as u32) * n + band
                };
                let mean = (0..views).map(|k| l[idx(k)]).sum::<f32>() / views as f32;
                for k in 0..views {
                    l[idx(k)] = 0.5 + 0.5 * (l[idx(k)] - mean);
                }
            }
        }
        l
    }

    #[test]
    fn the_tracked_operator_is_the_moved_eye_looking_at_retargeted_frames() {
        // T·R built from per-view kernels against T applied to R·L (the same kernel draws): equal away from the
        // display's edge, where T·R also passes light that R leaves dark, for shifts within the block and past it.
        let (d, cache, _, mut p) = bench();
        p.pupil_diameter_mm = 4.0;
        let l = zero_mean_frames(&d, 9);
        for (x_mm, y_mm) in [(1.0, 0.0), (-4.8, 0.0), (5.0, -2.0), (0.0, 6.4)] {
            let eye = EyePosition { x_mm, y_mm, dz_mm: 0.0 };
            let look = |tracked: bool| {
                let topts = TransportOptions {
                    sub_rays: 8,
                    tracked,
                    ..Default::default()
                };
                Observer::new(&d, &p, eye, &topts, Optics::Wave, &cache).unwrap()
            };
            let (tracked, moved) = (look(true), look(false));
            let (a, b) = (tracked.view(&l), moved.view(&retarget(&d, &l, eye)));
            let g = tracked.grid();
            let (w, h) = (g.width as usize, g.height as usize);
            // Four blocks in from every edge (a kernel spreads over its neighbours' pixels).
            let margin = 4 * w / 16;
            let (mut worst, mut scale) = (0f32, 0f32);
            for y in margin..h - margin {
                for x in margin..w - margin {
                    for c in 0..3 {
                        let n = (y * w + x) * 3 + c;
                        worst = worst.max((a[n] - b[n]).abs());
                        scale = scale.max(b[n].abs());
                    }
                }
            }
            assert!(scale > 0.1, "({x_mm}, {y_mm}): a dark view");
            // Measured: 0 (within the own block, and one whole block period over), 2e-7 and 4e-7 (f32 sums in
            // another order).
            assert!(worst <= 1e-5 * scale, "({x_mm}, {y_mm}): {worst} of {scale}");
        }
        // Only under wave optics at the design distance.
        let refused = |eye: EyePosition, optics: Optics| {
            let topts = TransportOptions {
                sub_rays: 8,
                tracked: true,
                ..Default::default()
            };
            Observer::new(&d, &p, eye, &topts, optics, &cache).is_err()
        };
        assert!(refused(
            EyePosition {
                x_mm: 1.0,
                y_mm: 0.0,
                dz_mm: 0.0
            },
            Optics::Geometric
        ));
        assert!(refused(
            EyePosition {
                x_mm: 1.0,
                y_mm: 0.0,
                dz_mm: 50.0
            },
            Optics::Wave
        ));
    }

    #[test]
    fn a_moved_eye_sees_the_design_view_through_retargeted_frames() {
        // Independent of the re-indexing: the wave-optics transport of an eye at the design position and of an
        // eye moved by whole views (within the block and past the block period), applied to random frames.
        let (d, cache, topts, p) = bench();
        let l = zero_mean_frames(&d, 3);
        let lum = |o: &Observer, l: &[f32]| crate::evaluation::luminance(&o.view(l));
        let design = Observer::new(&d, &p, EyePosition::default(), &topts, Optics::Wave, &cache).unwrap();
        let v0 = lum(&design, &l);
        let s = d.view_spacing_at_pupil_mm();
        for (m, e_y) in [(3i64, 0.0), (-5, 0.0), (8, 1.2)] {
            let eye = EyePosition {
                x_mm: m as f64 * s,
                y_mm: e_y,
                dz_mm: 0.0,
            };
            assert_eq!(view_shift(&d, eye).0, m);
            let moved = Observer::new(&d, &p, eye, &topts, Optics::Wave, &cache).unwrap();
            let tracked = crate::evaluation::ncc(&lum(&moved, &retarget(&d, &l, eye)), &v0);
            let untracked = crate::evaluation::ncc(&lum(&moved, &l), &v0);
            // Measured: 0.972 against 0.930 (m = 3), 0.842 against 0.780 (m = −5), 0.697 against 0.653 (m = 8).
            // The gain is modest because a 6 mm pupil spans nearly a whole block period (6.4 mm here): every
            // eye sees nearly every view, through its own block or a neighbour's, and what the re-indexing
            // cannot restore is the light that falls into the 1 mm gaps between blocks.
            assert!(
                tracked > untracked + 0.02,
                "m = {m}: tracked {tracked}, untracked {untracked}"
            );
            // Re-indexing the wrong way is worse than not re-indexing at all.
            let wrong = EyePosition {
                x_mm: -eye.x_mm,
                y_mm: -eye.y_mm,
                dz_mm: 0.0,
            };
            let mirrored = crate::evaluation::ncc(&lum(&moved, &retarget(&d, &l, wrong)), &v0);
            assert!(
                mirrored < untracked,
                "m = {m}: mirrored {mirrored}, untracked {untracked}"
            );
        }
    }
}
