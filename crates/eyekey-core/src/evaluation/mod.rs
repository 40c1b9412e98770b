//! Is it actually secret? Fidelity for the target and readability for everybody else (docs/design.md §4).
//!
//! Where the document's text is known the known-font attacker ([`KnownFontAttacker`]) decides whether a view is
//! read. Otherwise readability is judged contrast-invariantly: an attacker stretches contrast and denoises, so the
//! score is the best |normalised cross-correlation| between the document's luminance and the view's luminance
//! inside the box around the document's ink after Gaussian denoising at a few strengths ([`legibility`]); its
//! threshold is calibrated against the known-font attacker (`docs/legibility-calibration.md`). Fidelity is PSNR
//! and SSIM (Wang et al. 2004) against the objective.
//!
//! People may refocus: every sampled person, bystander and named observer is judged over their accommodation
//! range (`EvaluationOptions::accommodation`, by default −1 to +2 D around the profile's focus in 0.25 D steps,
//! narrowed with age) and reads when any focus reads; the view's `focus_d` says at which.
//!
//! Every simulated view here uses a sub-ray jitter seed different from the encoder's, so an encoding cannot
//! look good merely by fitting the sampling pattern of its own transport operator.

pub mod attackers;
mod bystanders;
mod contact_sheet;
mod key_sensitivity;
mod known_font;
mod learned;
mod metrics;
mod options;
mod reference;
mod report;
mod text_size;

use attackers::*;
pub use bystanders::{guesses_to_read, unwarp, BystanderOptions, BystanderPosition, BystanderSummary};
pub use contact_sheet::contact_sheet;
use key_sensitivity::*;
pub use known_font::{CellBox, DocumentText, KnownFontAttacker, KnownFontError, KnownFontRead};
pub use learned::{BoundReader, LearnedRead, LearnedReader};
pub use metrics::*;
pub use options::EvaluationOptions;
pub use reference::Reference;
pub use report::*;
pub use text_size::{text_height_on_grid, MIN_JUDGED_TEXT_PX};

use std::sync::atomic::{AtomicBool, Ordering};

use rayon::prelude::*;

use image::{Rgb, RgbImage};

use crate::physics::accommodation::Accommodation;
use crate::physics::display::DisplayGeometry;
use crate::physics::observer::{transports, Lens, Observer};
use crate::physics::population::{sample_population, SamplingScope};
use crate::physics::profile::VisionProfile;
use crate::physics::spectral::coupling;
use crate::physics::transport::{EyePosition, RetinalGrid, TransportCache, TransportOptions};

/// Evaluates light field `l`: the target, the given observers, a population sample, a camera attacker, key
/// sensitivity and head movement. Transport operators come from `cache`; `progress` receives 0..=1.
#[allow(clippy::too_many_arguments)]
pub fn evaluate(
    display: &DisplayGeometry,
    l: &[f32],
    document: &RgbImage,
    level: f64,
    target: &VisionProfile,
    observers: &[(String, VisionProfile)],
    options: &EvaluationOptions,
    cache: &TransportCache,
    progress: &(dyn Fn(f64) + Sync),
    cancel: &AtomicBool,
) -> Result<Evaluation, EvaluationError> {
    let topts = TransportOptions {
        sub_rays: options.sub_rays,
        seed: options.transport_seed(),
        ..Default::default()
    };
    let t_obs = Observer::new(display, target, EyePosition::default(), &topts, options.optics, cache)?;
    let g = t_obs.grid();
    let mut reference = Reference::new(document, g.width, g.height, level, options.threshold);
    if let Some(text) = &options.document_text {
        reference = reference.with_known_font(KnownFontAttacker::new(
            text,
            document.width(),
            document.height(),
            g.width,
            g.height,
        )?);
    }
    let mut ev = Evaluator {
        display,
        l,
        target,
        options,
        topts,
        cache,
        cancel,
        reference,
        pictures: Vec::new(),
    };
    let objective = t_obs.objective(document, level);
    ev.pictures
        .push(("objective.png".to_string(), t_obs.picture(&objective)));
    let target_view = t_obs.view(l);
    let mut target_score = ev.reference.score_lms("target", &target_view, t_obs.white);
    // The target is held to the bar at which a reader does read, not the one at which somebody might.
    let target_reading = ev.reference.target_reading(&target_score, options.target_margin);
    target_score.readable = target_reading.reads;
    ev.pictures
        .push(("target.png".to_string(), t_obs.picture(&target_view)));
    let target_light = mean(&luminance(&target_view));
    let observer_scores = ev.observers(observers)?;
    progress(0.1);
    let population = ev.population(&|p| progress(0.1 + 0.5 * p))?;
    let camera = ev.camera()?;
    progress(0.75);
    let key_sensitivity = ev.key_sensitivity()?;
    progress(0.9);
    let head_movement = ev.head_movement(target_score.readable)?;
    progress(0.95);
    let bystanders = ev.bystanders(target_light, &|p| progress(0.95 + 0.05 * p))?;
    progress(1.0);

    let mut report = Report {
        metric:
            "legibility = max over Gaussian denoising σ ∈ {0, 0.7, 1.5} px of |NCC(view luminance, document luminance)| inside the box around the document's ink (+2 px)"
                .into(),
        threshold: options.threshold,
        target: target_score,
        target_reading,
        observers: observer_scores,
        population,
        camera,
        key_sensitivity,
        head_movement,
        bystanders,
        learned_reader: ev.reference.learned.as_ref().map(|r| r.made().to_string()),
    };
    if let (Some(k), Some(p)) = (report.key_sensitivity.as_mut(), report.population.as_ref()) {
        k.empirical_bits = -(((p.readable_count + 1) as f64) / ((p.count + 1) as f64)).log2();
    }
    let mut pictures = ev.pictures;
    pictures.push(("contact_sheet.png".to_string(), contact_sheet(&report, &pictures)));
    Ok(Evaluation { report, pictures })
}

/// What the camera sweep hands each setting: its label, the channel's luminance, its white, the retinal grid.
type CameraVisit<'a> = dyn FnMut(&str, &[f32], f64, &RetinalGrid) + 'a;

/// One evaluation's shared state: what is looked at, with which transport, and the pictures kept so far.
struct Evaluator<'a> {
    display: &'a DisplayGeometry,
    l: &'a [f32],
    target: &'a VisionProfile,
    options: &'a EvaluationOptions,
    /// Transport options with the evaluation's own jitter seed.
    topts: TransportOptions,
    cache: &'a TransportCache,
    cancel: &'a AtomicBool,
    reference: Reference,
    pictures: Vec<(String, RgbImage)>,
}

impl Evaluator<'_> {
    fn check(&self) -> Result<(), EvaluationError> {
        if self.cancel.load(Ordering::Relaxed) {
            Err(EvaluationError::Cancelled)
        } else {
            Ok(())
        }
    }

    fn observer(&self, profile: &VisionProfile, eye: EyePosition) -> Result<Observer, EvaluationError> {
        Ok(Observer::new(
            self.display,
            profile,
            eye,
            &self.topts,
            self.options.optics,
            self.cache,
        )?)
    }

    /// `profile` at `eye` judged over its accommodation range (`options.accommodation`), its own focus first and
    /// then ever farther from it: the first focus whose view `judge` says reads, else the most legible, with
    /// [`ViewScore::focus_d`] saying which (set only when the range holds more than the own focus). `judge`
    /// scores an observer's view and hands back what the caller keeps of it.
    fn accommodating<T>(
        &self,
        profile: &VisionProfile,
        eye: EyePosition,
        judge: &dyn Fn(&Observer) -> (ViewScore, T),
    ) -> Result<(ViewScore, T), EvaluationError> {
        let states = self.options.accommodation.states(profile);
        let mut best: Option<(ViewScore, T)> = None;
        for &a in &states {
            self.check()?;
            let o = self.observer(&Accommodation::accommodated(profile, a), eye)?;
            let (mut s, kept) = judge(&o);
            if states.len() > 1 {
                s.focus_d = Some(a);
            }
            if s.readable {
                return Ok((s, kept));
            }
            if best.as_ref().is_none_or(|(b, _)| s.legibility > b.legibility) {
                best = Some((s, kept));
            }
        }
        Ok(best.expect("the own focus is always judged"))
    }

    /// The given observers' scores (and a picture each), each over their accommodation range.
    fn observers(&mut self, observers: &[(String, VisionProfile)]) -> Result<Vec<ViewScore>, EvaluationError> {
        let mut scores = Vec::new();
        for (k, (label, p)) in observers.iter().enumerate() {
            let (s, pic) = self.accommodating(p, EyePosition::default(), &|o| {
                self.reference.score_observer(label, o, self.l)
            })?;
            scores.push(s);
            self.pictures.push((format!("observer_{k}.png"), pic));
        }
        Ok(scores)
    }

    /// People sampled from published statistics, each at the design eye position (the worst case: a
    /// bystander who takes the target's seat) and over their accommodation range. Keeps the first views asked
    /// for and the most legible one.
    fn population(&mut self, progress: &dyn Fn(f64)) -> Result<Option<PopulationSummary>, EvaluationError> {
        let options = self.options;
        if options.population == 0 {
            return Ok(None);
        }
        let people = sample_population(options.population as usize, options.seed, SamplingScope::default());
        let mut scores = Vec::with_capacity(people.len());
        let mut kept: Vec<(usize, RgbImage)> = Vec::new();
        // A few people at once, each building their own kernels: one person's build and judging alone does not
        // keep every core busy (two a core at once took the 1,000-person evaluation to 0.70× its time,
        // BENCHMARKS.md "Job"). Scores and pictures are then taken in the people's order, as one at a time would.
        let at_once = 2 * rayon::current_num_threads().max(1);
        for (c, chunk) in people.chunks(at_once).enumerate() {
            self.check()?;
            let first = c * at_once;
            let judged = chunk
                .par_iter()
                .enumerate()
                .map(|(i, p)| {
                    let label = format!("person_{}", first + i);
                    self.accommodating(p, EyePosition::default(), &|o| {
                        self.reference.score_observer(&label, o, self.l)
                    })
                })
                .collect::<Result<Vec<_>, EvaluationError>>()?;
            for (i, (s, pic)) in judged.into_iter().enumerate() {
                let k = first + i;
                if (k as u32) < options.saved_population_views {
                    kept.push((k, pic.clone()));
                }
                let worst_so_far = scores.iter().all(|w: &ViewScore| s.legibility > w.legibility);
                if worst_so_far {
                    kept.retain(|(i, _)| *i != usize::MAX);
                    kept.push((usize::MAX, pic));
                }
                scores.push(s);
            }
            progress((first + chunk.len()) as f64 / people.len() as f64);
        }
        for (k, pic) in kept {
            let name = if k == usize::MAX {
                "population_worst.png".to_string()
            } else {
                format!("person_{k}.png")
            };
            self.pictures.push((name, pic));
        }
        Ok(Some(PopulationSummary::from_scores(scores)))
    }

    /// The camera attacker: ideal optics, focus swept, several apertures, an RGB sensor with and without a
    /// narrow filter per projector band; each channel judged alone; its best case is reported.
    fn camera(&mut self) -> Result<Option<CameraSummary>, EvaluationError> {
        let options = self.options;
        if options.camera_focus_d.is_empty() || options.camera_apertures_mm.is_empty() {
            return Ok(None);
        }
        let g = (self.reference.width as u32, self.reference.height as u32);
        let mut tried = Vec::new();
        let mut best: Option<(ViewScore, RgbImage)> = None;
        self.camera_sweep(
            EyePosition::default(),
            &options.camera_focus_d,
            &options.camera_apertures_mm,
            &mut |setting, lum, white, _| {
                let s = self.reference.score(&format!("camera {setting}"), lum, white);
                if best.as_ref().is_none_or(|(b, _)| s.legibility > b.legibility) {
                    // The attacker's picture: the channel stretched to its own range, shown in grey.
                    let stretched = stretch_to_unit(lum);
                    let pic = RgbImage::from_fn(g.0, g.1, |x, y| {
                        let b = (stretched[(y * g.0 + x) as usize].clamp(0.0, 1.0) * 255.0) as u8;
                        Rgb([b, b, b])
                    });
                    best = Some((s.clone(), pic));
                }
                tried.push(s);
            },
        )?;
        Ok(best.map(|(b, pic)| {
            self.pictures.push(("camera_best.png".to_string(), pic));
            CameraSummary { best: b, tried }
        }))
    }

    /// The camera attacker's settings at `eye`: an ideal lens at every focus and aperture, behind the sensor's
    /// R, G and B and behind a filter per projector band; `visit` gets each setting's label, the channel's
    /// luminance, its white and the retinal grid.
    fn camera_sweep(
        &self,
        eye: EyePosition,
        focus_d: &[f64],
        apertures_mm: &[f64],
        visit: &mut CameraVisit<'_>,
    ) -> Result<(), EvaluationError> {
        let display = self.display;
        let rgb = coupling(&display.projectors, &camera_rgb()).c;
        for &aperture in apertures_mm {
            for &focus in focus_d {
                self.check()?;
                let lens = camera_lens(focus, aperture);
                let tr = transports(
                    display,
                    Lens::Achromat(&lens),
                    eye,
                    &self.topts,
                    self.options.optics,
                    self.cache,
                )
                .map_err(crate::physics::observer::ObserverError::from)?;
                for (name, c) in camera_channels(&rgb, display.n_bands()) {
                    let cam = Observer::with_coupling(tr.clone(), c, display.l_max);
                    let lum: Vec<f32> = cam.view(self.l).chunks_exact(3).map(|p| p[0]).collect();
                    visit(
                        &format!("f={focus:+.1}D aperture={aperture}mm {name}"),
                        &lum,
                        cam.white[0],
                        &cam.grid(),
                    );
                }
            }
        }
        Ok(())
    }

    fn key_sensitivity(&self) -> Result<Option<KeySensitivity>, EvaluationError> {
        if self.options.key_directions == 0 {
            return Ok(None);
        }
        self.check()?;
        let ks = KeySensitivityProbe {
            display: self.display,
            l: self.l,
            target: self.target,
            reference: &self.reference,
            options: self.options,
            topts: &self.topts,
            cache: self.cache,
            cancel: self.cancel,
        };
        Ok(Some(ks.run()?))
    }

    /// The target's worst legibility on rings of the configured radii, and the largest radius up to which
    /// the target still reads at every ring position (by the judge: the known-font attacker where the text is
    /// known, the legibility threshold otherwise).
    fn head_movement(&self, target_readable: bool) -> Result<Option<HeadMovement>, EvaluationError> {
        let options = self.options;
        if options.head_offsets_mm.is_empty() {
            return Ok(None);
        }
        let (mut worst, mut all_read) = (Vec::new(), Vec::new());
        for &r in &options.head_offsets_mm {
            self.check()?;
            let (mut w, mut read) = (f64::INFINITY, true);
            // The ring's positions at once: each builds its own kernels, and two at a time keep both cores busy
            // through the serial parts of each.
            let scores = head_ring(r)
                .into_par_iter()
                .map(|eye| {
                    let o = self.observer(self.target, eye)?;
                    Ok(self.reference.score_observer("target moved", &o, self.l).0)
                })
                .collect::<Result<Vec<_>, EvaluationError>>()?;
            for s in scores {
                w = w.min(s.legibility);
                read &= s.readable;
            }
            worst.push(w);
            all_read.push(read);
        }
        let mut radius = 0.0;
        if target_readable {
            for (r, read) in options.head_offsets_mm.iter().zip(&all_read) {
                if *read {
                    radius = *r;
                } else {
                    break;
                }
            }
        }
        Ok(Some(HeadMovement {
            offsets_mm: options.head_offsets_mm.clone(),
            worst_legibility: worst,
            readable_radius_mm: radius,
        }))
    }

    /// Scores a bystander's luminance view both as seen and resampled onto the document's layout (the
    /// attacker knows the geometry and where they stand); the better of the two.
    fn score_bystander(&self, label: &str, lum: &[f32], white: f64, grid: &RetinalGrid, eye: EyePosition) -> ViewScore {
        let [seen, back] = self.bystander_readings(label, lum, white, grid, eye);
        Self::better_reading(seen, back)
    }

    /// A bystander's view scored as seen and unwarped back onto the document's frame.
    fn bystander_readings(
        &self,
        label: &str,
        lum: &[f32],
        white: f64,
        grid: &RetinalGrid,
        eye: EyePosition,
    ) -> [ViewScore; 2] {
        let seen = self.reference.score(label, lum, white);
        let back = self
            .reference
            .score(label, &unwarp(lum, grid, self.display, eye), white);
        [seen, back]
    }

    /// Of a view's two readings, the one that reads, else the more legible (the strict judge: any reading counts).
    fn better_reading(seen: ViewScore, back: ViewScore) -> ViewScore {
        let better = |a: &ViewScore, b: &ViewScore| (a.readable, a.legibility) >= (b.readable, b.legibility);
        if better(&seen, &back) {
            seen
        } else {
            back
        }
    }

    /// People and the focus-sweeping camera at every bystander position.
    fn bystanders(
        &mut self,
        target_light: f64,
        progress: &dyn Fn(f64),
    ) -> Result<Option<BystanderSummary>, EvaluationError> {
        let Some(bo) = self.options.bystanders.clone() else {
            return Ok(None);
        };
        bo.validate().map_err(EvaluationError::Bystanders)?;
        let display = self.display;
        let mut out = Vec::new();
        let mut best_view: Option<(f64, RgbImage)> = None;
        let positions = bo.positions(display);
        let n = positions.len();
        for (k, eye) in positions.into_iter().enumerate() {
            let at = format!("({:+.0}, {:+.0}, {:+.0}) mm", eye.x_mm, eye.y_mm, eye.dz_mm);
            let people = sample_population(
                bo.people as usize,
                self.options.seed ^ 0xB75D ^ (k as u64) << 20,
                SamplingScope::default(),
            );
            let mut best_person: Option<ViewScore> = None;
            let mut people_read = 0;
            let mut light = 0.0;
            for (i, p) in people.iter().enumerate() {
                let label = format!("bystander {at} person {i}");
                let (s, (person_light, pic)) = self.accommodating(p, eye, &|o| {
                    let view = o.view(self.l);
                    let lum = luminance(&view);
                    let white = luminance_of(o.white);
                    let s = self.score_bystander(&label, &lum, white, &o.grid(), eye);
                    (s, (mean(&lum), o.picture(&view)))
                })?;
                light += person_light;
                people_read += u32::from(s.readable);
                if best_view.as_ref().is_none_or(|(b, _)| s.legibility > *b) {
                    best_view = Some((s.legibility, pic));
                }
                if best_person.as_ref().is_none_or(|b| s.legibility > b.legibility) {
                    best_person = Some(s);
                }
            }
            let (mut best_camera, mut camera_read, mut settings) = (None::<ViewScore>, 0, 0);
            let (mut readers, mut guesses) = (Vec::new(), Vec::new());
            self.camera_sweep(
                eye,
                &bo.camera_focus_d,
                &bo.camera_apertures_mm,
                &mut |setting, lum, white, grid| {
                    let [seen, back] =
                        self.bystander_readings(&format!("camera {at} {setting}"), lum, white, grid, eye);
                    guesses.extend(
                        [&seen, &back]
                            .into_iter()
                            .filter_map(|s| s.known_font.as_ref())
                            .map(|k| (k.confidence, k.text.clone(), k.correct)),
                    );
                    let s = Self::better_reading(seen, back);
                    settings += 1;
                    camera_read += u32::from(s.readable);
                    if s.readable {
                        readers.push(match &s.known_font {
                            Some(k) => format!(
                                "{setting} (legibility {:.2}, known-font margin {:.3})",
                                s.legibility, k.margin
                            ),
                            None => format!("{setting} (legibility {:.2})", s.legibility),
                        });
                    }
                    if best_camera.as_ref().is_none_or(|b| s.legibility > b.legibility) {
                        best_camera = Some(s);
                    }
                },
            )?;
            let distance_mm = (eye.x_mm.powi(2) + eye.y_mm.powi(2) + eye.dz_mm.powi(2)).sqrt();
            out.push(BystanderPosition {
                eye,
                distance_mm,
                relative_light: if target_light > 0.0 && !people.is_empty() {
                    light / people.len() as f64 / target_light
                } else {
                    0.0
                },
                best_person,
                people_read,
                people: people.len() as u32,
                best_camera,
                camera_settings_read: camera_read,
                camera_settings: settings,
                camera_settings_that_read: readers,
                camera_guesses_to_read: bystanders::guesses_to_read(&guesses),
            });
            progress((k + 1) as f64 / n as f64);
        }
        if let Some((_, pic)) = best_view {
            self.pictures.push(("bystander_best.png".to_string(), pic));
        }
        Ok(Some(BystanderSummary::from_positions(out)))
    }
}

/// Mean of a luminance image.
fn mean(v: &[f32]) -> f64 {
    v.iter().map(|x| *x as f64).sum::<f64>() / v.len().max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The PIN slip's lines.
    const PIN_LINES: [&str; 2] = ["PIN", "4821"];

    /// A 32×32 lenslet display showing a PIN slip plainly (every view the same image): the display, the slip,
    /// the light field.
    fn plain_pin() -> (DisplayGeometry, RgbImage, Vec<f32>) {
        let display = DisplayGeometry {
            holes_x: 32,
            holes_y: 32,
            ..DisplayGeometry::lenslet()
        };
        let document = crate::imaging::glyphs::render_text(&PIN_LINES, 128, 128, 4);
        let l = crate::physics::observer::plain_light_field_for_image(&display, &document);
        (display, document, l)
    }

    /// Options that judge only what is asked beside them, the PIN slip's text known: nobody sampled, no camera, key
    /// or head scan, 4 sub-rays.
    fn pin_only() -> EvaluationOptions {
        EvaluationOptions {
            population: 0,
            sub_rays: 4,
            key_directions: 0,
            head_offsets_mm: vec![],
            camera_focus_d: vec![],
            document_text: Some(DocumentText {
                lines: PIN_LINES.iter().map(|s| s.to_string()).collect(),
                scale: 4,
                alphabet: "0123456789".into(),
            }),
            ..Default::default()
        }
    }

    /// [`evaluate`] of `l` showing `document` on `display`, for a target with perfect eyes and no further
    /// observers.
    fn evaluate_for_perfect_eyes(
        display: &DisplayGeometry,
        l: &[f32],
        document: &RgbImage,
        options: &EvaluationOptions,
        cache: &TransportCache,
    ) -> Evaluation {
        let perfect = VisionProfile::perfect();
        evaluate(
            display,
            l,
            document,
            0.8,
            &perfect,
            &[],
            options,
            cache,
            &|_| {},
            &AtomicBool::new(false),
        )
        .unwrap()
    }

    #[test]
    fn a_plain_image_is_read_by_a_bystander_beside_the_target_and_not_from_far_outside_the_display() {
        // A plain 2D image (every view of a lenslet equal) is the opposite of secret: two block periods aside
        // (12.8 mm) an eye sees it through the blocks two over, shifted by two lenslets, and reads it once the
        // shift is undone. (Between repeats the pupil straddles two blocks and sees a double image one lenslet
        // apart.) 500 mm aside the screen lies outside every lenslet's line of sight: the view is dark and unread.
        let (display, document, l) = plain_pin();
        let repeat = 2.0 * display.block_shift_at_pupil_mm(display.viewing_distance_mm);
        let options = EvaluationOptions {
            bystanders: Some(BystanderOptions {
                lateral_mm: vec![repeat, 500.0],
                distances_mm: vec![],
                people: 1,
                camera_focus_d: vec![0.0],
                camera_apertures_mm: vec![4.0],
                ..Default::default()
            }),
            ..pin_only()
        };
        let ev = evaluate_for_perfect_eyes(&display, &l, &document, &options, &TransportCache::default());
        let b = ev.report.bystanders.unwrap();
        assert_eq!(b.positions.len(), 8);
        assert_eq!(b.nearest_reader_mm, Some(repeat), "{:#?}", b.positions);
        assert!(
            b.positions.iter().any(|p| p.camera_guesses_to_read.is_some()),
            "a camera reads at the repeat somewhere: {:#?}",
            b.positions
        );
        for p in &b.positions {
            // The settings that read are named, one for each counted, from the settings tried.
            assert_eq!(
                p.camera_settings_that_read.len(),
                p.camera_settings_read as usize,
                "{p:#?}"
            );
            assert!(
                p.camera_settings_that_read.iter().all(|s| s.contains("aperture=4mm")),
                "{p:#?}"
            );
            if p.distance_mm == repeat {
                assert_eq!(p.people_read, 1, "{p:#?}");
                assert!(p.relative_light > 0.5, "{p:#?}");
                // Where a camera reads a plain image, its owner needs no inside knowledge: his most confident
                // reading is the right one.
                if p.camera_settings_read > 0 {
                    assert_eq!(p.camera_guesses_to_read, Some(1), "{p:#?}");
                }
            } else {
                assert_eq!((p.people_read, p.camera_settings_read), (0, 0), "{p:#?}");
                assert_eq!(p.camera_guesses_to_read, None, "{p:#?}");
                assert!(p.relative_light < 0.01, "{p:#?}");
            }
        }
    }

    #[test]
    fn an_observer_who_can_refocus_onto_the_text_reads_it_and_the_report_says_at_which_focus() {
        // A plain PIN slip seen by eyes defocused by spheres of +2 D (far-sighted: accommodating 2 D corrects
        // it), −1 D (near-sighted: relaxing 1 D corrects it) and +3.5 D (beyond the 2 D the range allows). Held
        // at their own focus none of them reads; allowed to refocus, the first two do, at the focus that cancels
        // their sphere, and the third does not.
        let (display, document, l) = plain_pin();
        let eye = |sphere_d: f64| VisionProfile {
            prescription: Some(crate::physics::zernike::Prescription {
                sphere_d,
                cylinder_d: 0.0,
                axis_deg: 0.0,
            }),
            ..VisionProfile::perfect()
        };
        let observers: Vec<(String, VisionProfile)> = [2.0, -1.0, 3.5]
            .iter()
            .map(|d| (format!("sphere {d:+} D"), eye(*d)))
            .collect();
        let judged = |accommodation: Accommodation| {
            let options = EvaluationOptions {
                accommodation,
                ..pin_only()
            };
            evaluate(
                &display,
                &l,
                &document,
                0.8,
                &VisionProfile::perfect(),
                &observers,
                &options,
                &TransportCache::default(),
                &|_| {},
                &AtomicBool::new(false),
            )
            .unwrap()
            .report
            .observers
        };
        let fixed = judged(Accommodation::fixed());
        assert!(fixed.iter().all(|s| !s.readable && s.focus_d.is_none()), "{fixed:#?}");
        let refocusing = judged(Accommodation::default());
        let verdicts: Vec<(bool, Option<f64>)> = refocusing.iter().map(|s| (s.readable, s.focus_d)).collect();
        // The first focus that reads, met on the way out from the own focus: a residual defocus of 0.5 D
        // (about 0.9 retinal pixels of blur at 6 mm) still reads, so it lies within 0.5 D short of the sphere.
        for (k, sphere) in [(0, 2.0f64), (1, -1.0)] {
            let (reads, focus) = verdicts[k];
            let focus = focus.unwrap();
            assert!(reads, "{refocusing:#?}");
            assert!(
                focus.signum() == sphere.signum() && (sphere - focus).abs() <= 0.5 + 1e-9,
                "{refocusing:#?}"
            );
        }
        // Out of reach: not read, and the view reported is its most legible, at the range's nearer end.
        assert!(!verdicts[2].0, "{refocusing:#?}");
        assert_eq!(verdicts[2].1, Some(2.0), "{refocusing:#?}");
    }

    #[test]
    fn the_population_is_judged_person_by_person_in_its_order_however_many_are_built_at_once() {
        // The population's people are built a few at a time; each score, the first views kept and the most
        // legible view must be those of judging each person alone, in the people's order. Seven people (not a
        // multiple of the number built at once) look at a plain image, which each reads with their own
        // legibility.
        let (display, document, l) = plain_pin();
        let options = EvaluationOptions {
            population: 7,
            saved_population_views: 2,
            sub_rays: 4,
            key_directions: 0,
            head_offsets_mm: vec![],
            camera_focus_d: vec![],
            ..Default::default()
        };
        let cache = TransportCache::default();
        let ev = evaluate_for_perfect_eyes(&display, &l, &document, &options, &cache);
        let people = sample_population(7, options.seed, SamplingScope::default());
        let topts = TransportOptions {
            sub_rays: options.sub_rays,
            seed: options.transport_seed(),
            ..Default::default()
        };
        let fresh = TransportCache::default();
        let (w, h) = (ev.pictures[0].1.width(), ev.pictures[0].1.height());
        let reference = Reference::new(&document, w, h, 0.8, options.threshold);
        let alone: Vec<(ViewScore, RgbImage)> = people
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let o = Observer::new(&display, p, EyePosition::default(), &topts, options.optics, &fresh).unwrap();
                reference.score_observer(&format!("person_{k}"), &o, &l)
            })
            .collect();
        let report = ev.report.population.as_ref().unwrap();
        let legibility: Vec<f64> = report.people.iter().map(|s| s.legibility).collect();
        let expected: Vec<f64> = alone.iter().map(|(s, _)| s.legibility).collect();
        assert_eq!(legibility, expected);
        let labels: Vec<&str> = report.people.iter().map(|s| s.label.as_str()).collect();
        assert_eq!(labels, (0..7).map(|k| format!("person_{k}")).collect::<Vec<_>>());
        // The people do not all read alike, so the most legible view names one of them.
        let most = (0..7).fold(0, |m, k| if expected[k] > expected[m] { k } else { m });
        assert!(expected.iter().any(|v| *v < expected[most]), "{expected:?}");
        let picture = |name: &str| &ev.pictures.iter().find(|(n, _)| n == name).unwrap().1;
        assert_eq!(picture("person_0.png"), &alone[0].1);
        assert_eq!(picture("person_1.png"), &alone[1].1);
        assert!(ev.pictures.iter().all(|(n, _)| n != "person_2.png"));
        assert_eq!(picture("population_worst.png"), &alone[most].1);
    }

    #[test]
    fn ncc_is_contrast_and_sign_invariant_in_legibility() {
        let doc: Vec<f32> = (0..400).map(|i| if (i / 7) % 3 == 0 { 0.0 } else { 1.0 }).collect();
        let faint: Vec<f32> = doc.iter().map(|v| 0.4 + 0.05 * v).collect();
        let negative: Vec<f32> = doc.iter().map(|v| 1.0 - v).collect();
        assert!((ncc(&faint, &doc) - 1.0).abs() < 1e-6);
        assert!((legibility(&negative, &doc, 20, 20) - 1.0).abs() < 1e-6);
        assert_eq!(ncc(&vec![0.5; 400], &doc), 0.0);
    }

    #[test]
    fn ssim_and_psnr_match_hand_values() {
        // Identical images: SSIM 1; a constant offset δ gives MSE δ², so PSNR = 20 log10(peak/δ).
        let a: Vec<f32> = (0..256).map(|i| (i % 16) as f32 / 16.0).collect();
        assert!((ssim(&a, &a, 16, 16, 1.0) - 1.0).abs() < 1e-9);
        let b: Vec<f32> = a.iter().map(|v| v + 0.1).collect();
        assert!((psnr(&a, &b, 1.0) - 20.0).abs() < 1e-3);
        // SSIM of an image against its negative is strongly negative (structure term −1).
        let n: Vec<f32> = a.iter().map(|v| 1.0 - v).collect();
        assert!(ssim(&a, &n, 16, 16, 1.0) < 0.0);
    }

    #[test]
    fn gaussian_blur_preserves_the_mean_and_smooths() {
        let img: Vec<f32> = (0..100).map(|i| if i == 55 { 1.0 } else { 0.0 }).collect();
        let b = gaussian_blur(&img, 10, 10, 1.0);
        let s: f32 = b.iter().sum();
        assert!((s - 1.0).abs() < 1e-4, "{s}");
        // The 1-D kernel at σ = 1 puts 0.4 in the centre tap: 0.16 in 2-D (Gaussian value 1/(2π) ≈ 0.159).
        assert!((b[55] - 0.159).abs() < 0.01, "{}", b[55]);
    }
}
