//! What a job will cost before it runs: its peak memory and an upper bound on its time, from the display's
//! geometry and the encoder's options alone, so a service can refuse a job that cannot run before it starts.
//!
//! The model (docs/design.md §5, "Admission") counts the light field's unknowns D = X·Y·U·V·N and the
//! observers K the solver renders (the target, its head positions, the decoys, the camera decoys, the
//! adaptive rounds' additions and the job's own observers):
//!
//! - memory ≈ 32 MiB + D · (72 + 4·K) bytes: about ten f32 vectors of the light field for the solver
//!   (iterate, momentum, gradient, previous iterate, scratch, the frames being encoded) with a margin for the
//!   transients of larger displays, and one more per observer (its retinal image and adjoint buffers, which
//!   scale with the light field);
//! - time ≤ D · K · (7·10⁻⁷ + 2.5·10⁻⁸ · max_iterations) s to build the operators and solve, plus
//!   D · E · 2·10⁻⁷ s to evaluate E = people + camera settings (the job's 147-setting camera sweep).
//!
//! The constants were measured on the 2-core reference machine (peak resident memory by `/usr/bin/time -v`
//! of `eyekey encode`; times from `eyekey bench --section job`); the figures, and how far the model sits
//! above them, are in BENCHMARKS.md ("Admission"). Both are meant as upper bounds: the model lies 30–75 % above
//! the measured peaks (and above the 6 GB a 64 M-unknown job reached in the service before it was stopped) and up to 2× above the times (the solver often stops before `max_iterations`).

use super::options::EncodeOptions;
use crate::physics::display::DisplayGeometry;

/// Memory every job needs whatever its size: the process, tables and spectra.
pub const BASE_BYTES: u64 = 32 << 20;
/// Solver bytes per unknown of the light field.
pub const SOLVER_BYTES_PER_UNKNOWN: u64 = 72;
/// Bytes per unknown for each observer the solver renders.
pub const OBSERVER_BYTES_PER_UNKNOWN: u64 = 4;
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
    let target = 1 + if options.head_radius_mm > 0.0 {
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
    target
        + u64::from(options.population_decoys)
        + u64::from(options.near_pupil_decoys) * if options.near_pupil_ring_mm > 0.0 { 2 } else { 1 }
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
    let peak_bytes = BASE_BYTES.saturating_add(unknowns.saturating_mul(per_unknown));
    let evaluated = u64::from(options.evaluation_population)
        + extra_observers as u64
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

/// The cheapest job a display can run: the target alone, no evaluation, one iteration.
pub fn cheapest(display: &DisplayGeometry) -> Footprint {
    let options = EncodeOptions {
        population_decoys: 0,
        near_pupil_decoys: 0,
        evaluation_population: 0,
        max_iterations: 1,
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
        // 100×100 holes, 5×5 views, 4 bands: D = 10⁶. Defaults: the target, 6 population decoys and 6
        // near-pupil decoys, K = 13.
        let d = DisplayGeometry::paper();
        let f = footprint(&d, &EncodeOptions::default(), 0);
        assert_eq!((f.unknowns, f.observers), (1_000_000, 13));
        assert_eq!(f.peak_bytes, (32 << 20) + 1_000_000 * (72 + 4 * 13));
        let seconds = 1e6 * 13.0 * (7e-7 + 2.5e-8 * 300.0) + 1e6 * (20.0 + 147.0) * 2e-7;
        assert!((f.seconds - seconds).abs() < 1e-9, "{}", f.seconds);
        // Two representative observers and a 1 mm head ring of 4 positions add 6 observers.
        let o = EncodeOptions {
            head_radius_mm: 1.0,
            ..Default::default()
        };
        assert_eq!(footprint(&d, &o, 2).observers, 13 + 2 + 4);
        // Camera decoys: one per focus setting and band.
        let o = EncodeOptions {
            camera_decoys: true,
            ..Default::default()
        };
        assert_eq!(footprint(&d, &o, 0).observers, 13 + 2 * 4);
        // The near-pupil decoys looked at again on a ring beside the seat: 6 more.
        let o = EncodeOptions {
            near_pupil_ring_mm: 0.8,
            ..Default::default()
        };
        assert_eq!(footprint(&d, &o, 0).observers, 13 + 6);
        // A bystander round: up to 8 camera decoys, and 15 offsets × 4 directions × 27 lenses × 7 channels looked
        // through.
        let o = EncodeOptions {
            bystander_rounds: 1,
            ..Default::default()
        };
        let f = footprint(&d, &o, 0);
        assert_eq!(f.observers, 13 + 8);
        let seconds = 1e6 * 21.0 * (7e-7 + 2.5e-8 * 300.0) + 1e6 * (20.0 + 147.0 + 11_340.0) * 2e-7;
        assert!((f.seconds - seconds).abs() < 1e-9, "{}", f.seconds);
        // Two head-box rounds: up to 4 tracked positions each, and 20 ring positions looked from each.
        let o = EncodeOptions {
            head_rounds: 2,
            ..Default::default()
        };
        let f = footprint(&d, &o, 0);
        assert_eq!(f.observers, 13 + 8);
        let seconds = 1e6 * 21.0 * (7e-7 + 2.5e-8 * 300.0) + 1e6 * (20.0 + 147.0 + 40.0) * 2e-7;
        assert!((f.seconds - seconds).abs() < 1e-9, "{}", f.seconds);
        // Three draws: three solves, each checked with 200 fresh people, the target, 20 ring positions and the
        // camera (27 lenses × 7 channels) at the seat and at its repeat 12.8 mm right, left, above and below
        // (`secure` repeats every 6.4 mm at the pupil), and at most confirmed with 400 more people.
        let o = EncodeOptions {
            draws: 3,
            ..Default::default()
        };
        let seconds =
            3.0 * (1e6 * 13.0 * (7e-7 + 2.5e-8 * 300.0) + 1e6 * (621.0 + 5.0 * 189.0) * 2e-7) + 1e6 * 167.0 * 2e-7;
        assert!((footprint(&d, &o, 0).seconds - seconds).abs() < 1e-6);
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
            let o = EncodeOptions {
                population_decoys: decoys,
                near_pupil_decoys: 0,
                ..Default::default()
            };
            let model = footprint(&d, &o, 0).peak_bytes as f64;
            let measured = (measured_kb * 1024) as f64;
            assert!(
                model >= measured && model <= 2.0 * measured,
                "{holes}/{decoys}: {model} vs {measured}"
            );
        }
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
        assert_eq!(c.peak_bytes, (32 << 20) + 64_000_000 * 76);
        assert!((c.seconds - 64e6 * (7e-7 + 2.5e-8)).abs() < 1e-6, "{}", c.seconds);
        // The default job: 8 GB and three hours.
        let job = footprint(&d, &EncodeOptions::default(), 0);
        assert_eq!(job.peak_bytes, (32 << 20) + 64_000_000 * 124);
        assert!(job.seconds > 5000.0, "{}", job.seconds);
        assert!(cheapest(&DisplayGeometry::secure()).peak_bytes < 64 << 20);
    }
}
