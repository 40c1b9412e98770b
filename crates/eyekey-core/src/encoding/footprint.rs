//! What a job will cost before it runs: its peak memory and an upper bound on its time, from the display's
//! geometry and the encoder's options alone, so a service can refuse a job that cannot run before it starts.
//!
//! The model (docs/design.md §5, "Admission") counts the light field's unknowns D = X·Y·U·V·N and the
//! observers K the solver renders (the target, its head positions, the decoys, the camera decoys, the
//! adaptive rounds' additions and the job's own observers):
//!
//! - memory ≈ 32 MiB + D · (72 + 4·K) bytes + K · S + B: about ten f32 vectors of the light field for the
//!   solver (iterate, momentum, gradient, previous iterate, scratch, the frames being encoded) with a margin for
//!   the transients of larger displays, and one more per observer (its retinal image and adjoint buffers, which
//!   scale with the light field); under wave optics S, each observer's kernel spectra and transforms
//!   ([`spectra_bytes`]: 12 bytes per view, band and pixel of the hole grid padded by the kernels' reach), and B,
//!   the ray bundles the job's angle-sampled kernels are made of ([`bundle_bytes`]: up to the process's bound
//!   on cached bundles, 160 MiB, and one more);
//! - time ≤ D · K · (7·10⁻⁷ + 2.5·10⁻⁸ · max_iterations) s to build the operators and solve, plus
//!   D · E · 2·10⁻⁷ s to evaluate E = people + camera settings (the job's 147-setting camera sweep).
//!
//! The constants were measured on the 2-core reference machine (peak resident memory by `/usr/bin/time -v`
//! of `eyekey encode`; times from `eyekey bench --section job`); the figures, and how far the model sits
//! above them, are in BENCHMARKS.md ("Admission"). Both are meant as upper bounds: the model lies 1.6–4.3× above
//! the measured peaks of every preset's default encode and of the target alone (most where a display's largest
//! pupils would sample angles and the job's do not), above the 6 GB a 64 M-unknown job reached in the service
//! before it was stopped, and up to 2× above the times (the solver often stops before `max_iterations`).

use super::options::EncodeOptions;
use super::pipeline::GUARD_SUB_RAYS;
use crate::physics::display::{Aperture, DisplayGeometry};
use crate::physics::observer::{Optics, KERNEL_RAYS_PER_SUB_RAY};
use crate::physics::transport::{
    angle_sampling_radius_mm, TransportOptions, RAY_BUNDLE_CACHE_BYTES, SAMPLING_PUPIL_STEP_MM,
};

/// Memory every job needs whatever its size: the process, tables and spectra.
pub const BASE_BYTES: u64 = 32 << 20;
/// Solver bytes per unknown of the light field.
pub const SOLVER_BYTES_PER_UNKNOWN: u64 = 72;
/// Bytes per unknown for each observer the solver renders.
pub const OBSERVER_BYTES_PER_UNKNOWN: u64 = 4;
/// Bytes per view, band and padded retinal pixel for each observer under wave optics: its kernels' spectra (f32
/// complex on half the padded grid, 4 bytes a pixel) for its own products, again for the objective's shared
/// transforms, and the term's transforms kept between products.
pub const SPECTRA_BYTES_PER_PADDED_PIXEL: u64 = 12;
/// The padding a kernel's reach adds to the hole grid on each side (holes): the widest kernels measured, `dense`'s
/// (453 taps), reach 10 holes.
pub const KERNEL_REACH_HOLES: u64 = 10;
/// Ray-bundle bytes per view and kernel ray of one eye position and sampling pupil at one wavelength behind
/// lenslets (the rays that enter the pupil, 20 bytes each): 55–56 for a 9 mm pupil, the widest a profile may
/// have (30–32 over `secure`'s default encode, pupils up to 7 mm).
pub const BUNDLE_BYTES_PER_KERNEL_RAY: u64 = 64;
/// ... and behind pinholes: 26–30 on `pinhole` for a 9 mm pupil.
pub const PINHOLE_BUNDLE_BYTES_PER_KERNEL_RAY: u64 = 32;
/// The narrowest and widest pupils a profile may have (`VisionProfile::validate`), mm: the ray bundles' sampling
/// pupils span them.
pub const PUPIL_RANGE_MM: (f64, f64) = (2.0, 9.0);
/// Seconds per unknown and observer to build its operators.
pub const BUILD_SECONDS: f64 = 7e-7;
/// Seconds per unknown, observer and solver iteration.
pub const ITERATION_SECONDS: f64 = 2.5e-8;
/// Seconds per unknown and evaluated person or camera setting.
pub const EVALUATION_SECONDS: f64 = 2e-7;
/// Camera settings of a job's evaluation (7 focus settings × 3 apertures × 7 filters).
pub const EVALUATION_CAMERA_SETTINGS: u64 = 147;

/// A job's estimated cost.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct Footprint {
    /// Unknowns of the light field, D = X·Y·U·V·N.
    pub unknowns: u64,
    /// Observers the solver renders, K.
    pub observers: u64,
    /// Estimated peak memory, bytes.
    pub peak_bytes: u64,
    /// Upper bound on the wall time on a 2-core machine, seconds.
    pub seconds: f64,
}

/// The observers the encoder renders for `options` with `extra_observers` representative observers.
pub fn encoder_observers(display: &DisplayGeometry, options: &EncodeOptions, extra_observers: usize) -> u64 {
    let target = 1
        + (options.focus_states_d().len() + options.pupil_states_mm().len()) as u64
        + if options.head_radius_mm > 0.0 {
            u64::from(options.head_positions)
        } else {
            0
        };
    let cameras = if options.camera_decoys {
        let positions = super::pipeline::camera_decoy_positions(options).len() as u64;
        let apertures = super::pipeline::camera_decoy_apertures(options).len() as u64;
        options.camera_decoy_focus_d.len() as u64 * apertures * display.n_bands() as u64 * positions
    } else {
        0
    };
    let adaptive = u64::from(options.adaptive_rounds) * u64::from(options.adaptive_per_round)
        + u64::from(options.head_rounds) * u64::from(super::options::HEAD_ROUND_MAX_ADDED)
        + u64::from(options.bystander_rounds) * u64::from(options.bystander_decoys_per_round);
    // Decoys looking at their own focus and again at the target's are two terms each.
    let focus_copies = if options.decoy_focus == super::options::DecoyFocus::Both {
        2
    } else {
        1
    };
    target
        + u64::from(options.population_decoys) * focus_copies
        + u64::from(options.near_pupil_decoys) * focus_copies * if options.near_pupil_ring_mm > 0.0 { 2 } else { 1 }
        + cameras
        + adaptive
        + extra_observers as u64
}

/// Camera settings of one position's sweep: the threat model's 27 lenses behind the sensor's R, G and B and each
/// band's filter (189 with 4 bands).
pub(crate) fn camera_sweep_settings(display: &DisplayGeometry) -> u64 {
    let sweep = crate::evaluation::BystanderOptions::default();
    let lenses = (sweep.camera_focus_d.len() * sweep.camera_apertures_mm.len()) as u64;
    lenses * (3 + display.n_bands() as u64)
}

/// Camera settings the bystander rounds look through: every round, each scan offset in four directions, one
/// position's sweep each.
pub fn bystander_scan_settings(display: &DisplayGeometry, options: &EncodeOptions) -> u64 {
    u64::from(options.bystander_rounds) * 4 * options.bystander_scan_mm.len() as u64 * camera_sweep_settings(display)
}

/// The estimated cost of a job on `display` with `options` and `extra_observers` representative observers
/// (see the module's model).
pub fn footprint(display: &DisplayGeometry, options: &EncodeOptions, extra_observers: usize) -> Footprint {
    let unknowns = (display.n_samples_per_band() as u64).saturating_mul(display.n_bands() as u64);
    let observers = encoder_observers(display, options, extra_observers);
    let per_unknown = SOLVER_BYTES_PER_UNKNOWN + OBSERVER_BYTES_PER_UNKNOWN * observers;
    let peak_bytes = BASE_BYTES
        .saturating_add(unknowns.saturating_mul(per_unknown))
        .saturating_add(observers.saturating_mul(spectra_bytes(display, options)))
        .saturating_add(bundle_bytes(display, options, observers));
    // Each person the evaluation judges may be looked at in every focus state of their accommodation range
    // (`EvaluationOptions::accommodation`, 13 by default): one who reads at none is judged in all of them.
    let evaluated = (u64::from(options.evaluation_population) + extra_observers as u64) * evaluation_focus_states()
        + EVALUATION_CAMERA_SETTINGS
        + bystander_scan_settings(display, options)
        + u64::from(options.head_rounds) * u64::from(super::options::HEAD_ROUND_POSITIONS);
    let d = unknowns as f64;
    // Each draw (`draws`) solves again and is checked with fresh people, a tracked head ring and the camera's
    // sweep at the seat and its first repeat past 10 mm, and at most confirmed with more fresh people.
    let draws = f64::from(options.draws.max(1));
    let checked = if options.draws > 1 {
        u64::from(super::options::DRAW_CHECK_PEOPLE)
            + u64::from(super::options::DRAW_CONFIRM_PEOPLE)
            + 21
            + camera_sweep_settings(display) * super::pipeline::draw_check_camera_positions(display).len() as u64
    } else {
        0
    };
    let seconds = draws
        * (d * observers as f64 * (BUILD_SECONDS + ITERATION_SECONDS * f64::from(options.max_iterations))
            + d * checked as f64 * EVALUATION_SECONDS)
        + d * evaluated as f64 * EVALUATION_SECONDS;
    Footprint {
        unknowns,
        observers,
        peak_bytes,
        seconds,
    }
}

/// Focus states a person is judged in at most by a job's evaluation: the default accommodation range's.
fn evaluation_focus_states() -> u64 {
    crate::physics::accommodation::Accommodation::default()
        .states(&crate::physics::profile::VisionProfile::perfect())
        .len() as u64
}

/// The kernels' spectra and transforms one observer holds under wave optics (see the constants): every view and
/// band on the hole grid padded by the kernels' reach.
pub fn spectra_bytes(display: &DisplayGeometry, options: &EncodeOptions) -> u64 {
    if options.optics != Optics::Wave {
        return 0;
    }
    let padded = |holes: u32| u64::from(holes) + 2 * KERNEL_REACH_HOLES;
    let views = u64::from(display.views_u * display.views_v) * display.n_bands() as u64;
    SPECTRA_BYTES_PER_PADDED_PIXEL
        .saturating_mul(views)
        .saturating_mul(padded(display.holes_x) * padded(display.holes_y))
}

/// The ray bundles a job may hold under wave optics on a display whose kernels may sample angles: a bundle per
/// eye position, sampling pupil and wavelength; at the seat at most one per sampling pupil that samples angles
/// (radii in steps of 0.25 mm up to a 9 mm pupil), elsewhere one per observer; and the target guard's (at
/// `GUARD_SUB_RAYS` times the rays); up to the process's bound on cached bundles, plus one of the guard's being
/// traced beyond it.
pub fn bundle_bytes(display: &DisplayGeometry, options: &EncodeOptions, observers: u64) -> u64 {
    if options.optics != Optics::Wave {
        return 0;
    }
    let q = TransportOptions::default().wavelengths_per_band.max(1);
    let wavelengths: Vec<f64> = display
        .projectors
        .iter()
        .flat_map(|p| p.band_wavelengths_nm(q as usize))
        .collect();
    // The sampling pupils (radii in steps up to the widest pupil) that sample angles at the shortest wavelength,
    // where the pinholes' pattern is narrowest.
    let from = wavelengths
        .iter()
        .map(|&l| angle_sampling_radius_mm(display, l, display.viewing_distance_mm))
        .fold(f64::INFINITY, f64::min);
    let widest = (PUPIL_RANGE_MM.1 / 2.0 / SAMPLING_PUPIL_STEP_MM).round() as u32;
    let pupils = (1..=widest)
        .filter(|k| f64::from(*k) * SAMPLING_PUPIL_STEP_MM >= from.max(PUPIL_RANGE_MM.0 / 2.0))
        .count() as u64;
    if pupils == 0 {
        return 0;
    }
    let per_ray = match display.aperture {
        Aperture::Lenslet => BUNDLE_BYTES_PER_KERNEL_RAY,
        Aperture::Pinhole => PINHOLE_BUNDLE_BYTES_PER_KERNEL_RAY,
    };
    let seat = 1 + u64::from(options.population_decoys) + u64::from(options.near_pupil_decoys);
    let looks = seat.min(observers).min(pupils) + observers.saturating_sub(seat);
    // One wavelength's bundle at the job's sub-rays: `KERNEL_RAYS_PER_SUB_RAY`·S/q rays a view.
    let rays = u64::from(KERNEL_RAYS_PER_SUB_RAY * options.sub_rays / q);
    let one = per_ray * u64::from(display.views_u * display.views_v) * rays;
    let guard = u64::from(GUARD_SUB_RAYS) * one;
    let all = (looks.saturating_mul(one) + guard).saturating_mul(wavelengths.len() as u64);
    all.min(RAY_BUNDLE_CACHE_BYTES as u64) + guard
}

/// The cheapest job a display can run: the target alone, no evaluation, one iteration.
pub fn cheapest(display: &DisplayGeometry) -> Footprint {
    let options = EncodeOptions {
        population_decoys: 0,
        near_pupil_decoys: 0,
        evaluation_population: 0,
        max_iterations: 1,
        security: super::options::Security::Strict,
        ..Default::default()
    };
    let mut f = footprint(display, &options, 0);
    f.seconds -= f.unknowns as f64 * EVALUATION_CAMERA_SETTINGS as f64 * EVALUATION_SECONDS;
    f
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_paper_preset_by_hand() {
        // 100×100 holes, 5×5 views, 4 bands: D = 10⁶. Defaults but `strict` (no target states): the target and
        // 6 population and 6 near-pupil decoys, each at its own focus and again refocused (`decoy_focus: both`),
        // K = 1 + 2·12 = 25; `standard`'s four states make it 29. With the decoys at their own focus only, 13.
        let d = DisplayGeometry::paper();
        assert_eq!(footprint(&d, &EncodeOptions::default(), 0).observers, 29);
        let strict = EncodeOptions {
            security: crate::encoding::options::Security::Strict,
            ..EncodeOptions::default()
        };
        assert_eq!(footprint(&d, &strict, 0).observers, 25);
        let base = EncodeOptions {
            decoy_focus: crate::encoding::options::DecoyFocus::Own,
            ..strict
        };
        let f = footprint(&d, &base, 0);
        assert_eq!((f.unknowns, f.observers), (1_000_000, 13));
        // Under geometric optics no spectra and no ray bundles.
        let geometric = EncodeOptions {
            optics: Optics::Geometric,
            ..base.clone()
        };
        assert_eq!(
            footprint(&d, &geometric, 0).peak_bytes,
            (32 << 20) + 1_000_000 * (72 + 4 * 13)
        );
        // Under wave optics each observer's spectra: 25 views × 4 bands × (100 + 2·10)² padded pixels × 12 bytes.
        assert_eq!(spectra_bytes(&d, &base), 17_280_000);
        assert_eq!(
            f.peak_bytes,
            (32 << 20) + 1_000_000 * (72 + 4 * 13) + 13 * 17_280_000 + bundle_bytes(&d, &base, 13)
        );
        // The evaluation: 20 people at up to 13 foci each, and 147 camera settings.
        let seconds = 1e6 * 13.0 * (7e-7 + 2.5e-8 * 300.0) + 1e6 * (20.0 * 13.0 + 147.0) * 2e-7;
        assert!((f.seconds - seconds).abs() < 1e-9, "{}", f.seconds);
        // Two representative observers and a 1 mm head ring of 4 positions add 6 observers.
        let o = EncodeOptions {
            head_radius_mm: 1.0,
            ..base.clone()
        };
        assert_eq!(footprint(&d, &o, 2).observers, 13 + 2 + 4);
        // Camera decoys: one per focus setting and band.
        let o = EncodeOptions {
            camera_decoys: true,
            ..base.clone()
        };
        assert_eq!(footprint(&d, &o, 0).observers, 13 + 2 * 4);
        // The near-pupil decoys looked at again on a ring beside the seat: 6 more.
        let o = EncodeOptions {
            near_pupil_ring_mm: 0.8,
            ..base.clone()
        };
        assert_eq!(footprint(&d, &o, 0).observers, 13 + 6);
        // A bystander round: up to 8 camera decoys, and 15 offsets × 4 directions × 27 lenses × 7 channels looked
        // through.
        let o = EncodeOptions {
            bystander_rounds: 1,
            ..base.clone()
        };
        let f = footprint(&d, &o, 0);
        assert_eq!(f.observers, 13 + 8);
        let seconds = 1e6 * 21.0 * (7e-7 + 2.5e-8 * 300.0) + 1e6 * (20.0 * 13.0 + 147.0 + 11_340.0) * 2e-7;
        assert!((f.seconds - seconds).abs() < 1e-9, "{}", f.seconds);
        // Two head-box rounds: up to 4 tracked positions each, and 20 ring positions looked from each.
        let o = EncodeOptions {
            head_rounds: 2,
            ..base.clone()
        };
        let f = footprint(&d, &o, 0);
        assert_eq!(f.observers, 13 + 8);
        let seconds = 1e6 * 21.0 * (7e-7 + 2.5e-8 * 300.0) + 1e6 * (20.0 * 13.0 + 147.0 + 40.0) * 2e-7;
        assert!((f.seconds - seconds).abs() < 1e-9, "{}", f.seconds);
        // Three draws: three solves, each checked with 200 fresh people, the target, 20 ring positions and the
        // camera (27 lenses × 7 channels) at the seat and at its repeat 12.8 mm right, left, above and below
        // (`secure` repeats every 6.4 mm at the pupil), and at most confirmed with 400 more people.
        let o = EncodeOptions {
            draws: 3,
            ..base.clone()
        };
        let seconds = 3.0 * (1e6 * 13.0 * (7e-7 + 2.5e-8 * 300.0) + 1e6 * (621.0 + 5.0 * 189.0) * 2e-7)
            + 1e6 * (20.0 * 13.0 + 147.0) * 2e-7;
        assert!((footprint(&d, &o, 0).seconds - seconds).abs() < 1e-6);
    }

    #[test]
    fn the_secure_preset_s_ray_bundles_by_hand() {
        // Lenslets: every sampling pupil samples angles, 15 of them (radii 1–4.5 mm). The default job: 13
        // observers at the seat, 13 looks, each 12 wavelengths (4 bands × 3) of 81 views × 682 kernel rays
        // (128 × 16 / 3) × 64 bytes = 3,535,488 bytes, and the guard's look at 4× the rays, 14,141,952: over the
        // cache's 160 MiB bound, and one guard bundle beyond it. The target alone too:
        // (3,535,488 + 14,141,952) × 12 = 212,129,280 bytes.
        let d = DisplayGeometry::secure();
        let o = EncodeOptions::default();
        assert_eq!(bundle_bytes(&d, &o, 13), (160 << 20) + 14_141_952);
        let alone = EncodeOptions {
            population_decoys: 0,
            near_pupil_decoys: 0,
            security: crate::encoding::options::Security::Strict,
            decoy_focus: crate::encoding::options::DecoyFocus::Own,
            ..Default::default()
        };
        assert_eq!(bundle_bytes(&d, &alone, 1), (160 << 20) + 14_141_952);
        // At 3 sub-rays (128 kernel rays, 663,552 bytes a look, the guard's 2,654,208) nothing reaches the bound:
        // 6 near-pupil decoys at the seat make 7 looks; looked at again on a ring 0.8 mm aside, 6 more.
        let few = |ring_mm: f64| EncodeOptions {
            near_pupil_decoys: 6,
            near_pupil_ring_mm: ring_mm,
            sub_rays: 3,
            ..alone.clone()
        };
        let k = |o: &EncodeOptions| encoder_observers(&d, o, 0);
        assert_eq!((k(&few(0.0)), k(&few(0.8))), (7, 13));
        // Refocused as well (`decoy_focus: both`, the default): each decoy twice.
        let both = |ring_mm: f64| EncodeOptions {
            decoy_focus: crate::encoding::options::DecoyFocus::Both,
            ..few(ring_mm)
        };
        assert_eq!((k(&both(0.0)), k(&both(0.8))), (13, 25));
        assert_eq!(
            bundle_bytes(&d, &few(0.0), 7),
            (7 * 663_552 + 2_654_208) * 12 + 2_654_208
        );
        assert_eq!(
            bundle_bytes(&d, &few(0.8), 13),
            (13 * 663_552 + 2_654_208) * 12 + 2_654_208
        );
        // Geometric optics: none.
        let geometric = EncodeOptions {
            optics: Optics::Geometric,
            ..o
        };
        assert_eq!(bundle_bytes(&d, &geometric, 13), 0);
        // The `dense` preset's 33 µm pinholes spread light wider than any pupil: its kernels never sample angles.
        assert_eq!(
            bundle_bytes(&DisplayGeometry::dense(), &EncodeOptions::default(), 13),
            0
        );
    }

    #[test]
    fn the_model_covers_the_measured_peaks() {
        // Peak resident memory of `eyekey encode` (no evaluation) on the reference machine, kB, against the
        // model: paper at 100, 200 and 300 holes a side with 7 observers (the target and 6 population
        // decoys), at 200 with 21, and one band behind 250×250 holes of 8×8 views.
        let paper = DisplayGeometry::paper();
        let one_band = DisplayGeometry {
            views_u: 8,
            views_v: 8,
            screen_pixel_pitch_mm: paper.hole_pitch_mm / 8.0,
            projectors: paper.projectors[..1].to_vec(),
            ..paper.clone()
        };
        for (base, holes, decoys, measured_kb) in [
            (&paper, 100, 6, 74_840u64),
            (&paper, 200, 6, 245_392),
            (&paper, 300, 6, 573_688),
            (&paper, 200, 20, 448_472),
            (&one_band, 250, 6, 285_372),
        ] {
            let d = DisplayGeometry {
                holes_x: holes,
                holes_y: holes,
                ..base.clone()
            };
            // Measured with the decoys at their own focus.
            let o = EncodeOptions {
                population_decoys: decoys,
                near_pupil_decoys: 0,
                security: crate::encoding::options::Security::Strict,
                decoy_focus: crate::encoding::options::DecoyFocus::Own,
                ..Default::default()
            };
            let model = footprint(&d, &o, 0).peak_bytes as f64;
            let measured = (measured_kb * 1024) as f64;
            assert!(
                model >= measured && model <= 5.0 * measured,
                "{holes}/{decoys}: {model} vs {measured}"
            );
        }
        // Every preset's default encode under `security: strict`, whole (`eyekey encode --display
        // examples/displays/P.json --target examples/profiles/target.json --document
        // examples/documents/pin_slip.png --security strict`, measured when the decoys held their own focus by
        // default): its 13 observers, and the target alone (`--population-decoys 0 --near-pupil-decoys 0`).
        // `secure` and `lenslet` hold 84 ray bundles with the decoys (142 MiB), `pinhole` 70 (35 MiB).
        for (d, decoys_kb, alone_kb) in [
            (DisplayGeometry::secure(), 209_692u64, 88_352u64),
            (DisplayGeometry::paper(), 187_024, 45_940),
            (DisplayGeometry::lenslet(), 244_040, 102_348),
            (DisplayGeometry::pinhole(), 85_344, 37_556),
            (DisplayGeometry::small(), 31_604, 17_228),
            (DisplayGeometry::dense(), 212_384, 43_276),
        ] {
            // Measured with the decoys at their own focus (`decoy_focus: own`).
            let strict = EncodeOptions {
                security: crate::encoding::options::Security::Strict,
                decoy_focus: crate::encoding::options::DecoyFocus::Own,
                ..Default::default()
            };
            let alone = EncodeOptions {
                population_decoys: 0,
                near_pupil_decoys: 0,
                ..strict.clone()
            };
            for (o, kb) in [(strict, decoys_kb), (alone, alone_kb)] {
                let model = footprint(&d, &o, 0).peak_bytes as f64;
                let measured = (kb * 1024) as f64;
                assert!(
                    model >= measured && model <= 5.0 * measured,
                    "{d:?} {o:?}: {model} vs {measured}"
                );
            }
        }
    }

    #[test]
    fn every_person_evaluated_costs_a_look_per_focus_state_of_their_range() {
        // −1 to +2 D in 0.25 D steps: 13 looks at most for each sampled person, one for each camera setting.
        assert_eq!(evaluation_focus_states(), 13);
        let d = DisplayGeometry::secure();
        let with = |people: u32| {
            footprint(
                &d,
                &EncodeOptions {
                    evaluation_population: people,
                    ..Default::default()
                },
                0,
            )
            .seconds
        };
        let per_look = d.n_samples_per_band() as f64 * d.n_bands() as f64 * EVALUATION_SECONDS;
        assert!((with(100) - with(0) - 100.0 * 13.0 * per_look).abs() < 1e-9 * with(100));
    }

    #[test]
    fn the_largest_display_costs_what_it_should() {
        // 1000×1000 holes of 8×8 views and one band: the 64 M unknowns `DisplayGeometry::validate` allows.
        let paper = DisplayGeometry::paper();
        let d = DisplayGeometry {
            holes_x: 1000,
            holes_y: 1000,
            views_u: 8,
            views_v: 8,
            screen_pixel_pitch_mm: paper.hole_pitch_mm / 8.0,
            projectors: paper.projectors[..1].to_vec(),
            ..paper
        };
        assert!(d.validate().is_ok());
        let c = cheapest(&d);
        assert_eq!(c.unknowns, 64_000_000);
        // The solver's vectors and the target's spectra: 64 views × (1000 + 2·10)² padded pixels × 12 bytes.
        assert_eq!(spectra_bytes(&d, &EncodeOptions::default()), 799_027_200);
        assert!(c.peak_bytes >= (32 << 20) + 64_000_000 * 76 + 799_027_200);
        assert!((c.seconds - 64e6 * (7e-7 + 2.5e-8)).abs() < 1e-6, "{}", c.seconds);
        // The default job: 19 GB and three hours.
        let job = footprint(&d, &EncodeOptions::default(), 0);
        assert!(job.peak_bytes >= (32 << 20) + 64_000_000 * 124 + 13 * 799_027_200);
        assert!(job.seconds > 5000.0, "{}", job.seconds);
        // `secure`'s target alone, measured 86 MiB (above), with its ray bundles counted.
        assert!(cheapest(&DisplayGeometry::secure()).peak_bytes < 256 << 20);
    }
}
