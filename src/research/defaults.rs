//! `eyekey experiment defaults`: does every preset's default encode serve its target? For each display preset,
//! held-out targets (people sampled with seeds no encoder or evaluation uses, at their own pupils) each get a PIN
//! slip of their own digits, encoded with the default options (`EncodeOptions::default()`) and the slip's text
//! hint (or, with `--no-hint`, as an uploaded image: the encoder then holds the target to the reads bar of
//! legibility); the known-font attacker judges the target's view, and held-out people at the target's
//! position say who else reads. A target whose encode fails (`target_cannot_read`) is a row of its own.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::Result;
use rand::{Rng, SeedableRng};

use super::experiment::pin_slip_of;
use super::table_header;
use eyekey_core::encoding::pipeline::{encode, EncodeOptions, JobSpec, OBJECTIVE_LEVEL};
use eyekey_core::evaluation::{evaluate, EvaluationOptions};
use eyekey_core::physics::display::{DisplayGeometry, PRESETS};
use eyekey_core::physics::population::sample_population;
use eyekey_core::physics::transport::TransportCache;

/// Runs `targets` held-out targets on every preset (or those named in `only`), each encoded with `options` (the
/// defaults, or variants of them) and judged with `population` held-out people; the target's view is also
/// drawn with `target_looks` further evaluation seeds (the kernels' sampling noise), each read by the known-font
/// attacker. Without `hint` the encoder is not told the slip's text (the evaluation still is). Writes
/// `out/defaults.md`; returns it.
pub fn run(
    out: &Path,
    targets: u32,
    population: u32,
    target_looks: u32,
    only: &[String],
    options: EncodeOptions,
    hint: bool,
) -> Result<String> {
    options.validate().map_err(|e| anyhow::anyhow!("encode options: {e}"))?;
    std::fs::create_dir_all(out)?;
    let mut md = table_header(&[
        "preset",
        "target (pupil)",
        "PIN",
        "encode",
        "decoys' weight: start × scale",
        "target: legibility, known font",
        "target read under other evaluation seeds (worst legibility, worst known-font margin)",
        "target with 8× the sub-rays: legibility, known font",
        "target refocused: legibility, known-font margin",
        "held-out people who read",
        "their pupils",
        "wavefront difference from the target's (RMS, orders ≥ 2): readers' median, everyone's median",
    ]);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0xD0C5);
    for &name in PRESETS {
        // Every preset's PINs are drawn whether it runs or not, so a run of some presets sees the same documents
        // as a run of all.
        let pins: Vec<String> = (0..targets)
            .map(|_| (0..4).map(|_| char::from(b'0' + rng.gen_range(0..10u8))).collect())
            .collect();
        if !only.is_empty() && !only.iter().any(|o| o == name) {
            continue;
        }
        let display = DisplayGeometry::preset(name)?;
        let cache = TransportCache::default();
        for (k, digits) in pins.into_iter().enumerate() {
            let target = sample_population(1, 0xD0C5_0000 + k as u64, Default::default()).remove(0);
            let (document, text) = pin_slip_of(display.holes_x * 4, display.holes_y * 4, &digits);
            let spec = JobSpec {
                display: display.clone(),
                target: target.clone(),
                target_label: format!("held-out target {k}"),
                observers: vec![],
                document: document.clone(),
                decoy: None,
                options: EncodeOptions {
                    document_text: hint.then(|| text.clone()),
                    ..options.clone()
                },
            };
            let t = Instant::now();
            let enc = match encode(&spec, &cache, &|_| {}, &AtomicBool::new(false)) {
                Ok(enc) => enc,
                Err(e @ eyekey_core::encoding::pipeline::PipelineError::TargetCannotRead { .. }) => {
                    writeln!(
                        md,
                        "| `{name}` | {k} ({:.1} mm) | {digits} | {:.0} s | **{e}** | | | | | | | |",
                        target.pupil_diameter_mm,
                        t.elapsed().as_secs_f64()
                    )?;
                    eprintln!("{}", md.lines().last().unwrap_or(""));
                    continue;
                }
                Err(e) => return Err(e.into()),
            };
            let t_encode = t.elapsed().as_secs_f64();
            let eval_options = EvaluationOptions {
                optics: options.optics,
                ..EvaluationOptions::population_only(population, Some(text))
            };
            // The encoded light field as the evaluation sees it, with `options`, the target refocused by `dd`.
            let judge_at = |options: &EvaluationOptions, dd: f64| {
                let person = if dd == 0.0 {
                    target.clone()
                } else {
                    target.refocused(dd)
                };
                evaluate(
                    &display,
                    &enc.light_field,
                    &document,
                    OBJECTIVE_LEVEL,
                    &person,
                    &[],
                    options,
                    &cache,
                    &|_| {},
                    &AtomicBool::new(false),
                )
            };
            let judge = |options: &EvaluationOptions| judge_at(options, 0.0);
            let ev = judge(&eval_options)?;
            // The target's view alone, its kernels drawn with `seed` and `sub_rays`.
            let target_view = |seed: u64, sub_rays: u32| {
                judge(&EvaluationOptions {
                    optics: eval_options.optics,
                    seed,
                    sub_rays,
                    ..EvaluationOptions::population_only(0, eval_options.document_text.clone())
                })
                .map(|ev| ev.report.target)
            };
            // The same view drawn with other evaluation seeds: a borderline target reads under some and not others.
            let (mut looks_read, mut worst, mut worst_margin) = (0, f64::INFINITY, f64::INFINITY);
            for j in 1..=target_looks {
                let look = target_view(eval_options.seed.wrapping_add(1_000 * j as u64), eval_options.sub_rays)?;
                looks_read += u32::from(look.readable);
                worst = worst.min(look.legibility);
                if let Some(k) = &look.known_font {
                    worst_margin = worst_margin.min(k.margin);
                }
            }
            // And once with 8 times the evaluation's sub-rays: kernels near their expectation, which is what a
            // real eye sees.
            // Refocused by ±0.25 D (accommodation's drift while one looks), judged by the known-font attacker.
            let mut refocused = Vec::new();
            for dd in [-0.25, 0.25] {
                let t = judge_at(
                    &EvaluationOptions {
                        optics: eval_options.optics,
                        ..EvaluationOptions::population_only(0, eval_options.document_text.clone())
                    },
                    dd,
                )?
                .report
                .target;
                refocused.push(format!(
                    "{:+.2} D: {:.2}, {}{}",
                    dd,
                    t.legibility,
                    t.known_font
                        .as_ref()
                        .map_or("–".into(), |k| format!("{:+.3}", k.margin)),
                    if t.readable { "" } else { " **not read**" }
                ));
            }
            let refocused = refocused.join("; ");
            let converged = target_view(eval_options.seed, 8 * eval_options.sub_rays)?;
            let converged = format!(
                "{:.2}, {}{}",
                converged.legibility,
                super::known_font_cell(&converged),
                if converged.readable { "" } else { " **not read**" }
            );
            let looks = if target_looks == 0 {
                "–".to_string()
            } else {
                format!("{looks_read} of {target_looks} ({worst:.2}, {worst_margin:+.3})")
            };
            let r = &ev.report;
            let kf = super::known_font_cell(&r.target);
            let p = r.population.as_ref().expect("a population was asked for");
            // The readers' pupils: the evaluation's people, drawn again with its seed.
            let people = sample_population(population as usize, eval_options.seed, Default::default());
            let mut pupils: Vec<f64> = p
                .people
                .iter()
                .filter(|s| s.readable)
                .filter_map(|s| s.label.strip_prefix("person_")?.parse::<usize>().ok())
                .filter_map(|k| Some(people.get(k)?.pupil_diameter_mm))
                .collect();
            pupils.sort_by(f64::total_cmp);
            // How far each person's eye is from the target's: the RMS of the difference of the two wavefronts over
            // the smaller of the two pupils (both given that pupil, ANSI Z80.28 Annex B), defocus and above.
            let differences: Vec<(bool, f64)> = p
                .people
                .iter()
                .filter_map(|s| {
                    let k = s.label.strip_prefix("person_")?.parse::<usize>().ok()?;
                    Some((s.readable, wavefront_difference_um(people.get(k)?, &target).ok()?))
                })
                .collect();
            let median = |mut v: Vec<f64>| {
                v.sort_by(f64::total_cmp);
                v.get(v.len() / 2).map_or("–".to_string(), |m| format!("{m:.2} µm"))
            };
            let distance = format!(
                "{}, {}",
                median(differences.iter().filter(|d| d.0).map(|d| d.1).collect()),
                median(differences.iter().map(|d| d.1).collect())
            );
            let smaller = pupils.iter().filter(|&&q| q <= target.pupil_diameter_mm).count();
            let readers = match (pupils.first(), pupils.last()) {
                (Some(lo), Some(hi)) => format!(
                    "{lo:.1}–{hi:.1} mm, median {:.1}; {smaller} at most the target's",
                    pupils[pupils.len() / 2]
                ),
                _ => "–".into(),
            };
            writeln!(
                md,
                "| `{name}` | {k} ({:.1} mm) | {digits} | {t_encode:.0} s | {} × {:.3} | {:.2}, {kf}{} | {looks} | {converged} | {refocused} | {} of {} | {readers} | {distance} |",
                target.pupil_diameter_mm,
                options.decoy_weight_on(&display),
                enc.solver.decoy_weight_scale,
                r.target.legibility,
                if r.target.readable { "" } else { " **not read**" },
                p.readable_count,
                p.count,
            )?;
            eprintln!("{}", md.lines().last().unwrap_or(""));
        }
    }
    std::fs::write(out.join("defaults.md"), &md)?;
    Ok(md)
}

/// The RMS (µm) of the difference between `a`'s and `b`'s wavefronts in radial orders 2 and up, both over the
/// smaller of their two pupils (the larger rescaled to it, ANSI Z80.28 Annex B): with unit-RMS terms, the root of
/// the summed squared coefficient differences.
fn wavefront_difference_um(
    a: &eyekey_core::physics::profile::VisionProfile,
    b: &eyekey_core::physics::profile::VisionProfile,
) -> Result<f64> {
    use eyekey_core::physics::zernike::{ZernikeCoefficients, MAX_RADIAL_ORDER};
    let pupil = a.pupil_diameter_mm.min(b.pupil_diameter_mm);
    let at = |p: &eyekey_core::physics::profile::VisionProfile| -> Result<Vec<f64>> {
        Ok(ZernikeCoefficients::new(p.pupil_diameter_mm, p.zernike_um.clone())?
            .rescaled(pupil)?
            .coefficients_um)
    };
    let (ca, cb) = (at(a)?, at(b)?);
    let n = ca.len().max(cb.len());
    let diff: Vec<f64> = (0..n)
        .map(|j| ca.get(j).copied().unwrap_or(0.0) - cb.get(j).copied().unwrap_or(0.0))
        .collect();
    Ok(ZernikeCoefficients::new(pupil, diff)?.rms_um(2..=MAX_RADIAL_ORDER))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wavefront_difference_is_the_rms_of_the_coefficient_differences_over_the_smaller_pupil() {
        let person = |pupil: f64, c: &[(usize, f64)]| {
            let mut p = sample_population(1, 3, Default::default()).remove(0);
            p.pupil_diameter_mm = pupil;
            p.zernike_um = vec![0.0; 15];
            for &(j, v) in c {
                p.zernike_um[j] = v;
            }
            p
        };
        // Same pupil: defocus (j = 4) 0.3 against 0 and coma (j = 7) 0.1 against 0.5: √(0.3² + 0.4²) = 0.5; tilt
        // (j = 1) is left out.
        let a = person(5.0, &[(4, 0.3), (7, 0.1), (1, 2.0)]);
        let b = person(5.0, &[(7, 0.5)]);
        assert!((wavefront_difference_um(&a, &b).unwrap() - 0.5).abs() < 1e-12);
        // Pure defocus over 6 mm seen through 4 mm: the same dioptric power, so c(2,0) scales by (4/6)², and an
        // eye of 4 mm with that coefficient does not differ.
        let wide = person(6.0, &[(4, 0.9)]);
        let narrow = person(4.0, &[(4, 0.9 * (4.0f64 / 6.0).powi(2))]);
        assert!(wavefront_difference_um(&wide, &narrow).unwrap() < 1e-12);
        assert!((wavefront_difference_um(&wide, &person(4.0, &[])).unwrap() - 0.4).abs() < 1e-12);
    }
}
