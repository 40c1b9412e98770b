//! `eyekey experiment bystanders`: a PIN slip encoded for the sweep's sampled target on the wave sweep's
//! lenslet baseline, looked at from a grid of positions beside and above the target (10–500 mm, at the design
//! distance) by sampled people and by a camera that sweeps focus ±3 D and aperture 2–8 mm behind RGB and
//! one-band filters (`eyekey_core::evaluation::BystanderOptions`); and by the same camera at the target's own
//! position. `eyekey experiment headbox`: the target's head box.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::Result;

use super::experiment::{pin_slip, pin_slip_text, sampled_target, sweep_lenslet};
use super::table_header;
use eyekey_core::encoding::pipeline::{encode, EncodeOptions, JobSpec, OBJECTIVE_LEVEL};
use eyekey_core::evaluation::{evaluate, BystanderOptions, BystanderSummary, EvaluationOptions, ViewScore};
use eyekey_core::physics::observer::Optics;
use eyekey_core::physics::transport::TransportCache;

/// One encoding looked at from everywhere.
#[derive(Clone, Copy)]
struct Encoding {
    label: &'static str,
    decoys: u32,
    decoy_weight: f64,
    /// The target stacked on a ring of this radius (mm; 0 = only the design position).
    head_radius_mm: f64,
    /// The decoys' leak penalty weight (0 = off).
    leak_weight: f64,
    /// Camera decoys at −1, 0 and +1 D (aperture `camera_aperture_mm`).
    cameras: bool,
    /// Decoys whose pupils bracket the target's (`near_pupil_decoys`).
    near_pupil: u32,
    /// Those decoys also on a ring of this radius around the seat (`near_pupil_ring_mm`; 0 = not).
    near_pupil_ring_mm: f64,
    /// The camera decoys' aperture, mm (when `cameras`).
    camera_aperture_mm: f64,
    /// Further apertures of the camera decoys, mm (`camera_decoy_extra_apertures_mm`).
    camera_extra_apertures_mm: &'static [f64],
    /// The camera decoys' focus settings, dioptres (when `cameras`).
    camera_focus_d: &'static [f64],
    /// The camera decoys also on a ring of this radius around the seat (`camera_decoy_ring_mm`; 0 = not).
    camera_ring_mm: f64,
    /// Positions of the target on its ring (`head_positions`).
    head_positions: u32,
    /// Each ring position's weight (`head_weight`).
    head_weight: f64,
    /// The encoder's seed (its decoys' noise and people, the kernels' draws).
    seed: u64,
    /// The encoder's target guard (`ensure_target_reads`), as a job has it.
    guard: bool,
    /// The slip's text hint given to the encoder (`document_text`) without the guard: the leak penalty then also
    /// covers each secret character's glyphs, and bystander rounds judge by the known-font attacker.
    text_hint: bool,
    /// Bystander camera rounds (`bystander_rounds`, over the default scan).
    bystander_rounds: u32,
    /// Head-box rounds (`head_rounds`).
    head_rounds: u32,
    /// The weight head-box rounds raise a stacked position to at most (`head_round_max_weight`).
    head_round_max_weight: f64,
    /// Adaptive decoy rounds (`adaptive_rounds`, with the encoder's default candidates).
    adaptive_rounds: u32,
    /// Draws tried, the best by the encoder's own checks kept (`draws`).
    draws: u32,
}

/// The sweep's baseline: 6 noise decoys at weight 0.3 and nothing else; each encoding below changes some of it.
const BASELINE: Encoding = Encoding {
    label: "6 noise decoys, weight 0.3 (the sweep's baseline)",
    decoys: 6,
    decoy_weight: 0.3,
    head_radius_mm: 0.0,
    leak_weight: 0.0,
    cameras: false,
    near_pupil: 0,
    near_pupil_ring_mm: 0.0,
    camera_aperture_mm: 8.0,
    camera_extra_apertures_mm: &[],
    camera_focus_d: &[-1.0, 0.0, 1.0],
    camera_ring_mm: 0.0,
    head_positions: 4,
    head_weight: eyekey_core::encoding::options::DEFAULT_HEAD_WEIGHT,
    seed: 5,
    guard: false,
    text_hint: false,
    bystander_rounds: 0,
    head_rounds: 0,
    head_round_max_weight: eyekey_core::encoding::options::HEAD_ROUND_MAX_WEIGHT,
    adaptive_rounds: 0,
    draws: 1,
};

/// Camera decoys at 0 and +2 D behind a 4 mm aperture, at the seat and on a 0.8 mm ring around it: the settings
/// and the place (0.8 mm right of the seat, and its repeats every 6.4 mm) of the cameras that read ring-stacked
/// frames (docs/experiments.md §2c).
const CAMERA_RING: Encoding = Encoding {
    label: "camera decoys at 0, +2 D (4 mm), also on a 0.8 mm ring",
    cameras: true,
    camera_aperture_mm: 4.0,
    camera_focus_d: &[0.0, 2.0],
    camera_ring_mm: 0.8,
    ..BASELINE
};

/// The head-box frames closest to every condition at once: the target on a 0.3 mm ring, the defaults' decoys
/// (leak weight 3), the near-pupil decoys and camera decoys at −1, 0, +2 D (4 mm) also on a 0.8 mm ring.
const BOTH_RINGS: Encoding = Encoding {
    label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), target stacked on a 0.3 mm ring, camera decoys at −1, 0, +2 D (4 mm) also on a 0.8 mm ring",
    head_radius_mm: 0.3,
    leak_weight: 3.0,
    near_pupil: 6,
    near_pupil_ring_mm: 0.8,
    camera_focus_d: &[-1.0, 0.0, 2.0],
    ..CAMERA_RING
};

/// What the experiments share: the wave sweep's lenslet baseline display, its sampled target and PIN slip.
pub(super) struct Baseline {
    pub(super) display: eyekey_core::physics::display::DisplayGeometry,
    pub(super) target: eyekey_core::physics::profile::VisionProfile,
    pub(super) document: image::RgbImage,
    pub(super) text: eyekey_core::evaluation::DocumentText,
    pub(super) cache: TransportCache,
}

impl Baseline {
    pub(super) fn new() -> Result<Self> {
        let display = sweep_lenslet(32, 1.0, 9, 0.6, 500.0);
        display.validate()?;
        let g = (display.holes_x * 4, display.holes_y * 4);
        Ok(Self {
            display,
            target: sampled_target(),
            document: pin_slip(g.0, g.1),
            text: pin_slip_text(g.0),
            cache: TransportCache::default(),
        })
    }

    /// The experiments' encode options: 12 sub-rays, seed 5, wave optics, no decoys, no leak penalty and no
    /// target guard yet (each experiment says what it adds, whatever the defaults).
    pub(super) fn options(max_iterations: u32) -> EncodeOptions {
        EncodeOptions {
            population_decoys: 0,
            near_pupil_decoys: 0,
            decoy_weight: Some(0.0),
            leak_weight: 0.0,
            ensure_target_reads: false,
            max_iterations,
            sub_rays: 12,
            seed: Some(5),
            optics: Optics::Wave,
            ..Default::default()
        }
    }

    /// Encodes the PIN slip with `e`'s decoys and stacked target; returns the light field and the seconds it
    /// took.
    fn encode(&self, e: &Encoding, max_iterations: u32) -> Result<(Vec<f32>, f64)> {
        self.encode_with(
            e.label,
            EncodeOptions {
                population_decoys: e.decoys,
                near_pupil_decoys: e.near_pupil,
                near_pupil_ring_mm: e.near_pupil_ring_mm,
                decoy_weight: Some(e.decoy_weight),
                head_radius_mm: e.head_radius_mm,
                head_positions: e.head_positions,
                head_weight: e.head_weight,
                seed: Some(e.seed),
                leak_weight: e.leak_weight,
                camera_decoys: e.cameras,
                camera_decoy_focus_d: e.camera_focus_d.to_vec(),
                camera_decoy_aperture_mm: e.camera_aperture_mm,
                camera_decoy_extra_apertures_mm: e.camera_extra_apertures_mm.to_vec(),
                camera_decoy_ring_mm: e.camera_ring_mm,
                ensure_target_reads: e.guard,
                bystander_rounds: e.bystander_rounds,
                head_rounds: e.head_rounds,
                head_round_max_weight: e.head_round_max_weight,
                adaptive_rounds: e.adaptive_rounds,
                draws: e.draws,
                // The guard judges the target as the job would, with the slip's text hint; bystander rounds and the
                // draws' checks judge by it too, but leave the leak penalty as the row has it unless the hint is
                // asked for.
                document_text: (e.guard
                    || e.text_hint
                    || e.bystander_rounds > 0
                    || e.head_rounds > 0
                    || e.adaptive_rounds > 0
                    || e.draws > 1)
                    .then(|| self.text.clone()),
                leak_glyphs: e.guard || e.text_hint,
                ..Self::options(max_iterations)
            },
        )
    }

    /// Encodes the PIN slip with `options`; returns the light field and the seconds it took.
    pub(super) fn encode_with(&self, label: &str, options: EncodeOptions) -> Result<(Vec<f32>, f64)> {
        let t = Instant::now();
        let spec = JobSpec {
            display: self.display.clone(),
            target: self.target.clone(),
            target_label: label.into(),
            observers: vec![],
            document: self.document.clone(),
            decoy: None,
            options,
        };
        let enc = encode(&spec, &self.cache, &|_| {}, &AtomicBool::new(false))?;
        for c in &enc.solver.draws {
            eprintln!(
                "{label}: draw {}: target reads {}, ring {} of {}, {} of {} fresh people read, {} of {} camera settings read (the seat and its first repeat past 10 mm){}{}",
                c.seed,
                c.target_reads,
                c.ring_read,
                c.ring_positions,
                c.people_read,
                c.people,
                c.cameras_read,
                c.cameras,
                if c.confirm_people > 0 {
                    format!("; confirmed: {} of {} more people read", c.confirm_read, c.confirm_people)
                } else {
                    String::new()
                },
                if c.kept { " (kept)" } else { "" }
            );
        }
        for (k, n) in enc.solver.adaptive_decoys_added.iter().enumerate() {
            eprintln!("{label}: adaptive round {}: {n} people added as decoys", k + 1);
        }
        for (k, r) in enc.solver.head_rounds.iter().enumerate() {
            let added: Vec<String> = r.added.iter().map(|[x, y]| format!("({x:.2}, {y:.2})")).collect();
            let raised: Vec<String> = r
                .raised
                .iter()
                .map(|p| format!("({:.2}, {:.2}) to {}", p.at[0], p.at[1], p.weight))
                .collect();
            eprintln!(
                "{label}: head-box round {}: the tracked target read at {} of {} positions; added {}{}",
                k + 1,
                r.read,
                r.positions,
                if added.is_empty() {
                    "none".to_string()
                } else {
                    added.join(", ") + " mm"
                },
                if raised.is_empty() {
                    String::new()
                } else {
                    format!("; weight raised at {}", raised.join(", "))
                }
            );
        }
        if enc.solver.solves.len() > 1 {
            let solves: Vec<String> = enc
                .solver
                .solves
                .iter()
                .map(|s| {
                    format!(
                        "{} ({}, decoys × {:.3})",
                        s.iterations,
                        s.termination.as_str(),
                        s.decoy_weight_scale
                    )
                })
                .collect();
            eprintln!(
                "{label}: the kept frames' solves, iterations each: {}",
                solves.join(", ")
            );
        }
        for (k, r) in enc.solver.bystander_rounds.iter().enumerate() {
            eprintln!(
                "{label}: bystander round {}: {} of {} camera settings read, best known-font margin {:?}, {} added as decoys",
                k + 1,
                r.read,
                r.settings,
                r.best_margin,
                r.added
            );
        }
        Ok((enc.light_field, t.elapsed().as_secs_f64()))
    }

    /// Evaluates light field `l` for the target with `options`; returns the evaluation and its seconds.
    pub(super) fn evaluate(
        &self,
        l: &[f32],
        options: &EvaluationOptions,
        progress: &(dyn Fn(f64) + Sync),
    ) -> Result<(eyekey_core::evaluation::Evaluation, f64)> {
        let t = Instant::now();
        let ev = evaluate(
            &self.display,
            l,
            &self.document,
            OBJECTIVE_LEVEL,
            &self.target,
            &[],
            options,
            &self.cache,
            progress,
            &AtomicBool::new(false),
        )?;
        Ok((ev, t.elapsed().as_secs_f64()))
    }
}

fn score_cell(s: Option<&ViewScore>) -> String {
    match s {
        None => "–".into(),
        Some(s) => {
            let kf = s
                .known_font
                .as_ref()
                .map(|k| format!(", read \"{}\" ({}/{})", k.text, k.characters_right, k.characters))
                .unwrap_or_default();
            format!("{:.2}{kf}", s.legibility)
        }
    }
}

/// A length in mm to 0.1 mm, without a decimal when whole (positions between the display's repeats are
/// looked at in tenths).
fn mm(v: f64) -> String {
    // Adding 0 turns a rounded −0 into 0.
    format!("{}", (v * 10.0).round() / 10.0 + 0.0)
}

/// The same with its sign.
fn signed_mm(v: f64) -> String {
    format!("{:+}", (v * 10.0).round() / 10.0 + 0.0)
}

fn position_rows(md: &mut String, b: &BystanderSummary) -> Result<()> {
    md.push_str(&table_header(&[
        "position (x, y, Δd) mm",
        "from the target's pupil",
        "light vs target",
        "people read",
        "best person: legibility, known font",
        "camera settings read",
        "best camera: legibility, known font (setting)",
    ]));
    for p in &b.positions {
        let cam = p
            .best_camera
            .as_ref()
            .map(|c| {
                let setting = c.label.split(") mm ").nth(1).unwrap_or("");
                format!("{} ({setting})", score_cell(Some(c)))
            })
            .unwrap_or_else(|| "–".into());
        writeln!(
            md,
            "| ({}, {}, {}) | {} mm | {:.2} | {} of {} | {} | {} of {}{} | {} |",
            signed_mm(p.eye.x_mm),
            signed_mm(p.eye.y_mm),
            signed_mm(p.eye.dz_mm),
            mm(p.distance_mm),
            p.relative_light,
            p.people_read,
            p.people,
            score_cell(p.best_person.as_ref()),
            p.camera_settings_read,
            p.camera_settings,
            match (p.camera_settings_that_read.is_empty(), p.camera_guesses_to_read) {
                (true, _) => String::new(),
                (false, None) => format!(": {}", p.camera_settings_that_read.join("; ")),
                (false, Some(n)) => format!(
                    ": {}; the camera attacker's own pick (readings by falling confidence) is right at guess {n}",
                    p.camera_settings_that_read.join("; ")
                ),
            },
            cam
        )?;
    }
    Ok(())
}

/// Runs the bystander experiment with `people` sampled people per position; writes `out/bystanders.md`,
/// `out/bystanders.json` and each encoding's pictures; returns the Markdown.
pub fn run(
    out: &Path,
    bystanders: BystanderOptions,
    max_iterations: u32,
    sub_rays: u32,
    only: Option<&str>,
    overrides: Overrides,
) -> Result<String> {
    bystanders.validate().map_err(|e| anyhow::anyhow!("bystanders: {e}"))?;
    if bystanders.lateral_mm.is_empty()
        && (bystanders.distances_mm.is_empty() || bystanders.lateral_at_distance_mm.is_empty())
    {
        anyhow::bail!("bystanders: no position to look from (give --lateral or --distances)");
    }
    std::fs::create_dir_all(out)?;
    let base = Baseline::new()?;
    let encodings = [
        Encoding {
            label: "no decoys",
            decoys: 0,
            decoy_weight: 0.0,
            ..BASELINE
        },
        Encoding {
            label: "6 noise decoys, weight 0.3 (the sweep's baseline)",
            ..BASELINE
        },
        Encoding {
            label: "6 noise decoys, weight 0.3, the target stacked on a 5 mm ring",
            head_radius_mm: 5.0,
            ..BASELINE
        },
        Encoding {
            label: "6 noise decoys, weight 0.3, leak penalty 1",
            leak_weight: 1.0,
            ..BASELINE
        },
        Encoding {
            label: "6 noise decoys, weight 0.3, leak penalty 1, the target stacked on a 5 mm ring",
            head_radius_mm: 5.0,
            leak_weight: 1.0,
            ..BASELINE
        },
        Encoding {
            label: "6 noise decoys, weight 0.3, leak penalty 3",
            leak_weight: 3.0,
            ..BASELINE
        },
        Encoding {
            label: "6 noise decoys, weight 0.3, leak penalty 1, camera decoys at −1, 0, +1 D (8 mm)",
            leak_weight: 1.0,
            cameras: true,
            ..BASELINE
        },
        Encoding {
            label: "6 noise decoys, weight 0.3, leak penalty 12, target stacked on a 0.3 mm ring (the head box)",
            head_radius_mm: 0.3,
            leak_weight: 12.0,
            ..BASELINE
        },
        Encoding {
            label: "6 noise decoys, weight 0.3, leak penalty 12, target stacked on a 0.3 mm ring, camera decoys at −1, 0, +1 D (8 mm)",
            head_radius_mm: 0.3,
            leak_weight: 12.0,
            cameras: true,
            ..BASELINE
        },
        Encoding {
            label: "6 noise decoys, weight 0.3, leak penalty 20, target stacked on a 0.3 mm ring, camera decoys at −1, 0, +1 D (8 mm)",
            head_radius_mm: 0.3,
            leak_weight: 20.0,
            cameras: true,
            ..BASELINE
        },
        Encoding {
            label: "6 noise decoys, weight 0.3, leak penalty 3, 6 near-pupil decoys (the defaults)",
            leak_weight: 3.0,
            near_pupil: 6,
            ..BASELINE
        },
        Encoding {
            label: "6 noise decoys, weight 0.5, leak penalty 3, 6 near-pupil decoys, the target guard (the secure defaults)",
            decoy_weight: 0.5,
            leak_weight: 3.0,
            near_pupil: 6,
            guard: true,
            ..BASELINE
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys), target stacked on a 0.3 mm ring (a tracked head box)",
            head_radius_mm: 0.3,
            leak_weight: 3.0,
            near_pupil: 6,
            ..BASELINE
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), target stacked on a 0.3 mm ring (a tracked head box)",
            head_radius_mm: 0.3,
            leak_weight: 3.0,
            near_pupil: 6,
            near_pupil_ring_mm: 0.8,
            ..BASELINE
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), target stacked on a 0.3 mm ring, camera decoys at −1, 0, +1 D (8 mm) (a tracked head box)",
            head_radius_mm: 0.3,
            leak_weight: 3.0,
            cameras: true,
            near_pupil: 6,
            near_pupil_ring_mm: 0.8,
            ..BASELINE
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys), target stacked on a 0.3 mm ring, camera decoys at −1, 0, +1 D (4 mm) (a tracked head box)",
            head_radius_mm: 0.3,
            leak_weight: 3.0,
            cameras: true,
            near_pupil: 6,
            camera_aperture_mm: 4.0,
            ..BASELINE
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), target stacked on a 0.3 mm ring, camera decoys at −1, 0, +1 D (4 mm) (a tracked head box)",
            head_radius_mm: 0.3,
            leak_weight: 3.0,
            cameras: true,
            near_pupil: 6,
            near_pupil_ring_mm: 0.8,
            camera_aperture_mm: 4.0,
            ..BASELINE
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.5 mm ring), target stacked on a 0.3 mm ring (a tracked head box)",
            head_radius_mm: 0.3,
            leak_weight: 3.0,
            near_pupil: 6,
            near_pupil_ring_mm: 0.5,
            ..BASELINE
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.5 mm ring), target stacked on a 0.3 mm ring, camera decoys at −1, 0, +1 D (4 mm) (a tracked head box)",
            head_radius_mm: 0.3,
            leak_weight: 3.0,
            cameras: true,
            near_pupil: 6,
            near_pupil_ring_mm: 0.5,
            camera_aperture_mm: 4.0,
            ..BASELINE
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys), target stacked on a 0.3 mm ring, camera decoys at 0, +2 D (4 mm) also on a 0.8 mm ring (a tracked head box)",
            head_radius_mm: 0.3,
            leak_weight: 3.0,
            near_pupil: 6,
            ..CAMERA_RING
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), target stacked on a 0.3 mm ring, camera decoys at −1, 0, +2 D (4 mm) also on a 0.8 mm ring (a tracked head box)",
            ..BOTH_RINGS
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), leak penalty 2, target stacked on a 0.3 mm ring, camera decoys at −1, 0, +2 D (4 mm) also on a 0.8 mm ring (a tracked head box)",
            leak_weight: 2.0,
            ..BOTH_RINGS
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), leak penalty 2, target at 8 positions on a 0.3 mm ring, camera decoys at −1, 0, +2 D (4 mm) also on a 0.8 mm ring (a tracked head box)",
            head_positions: 8,
            leak_weight: 2.0,
            ..BOTH_RINGS
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), target at 8 positions on a 0.3 mm ring, camera decoys at −1, 0, +2 D (4 mm) also on a 0.8 mm ring (a tracked head box)",
            head_positions: 8,
            ..BOTH_RINGS
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), target at 6 positions on a 0.3 mm ring, camera decoys at −1, 0, +2 D (4 mm) also on a 0.8 mm ring (a tracked head box)",
            head_positions: 6,
            ..BOTH_RINGS
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), target at 6 positions on a 0.3 mm ring, camera decoys at −1, 0, +2 D (8 mm) also on a 0.8 mm ring (a tracked head box)",
            head_positions: 6,
            camera_aperture_mm: 8.0,
            ..BOTH_RINGS
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), leak penalty 3.75, target at 6 positions on a 0.3 mm ring, camera decoys at −1, 0, +2 D (4 mm) also on a 0.8 mm ring (a tracked head box)",
            head_positions: 6,
            leak_weight: 3.75,
            ..BOTH_RINGS
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), leak penalty 3.5, target at 6 positions on a 0.3 mm ring, camera decoys at −1, 0, +2 D (4 mm) also on a 0.8 mm ring (a tracked head box)",
            head_positions: 6,
            leak_weight: 3.5,
            ..BOTH_RINGS
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), leak penalty 4, target at 6 positions on a 0.3 mm ring, camera decoys at −1, 0, +2 D (4 mm) also on a 0.8 mm ring (a tracked head box)",
            head_positions: 6,
            leak_weight: 4.0,
            ..BOTH_RINGS
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), target at 6 positions on a 0.3 mm ring, camera decoys at −1, 0, +2 D (4 mm) also on a 1.2 mm ring (a tracked head box)",
            head_positions: 6,
            camera_ring_mm: 1.2,
            ..BOTH_RINGS
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), target at 6 positions on a 0.3 mm ring, camera decoys at −1, 0, +2 D behind 4 and 8 mm also on a 0.8 mm ring (a tracked head box)",
            head_positions: 6,
            camera_extra_apertures_mm: &[8.0],
            ..BOTH_RINGS
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys, also on a 0.8 mm ring), target at 6 positions on a 0.3 mm ring, camera decoys at −3, −1, 0, +2 D (4 mm) also on a 0.8 mm ring (a tracked head box)",
            head_positions: 6,
            camera_focus_d: &[-3.0, -1.0, 0.0, 2.0],
            ..BOTH_RINGS
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys), leak penalty 12, target stacked on a 0.3 mm ring (a tracked head box)",
            head_radius_mm: 0.3,
            leak_weight: 12.0,
            near_pupil: 6,
            ..BASELINE
        },
        Encoding {
            label: "the defaults (6 near-pupil decoys), target stacked on a 0.3 mm ring, camera decoys at −1, 0, +1 D (8 mm) (a tracked head box)",
            head_radius_mm: 0.3,
            leak_weight: 3.0,
            cameras: true,
            near_pupil: 6,
            ..BASELINE
        },
    ];
    let mut md = String::new();
    let mut all = Vec::new();
    for (k, e) in encodings.iter().enumerate() {
        if only.is_some_and(|f| !e.label.contains(f)) {
            continue;
        }
        let (e, label) = &overrides.apply(e);
        let (l, t_encode) = base.encode(e, max_iterations)?;
        let options = EvaluationOptions {
            population: 0,
            optics: Optics::Wave,
            document_text: Some(base.text.clone()),
            sub_rays,
            key_directions: 0,
            head_offsets_mm: vec![],
            camera_focus_d: bystanders.camera_focus_d.clone(),
            camera_apertures_mm: bystanders.camera_apertures_mm.clone(),
            bystanders: Some(bystanders.clone()),
            ..Default::default()
        };
        let t = Instant::now();
        let (ev, t_eval) = base.evaluate(&l, &options, &|p| {
            eprint!(
                "\r{}: evaluation {:.0} % ({:.0} s)",
                label,
                100.0 * p,
                t.elapsed().as_secs_f64()
            )
        })?;
        let dir = out.join(format!("encoding_{k}"));
        eyekey_core::encoding::pipeline::write_evaluation(&ev, &dir)?;
        let r = &ev.report;
        let b = r.bystanders.as_ref().expect("bystanders were asked for");
        writeln!(md, "### {label}\n")?;
        writeln!(
            md,
            "Target: legibility {:.2}, known font {}. Camera at the target's position (focus ±3 D, apertures 2–8 mm, RGB and one-band filters): {}. Encode {t_encode:.0} s, evaluation {t_eval:.0} s (views drawn with {sub_rays} sub-rays per sample).\n",
            r.target.legibility,
            score_cell(Some(&r.target)),
            r.camera
                .as_ref()
                .map(|c| format!(
                    "best {} ({}), {} of {} settings read",
                    score_cell(Some(&c.best)),
                    c.best.label,
                    c.tried.iter().filter(|s| s.readable).count(),
                    c.tried.len()
                ))
                .unwrap_or_else(|| "not evaluated".into())
        )?;
        match b.nearest_reader_mm {
            Some(d) => writeln!(
                md,
                "**Nearest bystander who read: {} mm from the target's pupil** (nearest position looked at: {} mm).\n",
                mm(d),
                mm(b.nearest_position_mm)
            )?,
            None => writeln!(
                md,
                "**No bystander read** at any of the {} positions ({} mm and farther from the target's pupil).\n",
                b.positions.len(),
                mm(b.nearest_position_mm)
            )?,
        }
        position_rows(&mut md, b)?;
        md.push('\n');
        eprintln!("\n{label}: encode {t_encode:.0} s, evaluation {t_eval:.0} s");
        all.push(serde_json::json!({"encoding": label, "report": r}));
    }
    std::fs::write(out.join("bystanders.md"), &md)?;
    std::fs::write(out.join("bystanders.json"), serde_json::to_string_pretty(&all)?)?;
    Ok(md)
}

/// How the target's head box is served.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum HeadBoxMethod {
    /// Frames encoded for the design position, shown as they are.
    Fixed,
    /// The same frames re-indexed for the tracked eye position (`physics::tracking::retarget`).
    Tracked,
}

/// Weights and the seed that replace every encoding's own; each label then says so.
#[derive(Clone, Copy, Debug, Default, clap::Args)]
pub struct Overrides {
    /// Every encoding's decoys at this weight instead of its own (0.3 but where a label says otherwise).
    #[arg(long)]
    pub decoy_weight: Option<f64>,
    /// Every head-box encoding's ring positions at this weight instead of 0.25.
    #[arg(long)]
    pub head_weight: Option<f64>,
    /// Every encoding with this encoder seed instead of 5 (the people and cameras who look are the same).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Every encoding given the slip's text hint (its leak penalty then covers the secret glyphs too).
    #[arg(long)]
    pub text_hint: bool,
    /// Every encoding with this many bystander camera rounds (`bystander_rounds`): they judge by the slip's
    /// known-font attacker, and the leak penalty stays as the row has it (glyphs only with `--text-hint`).
    #[arg(long)]
    pub bystander_rounds: Option<u32>,
    /// Every encoding with this many head-box rounds (`head_rounds`): the tracked target looks from rings of 1–5
    /// mm and where it misreads, the tracked target there joins its stacked positions; they judge
    /// by the slip's known-font attacker, the leak penalty as the row has it.
    #[arg(long)]
    pub head_rounds: Option<u32>,
    /// Every encoding's head-box rounds raise a stacked position's weight to this at most
    /// (`head_round_max_weight`) instead of the design position's 1.
    #[arg(long)]
    pub head_round_max_weight: Option<f64>,
    /// Every encoding with this many adaptive decoy rounds (`adaptive_rounds`): fresh people at the seat who
    /// still read join as decoys; judged by the slip's known-font attacker.
    #[arg(long)]
    pub adaptive_rounds: Option<u32>,
    /// Every encoding with the target guard (`ensure_target_reads`) and the text hint, as a job runs.
    #[arg(long)]
    pub guard: bool,
    /// Every encoding tried with this many draws, the best by the encoder's own checks kept (`draws`).
    #[arg(long)]
    pub draws: Option<u32>,
}

impl Overrides {
    /// `e` with the weights given (where it has decoys, and a ring), and its label saying so.
    fn apply(&self, e: &Encoding) -> (Encoding, String) {
        let (mut e, mut label) = (*e, e.label.to_string());
        if let Some(w) = self.decoy_weight.filter(|_| e.decoys + e.near_pupil > 0) {
            e.decoy_weight = w;
            label += &format!(", decoys at weight {w}");
        }
        if let Some(w) = self.head_weight.filter(|_| e.head_radius_mm > 0.0) {
            e.head_weight = w;
            label += &format!(", ring positions at weight {w}");
        }
        if let Some(seed) = self.seed {
            e.seed = seed;
            label += &format!(", encoder seed {seed}");
        }
        if self.guard && !e.guard {
            e.guard = true;
            label += ", with the target guard";
        }
        if self.text_hint && !e.guard {
            e.text_hint = true;
            label += ", with the text hint";
        }
        if let Some(n) = self.draws {
            e.draws = n;
            label += &format!(", the best of {n} draws");
        }
        if let Some(n) = self.head_rounds {
            e.head_rounds = n;
            label += &format!(", {n} head-box round(s)");
        }
        if let Some(w) = self.head_round_max_weight {
            e.head_round_max_weight = w;
            label += &format!(", stacked positions raised to weight {w} at most");
        }
        if let Some(n) = self.adaptive_rounds {
            e.adaptive_rounds = n;
            label += &format!(", {n} adaptive round(s)");
        }
        if let Some(n) = self.bystander_rounds {
            e.bystander_rounds = n;
            label += &format!(", {n} bystander camera round(s)");
        }
        (e, label)
    }
}

/// One head-box experiment row: label, the target's ring radius (mm), how the frames are served, the leak weight,
/// whether camera decoys look from the seat.
type HeadBoxRow = (&'static str, f64, HeadBoxMethod, f64, bool);

/// The target's worst reading on rings of `offsets` around the design position (right, left, up, down): the
/// lowest legibility and how many of the ring's positions the known-font attacker read.
pub(super) fn head_rings(
    display: &eyekey_core::physics::display::DisplayGeometry,
    l: &[f32],
    target: &eyekey_core::physics::profile::VisionProfile,
    reference: &eyekey_core::evaluation::Reference,
    method: HeadBoxMethod,
    offsets: &[f64],
    cache: &TransportCache,
) -> Result<Vec<(f64, f64, u32)>> {
    let topts = eyekey_core::physics::transport::TransportOptions {
        sub_rays: 12,
        seed: 0xBEAD,
        ..Default::default()
    };
    let mut out = Vec::new();
    for &r in offsets {
        let (mut worst, mut read) = (f64::INFINITY, 0);
        for eye in eyekey_core::evaluation::attackers::head_ring(r) {
            let o = eyekey_core::physics::observer::Observer::new(display, target, eye, &topts, Optics::Wave, cache)?;
            let shown = match method {
                HeadBoxMethod::Fixed => l.to_vec(),
                HeadBoxMethod::Tracked => eyekey_core::physics::tracking::retarget(display, l, eye),
            };
            let (s, _) = reference.score_observer("target moved", &o, &shown);
            worst = worst.min(s.legibility);
            read += u32::from(s.known_font.as_ref().is_some_and(|k| k.correct));
        }
        out.push((r, worst, read));
    }
    Ok(out)
}

/// How many of `evaluation`'s people at the design position read `l` through other kernel
/// draws: the evaluation's own draw again (the evaluation's count, as a check), `draws` more at its sub-rays, and
/// one at `GUARD_SUB_RAYS` times them; a row each in `md`.
fn seat_kernels(
    base: &Baseline,
    l: &[f32],
    reference: &eyekey_core::evaluation::Reference,
    evaluation: &EvaluationOptions,
    draws: u32,
    label: &str,
    md: &mut String,
) -> Result<()> {
    use eyekey_core::physics::transport::{EyePosition, TransportOptions};
    use rayon::prelude::*;
    let people = eyekey_core::physics::population::sample_population(
        evaluation.population as usize,
        evaluation.seed,
        Default::default(),
    );
    let sub_rays = evaluation.sub_rays;
    let guard = eyekey_core::encoding::pipeline::GUARD_SUB_RAYS;
    let mut looks = vec![(
        "the evaluation's draw".to_string(),
        sub_rays,
        evaluation.transport_seed(),
    )];
    looks.extend((1..=u64::from(draws)).map(|k| (format!("draw {k}"), sub_rays, 0x5EA7_0000 + k)));
    looks.push((format!("{guard}× the sub-rays"), guard * sub_rays, 0x5EA7_1000));
    for (name, rays, seed) in looks {
        let t = Instant::now();
        let opts = TransportOptions {
            sub_rays: rays,
            seed,
            ..Default::default()
        };
        let read = people
            .par_iter()
            .map(|p| {
                let o = eyekey_core::physics::observer::Observer::new(
                    &base.display,
                    p,
                    EyePosition::default(),
                    &opts,
                    Optics::Wave,
                    &base.cache,
                )?;
                Ok(u32::from(reference.score_observer("seat", &o, l).0.readable))
            })
            .collect::<Result<Vec<u32>>>()?
            .into_iter()
            .sum::<u32>();
        let (lo, hi) = eyekey_core::evaluation::wilson_interval(u64::from(read), people.len() as u64, 1.96);
        writeln!(
            md,
            "| {label} | {name} ({rays} sub-rays) | {read} of {} ({:.1}–{:.1} %) | {:.0} s |",
            people.len(),
            100.0 * lo,
            100.0 * hi,
            t.elapsed().as_secs_f64()
        )?;
        eprintln!("{label}: seat, {name} ({rays} sub-rays): {read} of {}", people.len());
    }
    Ok(())
}

/// The head-box experiment: the wave sweep's baseline encoding, shown fixed or re-indexed for the tracked eye,
/// and encodings with the target stacked at 4 positions on a ring (2.5 mm, 5 mm); the target's readings over
/// ±5 mm and the fraction of `population` people at the design position who read each. Writes
/// `out/headbox.md`.
pub fn headbox(
    out: &Path,
    population: u32,
    max_iterations: u32,
    only: Option<&str>,
    seat_kernel_draws: u32,
    overrides: Overrides,
) -> Result<String> {
    std::fs::create_dir_all(out)?;
    let base = Baseline::new()?;
    let (display, target, document, text, cache) =
        (&base.display, &base.target, &base.document, &base.text, &base.cache);
    let reference = eyekey_core::evaluation::Reference::new(
        document,
        display.holes_x,
        display.holes_y,
        OBJECTIVE_LEVEL,
        eyekey_core::evaluation::DEFAULT_THRESHOLD,
    )
    .with_known_font(eyekey_core::evaluation::KnownFontAttacker::new(
        text,
        document.width(),
        document.height(),
        display.holes_x,
        display.holes_y,
    )?);
    let offsets = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
    let mut kernels_md = table_header(&[
        "frames",
        "kernels the people at the design position look through",
        "people who read (95 % CI)",
        "time",
    ]);
    let mut md = table_header(&[
        "frames",
        "encode",
        "people at the design position who read (95 % CI)",
        "their evaluation",
        "target at 0 / 1 / 2 / 3 / 4 / 5 mm: worst legibility (ring positions read by the known-font attacker, of 4)",
    ]);
    let without_near_pupil = [
        (
            "encoded for the design position, shown fixed",
            0.0,
            HeadBoxMethod::Fixed,
            0.0,
            false,
        ),
        (
            "the same frames re-indexed for the tracked eye",
            0.0,
            HeadBoxMethod::Tracked,
            0.0,
            false,
        ),
        ("target stacked on a 2.5 mm ring", 2.5, HeadBoxMethod::Fixed, 0.0, false),
        ("target stacked on a 5 mm ring", 5.0, HeadBoxMethod::Fixed, 0.0, false),
        (
            "target stacked on a 5 mm ring, re-indexed for the tracked eye",
            5.0,
            HeadBoxMethod::Tracked,
            0.0,
            false,
        ),
        (
            "with the leak penalty (weight 3, the default), shown fixed",
            0.0,
            HeadBoxMethod::Fixed,
            3.0,
            false,
        ),
        (
            "with the leak penalty (weight 3), re-indexed for the tracked eye",
            0.0,
            HeadBoxMethod::Tracked,
            3.0,
            false,
        ),
        (
            "with the leak penalty (weight 3), target stacked on a 0.3 mm ring, shown fixed",
            0.3,
            HeadBoxMethod::Fixed,
            3.0,
            false,
        ),
        (
            "with the leak penalty (weight 3), target stacked on a 0.3 mm ring, re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            3.0,
            false,
        ),
        (
            "with the leak penalty (weight 3), target stacked on a 0.15 mm ring, re-indexed for the tracked eye",
            0.15,
            HeadBoxMethod::Tracked,
            3.0,
            false,
        ),
        (
            "with the leak penalty (weight 5), target stacked on a 0.3 mm ring, re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            5.0,
            false,
        ),
        (
            "with the leak penalty (weight 8), target stacked on a 0.3 mm ring, re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            8.0,
            false,
        ),
        (
            "with the leak penalty (weight 8), re-indexed for the tracked eye",
            0.0,
            HeadBoxMethod::Tracked,
            8.0,
            false,
        ),
        (
            "with the leak penalty (weight 12), target stacked on a 0.3 mm ring, re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            12.0,
            false,
        ),
        (
            "with the leak penalty (weight 20), target stacked on a 0.3 mm ring, re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            20.0,
            false,
        ),
        (
            "with the leak penalty (weight 12), target stacked on a 0.3 mm ring, camera decoys at −1, 0, +1 D (8 mm), re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            12.0,
            true,
        ),
        (
            "with the leak penalty (weight 20), target stacked on a 0.3 mm ring, camera decoys at −1, 0, +1 D (8 mm), re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            20.0,
            true,
        ),
    ];
    // The defaults (leak penalty 3 and 6 near-pupil decoys), fixed and tracked, and with the head-box ring.
    let with_near_pupil = [
        (
            "the defaults (leak penalty 3, 6 near-pupil decoys), shown fixed",
            0.0,
            HeadBoxMethod::Fixed,
            3.0,
            false,
        ),
        (
            "the defaults, re-indexed for the tracked eye",
            0.0,
            HeadBoxMethod::Tracked,
            3.0,
            false,
        ),
        (
            "the defaults, target stacked on a 0.3 mm ring, re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            3.0,
            false,
        ),
        (
            "the defaults with leak penalty 12, target stacked on a 0.3 mm ring, re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            12.0,
            false,
        ),
        (
            "the defaults, target stacked on a 0.3 mm ring, camera decoys at −1, 0, +1 D (8 mm), re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            3.0,
            true,
        ),
    ];
    // The near-pupil decoys also looked at on a 0.8 mm ring around the seat (`near_pupil_ring_mm`).
    let with_seat_ring = [(
        "the defaults with the near-pupil decoys also on a 0.8 mm ring, target stacked on a 0.3 mm ring, re-indexed for the tracked eye",
        0.3,
        HeadBoxMethod::Tracked,
        3.0,
        false,
    )];
    // Camera decoys at 0 and +2 D (4 mm) at the seat and on a 0.8 mm ring around it (`camera_decoy_ring_mm`):
    // a camera 0.8 mm right of the seat reads the ring-stacked frames, and so do cameras at the repeats.
    let with_camera_ring = [(
        "the defaults, target stacked on a 0.3 mm ring, camera decoys at 0, +2 D (4 mm) also on a 0.8 mm ring, re-indexed for the tracked eye",
        0.3,
        HeadBoxMethod::Tracked,
        3.0,
        true,
    )];
    // Both rings, and the camera decoys at −1 D as well.
    let with_both_rings = [
        (
            "the defaults with the near-pupil decoys also on a 0.8 mm ring, target stacked on a 0.3 mm ring, camera decoys at −1, 0, +2 D (4 mm) also on a 0.8 mm ring, re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            3.0,
            true,
        ),
        (
            "the same with leak penalty 2 (near-pupil and camera decoys also on a 0.8 mm ring, target on a 0.3 mm ring), re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            2.0,
            true,
        ),
    ];
    // The same at leak weight 2 and 3 with the target at 8 positions on its ring instead of 4.
    let with_eight_stacked = [
        (
            "the same with leak penalty 2 and the target at 8 positions on its 0.3 mm ring (near-pupil and camera decoys also on a 0.8 mm ring), re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            2.0,
            true,
        ),
        (
            "the same with leak penalty 3 and the target at 8 positions on its 0.3 mm ring (near-pupil and camera decoys also on a 0.8 mm ring), re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            3.0,
            true,
        ),
    ];
    // Between the two: the target at 6 positions on its ring, at leak weight 3, 4, 3.5 and 3.75.
    let with_six_stacked = [
        (
            "the same with leak penalty 3 and the target at 6 positions on its 0.3 mm ring (near-pupil and camera decoys also on a 0.8 mm ring), re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            3.0,
            true,
        ),
        (
            "the same with leak penalty 4 and the target at 6 positions on its 0.3 mm ring (near-pupil and camera decoys also on a 0.8 mm ring), re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            4.0,
            true,
        ),
        (
            "the same with leak penalty 3.5 and the target at 6 positions on its 0.3 mm ring (near-pupil and camera decoys also on a 0.8 mm ring), re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            3.5,
            true,
        ),
        (
            "the same with leak penalty 3.75 and the target at 6 positions on its 0.3 mm ring (near-pupil and camera decoys also on a 0.8 mm ring), re-indexed for the tracked eye",
            0.3,
            HeadBoxMethod::Tracked,
            3.75,
            true,
        ),
    ];
    // The same with camera decoys at −3 D as well (a camera at −3 D read those frames 14.4 mm left).
    let with_six_stacked_far_focus = [(
        "the same with leak penalty 3, the target at 6 positions on its 0.3 mm ring and camera decoys at −3, −1, 0, +2 D (near-pupil and camera decoys also on a 0.8 mm ring), re-indexed for the tracked eye",
        0.3,
        HeadBoxMethod::Tracked,
        3.0,
        true,
    )];
    // The same with the camera decoys' ring at 1.2 mm (a camera 14.4 mm left, 1.6 mm past a repeat, read the
    // 6-position frames).
    let with_six_stacked_wider_camera_ring = [(
        "the same with leak penalty 3, the target at 6 positions on its 0.3 mm ring and camera decoys on a 1.2 mm ring (near-pupil decoys on a 0.8 mm ring), re-indexed for the tracked eye",
        0.3,
        HeadBoxMethod::Tracked,
        3.0,
        true,
    )];
    // The same with the camera decoys behind 8 mm instead of 4 mm (the camera that read the 6-position frames
    // 14.4 mm left was at 8 mm).
    let with_six_stacked_wide_camera_decoys = [(
        "the same with leak penalty 3, the target at 6 positions on its 0.3 mm ring and camera decoys behind 8 mm (near-pupil and camera decoys also on a 0.8 mm ring), re-indexed for the tracked eye",
        0.3,
        HeadBoxMethod::Tracked,
        3.0,
        true,
    )];
    // The same with the camera decoys behind both 4 and 8 mm (behind 8 mm alone they left cameras behind 2 mm
    // reading).
    let with_six_stacked_two_apertures = [(
        "the same with leak penalty 3, the target at 6 positions on its 0.3 mm ring and camera decoys behind 4 and 8 mm (near-pupil and camera decoys also on a 0.8 mm ring), re-indexed for the tracked eye",
        0.3,
        HeadBoxMethod::Tracked,
        3.0,
        true,
    )];
    // Each group of rows with what its rows share: near-pupil decoys and their ring around the seat, the focus
    // settings of camera decoys also on a ring (empty: no such ring), the target's positions on its ring, the
    // camera decoys' ring radius and their apertures (the first `camera_decoy_aperture_mm`, the rest extra). Other
    // decoy weights, ring weights and seeds: `Overrides`.
    type Shared = (u32, f64, &'static [f64], u32, f64, &'static [f64]);
    let groups: [(&[HeadBoxRow], Shared); 11] = [
        (&without_near_pupil, (0, 0.0, &[], 4, 0.8, &[4.0])),
        (&with_near_pupil, (6, 0.0, &[], 4, 0.8, &[4.0])),
        (&with_seat_ring, (6, 0.8, &[], 4, 0.8, &[4.0])),
        (&with_camera_ring, (6, 0.0, &[0.0, 2.0], 4, 0.8, &[4.0])),
        (&with_both_rings, (6, 0.8, &[-1.0, 0.0, 2.0], 4, 0.8, &[4.0])),
        (&with_eight_stacked, (6, 0.8, &[-1.0, 0.0, 2.0], 8, 0.8, &[4.0])),
        (&with_six_stacked, (6, 0.8, &[-1.0, 0.0, 2.0], 6, 0.8, &[4.0])),
        (
            &with_six_stacked_far_focus,
            (6, 0.8, &[-3.0, -1.0, 0.0, 2.0], 6, 0.8, &[4.0]),
        ),
        (
            &with_six_stacked_wider_camera_ring,
            (6, 0.8, &[-1.0, 0.0, 2.0], 6, 1.2, &[4.0]),
        ),
        (
            &with_six_stacked_wide_camera_decoys,
            (6, 0.8, &[-1.0, 0.0, 2.0], 6, 0.8, &[8.0]),
        ),
        (
            &with_six_stacked_two_apertures,
            (6, 0.8, &[-1.0, 0.0, 2.0], 6, 0.8, &[4.0, 8.0]),
        ),
    ];
    let rows = groups
        .into_iter()
        .flat_map(|(rows, (np, np_ring, focus, positions, ring, aperture))| {
            rows.iter()
                .map(move |&row| (row, np, np_ring, focus, positions, ring, aperture))
        });
    for (
        (label, head_radius_mm, method, leak_weight, cameras),
        near_pupil,
        near_pupil_ring_mm,
        camera_ring,
        head_positions,
        camera_ring_mm,
        camera_apertures_mm,
    ) in rows
    {
        if only.is_some_and(|f| !f.split('|').any(|part| label.contains(part))) {
            continue;
        }
        let encoding = Encoding {
            label,
            decoys: 6,
            decoy_weight: 0.3,
            head_radius_mm,
            leak_weight,
            cameras,
            near_pupil,
            near_pupil_ring_mm,
            head_positions,
            ..if camera_ring.is_empty() {
                BASELINE
            } else {
                Encoding {
                    camera_focus_d: camera_ring,
                    camera_ring_mm,
                    camera_aperture_mm: camera_apertures_mm[0],
                    camera_extra_apertures_mm: &camera_apertures_mm[1..],
                    ..CAMERA_RING
                }
            }
        };
        let (encoding, label) = &overrides.apply(&encoding);
        let (l, t_encode) = base.encode(encoding, max_iterations)?;
        let evaluation = EvaluationOptions {
            optics: Optics::Wave,
            sub_rays: 12,
            ..EvaluationOptions::population_only(population, Some(text.clone()))
        };
        let (ev, t_eval) = base.evaluate(&l, &evaluation, &|_| {})?;
        let p = ev.report.population.as_ref().expect("a population was asked for");
        if seat_kernel_draws > 0 {
            seat_kernels(
                &base,
                &l,
                &reference,
                &evaluation,
                seat_kernel_draws,
                label,
                &mut kernels_md,
            )?;
        }
        let rings = head_rings(display, &l, target, &reference, method, &offsets, cache)?;
        let cells: Vec<String> = rings.iter().map(|(_, w, read)| format!("{w:.2} ({read})")).collect();
        writeln!(
            md,
            "| {label} | {t_encode:.0} s | {} of {} ({:.1}–{:.1} %) | {t_eval:.0} s | {} |",
            p.readable_count,
            p.count,
            100.0 * p.readable_ci95.0,
            100.0 * p.readable_ci95.1,
            cells.join(" / ")
        )?;
        eprintln!("{label}: {}", md.lines().last().unwrap_or(""));
    }
    if seat_kernel_draws > 0 {
        write!(
            md,
            "\nThe same {population} people at the design position (the evaluation's sample), each looked at \
             through the evaluation's kernel draw again, through {seat_kernel_draws} more draws of as many \
             sub-rays, and through kernels drawn with {}× the sub-rays (the target guard's, near their \
             expectation, which is what a real eye sees):\n\n{kernels_md}",
            eyekey_core::encoding::pipeline::GUARD_SUB_RAYS
        )?;
    }
    std::fs::write(
        out.join(if only.is_some() {
            "headbox-only.md"
        } else {
            "headbox.md"
        }),
        &md,
    )?;
    Ok(md)
}

#[cfg(test)]
mod tests {
    use super::{mm, signed_mm};

    #[test]
    fn positions_are_written_to_a_tenth_of_a_millimetre() {
        assert_eq!(mm(20.0), "20");
        assert_eq!(mm(12.8), "12.8");
        assert_eq!(mm(19.199999), "19.2");
        assert_eq!(signed_mm(-12.8), "-12.8");
        assert_eq!(signed_mm(0.0), "+0");
        assert_eq!(signed_mm(-0.01), "+0");
        assert_eq!(signed_mm(500.0), "+500");
    }
}
