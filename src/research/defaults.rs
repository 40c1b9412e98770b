//! `eyekey experiment defaults`: does every preset's default encode serve its target? For each display preset,
//! held-out targets (people sampled with seeds no encoder or evaluation uses, at their own pupils) each get a PIN
//! slip of their own digits, encoded with the default options (`EncodeOptions::default()`) and the slip's text
//! hint; the known-font attacker judges the target's view, and held-out people at the target's
//! position say who else reads.

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
/// attacker. Writes `out/defaults.md`; returns it.
pub fn run(
    out: &Path,
    targets: u32,
    population: u32,
    target_looks: u32,
    only: &[String],
    options: EncodeOptions,
) -> Result<String> {
    options.validate().map_err(|e| anyhow::anyhow!("encode options: {e}"))?;
    std::fs::create_dir_all(out)?;
    let mut md = table_header(&[
        "preset",
        "target (pupil)",
        "PIN",
        "encode",
        "decoy weights scaled by",
        "target: legibility, known font",
        "target read under other evaluation seeds (worst legibility, worst known-font margin)",
        "target with 8× the sub-rays: legibility, known font",
        "held-out people who read",
        "their pupils",
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
                    document_text: Some(text.clone()),
                    ..options.clone()
                },
            };
            let t = Instant::now();
            let enc = encode(&spec, &cache, &|_| {}, &AtomicBool::new(false))?;
            let t_encode = t.elapsed().as_secs_f64();
            let eval_options = EvaluationOptions {
                optics: options.optics,
                ..EvaluationOptions::population_only(population, Some(text))
            };
            let ev = evaluate(
                &display,
                &enc.light_field,
                &document,
                OBJECTIVE_LEVEL,
                &target,
                &[],
                &eval_options,
                &cache,
                &|_| {},
                &AtomicBool::new(false),
            )?;
            // The target's view alone, its kernels drawn with `seed` and `sub_rays`.
            let target_view = |seed: u64, sub_rays: u32| {
                evaluate(
                    &display,
                    &enc.light_field,
                    &document,
                    OBJECTIVE_LEVEL,
                    &target,
                    &[],
                    &EvaluationOptions {
                        optics: eval_options.optics,
                        seed,
                        sub_rays,
                        ..EvaluationOptions::population_only(0, eval_options.document_text.clone())
                    },
                    &cache,
                    &|_| {},
                    &AtomicBool::new(false),
                )
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
                "| `{name}` | {k} ({:.1} mm) | {digits} | {t_encode:.0} s | {:.3} | {:.2}, {kf}{} | {looks} | {converged} | {} of {} | {readers} |",
                target.pupil_diameter_mm,
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
