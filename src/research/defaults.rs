//! `eyekey experiment defaults`: does the target read what a default encode makes for it? For each display
//! preset, held-out targets (people sampled with seeds no encoder or evaluation uses) each get a document of their
//! own digits: a PIN slip in eyekey's font, encoded with its text hint (or, with `--no-hint`, as an uploaded image,
//! which the encoder then holds to the reads bar of legibility), or a PIN slip or two lines of text in a font eyekey
//! does not draw (always uploaded). The known-font attacker for the document's own font and layout reads the
//! target's view under four kernel draws at its profile's focus and refocused by ±0.25 D, and once with its pupil
//! 0.5 mm narrower and wider; held-out people at the target's seat say who else reads, at their own focus and at any
//! focus of their accommodation range (−1 to +2 D in 0.25 D steps). A target whose encode fails
//! (`target_cannot_read`) counts as not reading.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::Result;
use image::RgbImage;
use rand::{Rng, SeedableRng};

use super::experiment::pin_slip_of;
use super::fonts::{draw_filling, DocFont};
use super::table_header;
use eyekey_core::encoding::pipeline::{encode, EncodeOptions, JobSpec, PipelineError, OBJECTIVE_LEVEL};
use eyekey_core::evaluation::{
    luminance, luminance_of, EvaluationOptions, KnownFontAttacker, LearnedReader, Reference, DEFAULT_THRESHOLD,
};
use eyekey_core::physics::accommodation::Accommodation;
use eyekey_core::physics::display::{DisplayGeometry, PRESETS};
use eyekey_core::physics::observer::Observer;
use eyekey_core::physics::population::{sample_person_with_pupil, sample_population};
use eyekey_core::physics::profile::VisionProfile;
use eyekey_core::physics::transport::{EyePosition, TransportCache, TransportOptions};

/// The documents an experiment run encodes.
pub enum Documents {
    /// PIN slips in eyekey's 5×7 font ("PIN" over four digits), as `eyekey example document` draws them.
    PinSlips,
    /// Documents in a font eyekey does not draw (a file name in Debian's font directories): a PIN slip, or with
    /// `lines` two lines of text ("A" and "B", each with four digits; eight secret characters).
    InFont {
        /// The font's file name.
        font: String,
        /// Two lines of text instead of a PIN slip.
        lines: bool,
    },
}

/// What one run measures.
pub struct Setup {
    /// Held-out targets per display.
    pub targets: u32,
    /// Held-out people at each target's seat.
    pub population: u32,
    /// Kernel draws of each of the target's looks (the evaluation's and further seeds).
    pub target_looks: u32,
    /// The encoder is told a PIN slip's text (eyekey's font only).
    pub hint: bool,
    /// Targets' pupils spread evenly over 3–7 mm, their aberrations stated over 7.5 mm (else the population's
    /// 4–7 mm, stated at the viewing pupil).
    pub wide_pupils: bool,
    /// The documents.
    pub documents: Documents,
}

/// One target's document and the attacker that knows its font and layout.
struct Document {
    image: RgbImage,
    text: String,
    hint: Option<eyekey_core::evaluation::DocumentText>,
    attacker: KnownFontAttacker,
}

impl Documents {
    /// The name in tables.
    fn name(&self, hint: bool) -> String {
        match self {
            Self::PinSlips if hint => "PIN slip in eyekey's font, text hint".into(),
            Self::PinSlips => "PIN slip in eyekey's font, uploaded".into(),
            Self::InFont { font, lines: false } => format!("PIN slip in {font}, uploaded"),
            Self::InFont { font, lines: true } => format!("two lines in {font}, uploaded"),
        }
    }

    /// Target `k`'s document on a `width`×`height` page read on a `grid`-sized retina, of `digits` (eight).
    fn draw(
        &self,
        font: Option<&DocFont>,
        digits: &str,
        size: (u32, u32),
        grid: (u32, u32),
        hint: bool,
    ) -> Result<Document> {
        let (width, height) = size;
        match (self, font) {
            (Self::PinSlips, _) => {
                let (image, text) = pin_slip_of(width, height, &digits[..4]);
                let attacker = KnownFontAttacker::new(&text, width, height, grid.0, grid.1)?;
                Ok(Document {
                    image,
                    text: digits[..4].to_string(),
                    hint: hint.then_some(text),
                    attacker,
                })
            }
            (Self::InFont { lines, .. }, Some(font)) => {
                let text: Vec<String> = if *lines {
                    vec![format!("A {}", &digits[..4]), format!("B {}", &digits[4..])]
                } else {
                    vec!["PIN".into(), digits[..4].to_string()]
                };
                let drawn = draw_filling(font, &text, 0.85, width, height, grid)?;
                Ok(Document {
                    image: drawn.document,
                    text: text.join(" / "),
                    hint: None,
                    attacker: drawn.attacker,
                })
            }
            (Self::InFont { .. }, None) => anyhow::bail!("no font loaded"),
        }
    }
}

/// The seed of the `j`-th kernel draw the experiment views with: the evaluation's (j = 0), then others 1,000
/// apart, none of them the encoder's.
fn look_seed(j: u32) -> u64 {
    EvaluationOptions {
        seed: EvaluationOptions::default().seed.wrapping_add(1_000 * u64::from(j)),
        ..Default::default()
    }
    .transport_seed()
}

/// How one look reads: the known-font attacker's margin (negative when a character is misread) and legibility.
#[derive(Clone, Copy)]
struct Look {
    reads: bool,
    /// The learned reader read every digit (never, where none was trained on the document's layout).
    learned: bool,
    margin: f64,
    legibility: f64,
}

/// Runs `setup` on every preset (or those named in `only`), each target encoded with `options` (seed and all).
/// Writes `out/defaults.md` (a summary per display, then a row per target); returns it.
pub fn run(out: &Path, setup: &Setup, only: &[String], options: EncodeOptions) -> Result<String> {
    options.validate().map_err(|e| anyhow::anyhow!("encode options: {e}"))?;
    std::fs::create_dir_all(out)?;
    let font = match &setup.documents {
        Documents::InFont { font, .. } => Some(DocFont::load(font)?),
        Documents::PinSlips => None,
    };
    let doc_name = setup.documents.name(setup.hint);
    let mut rows = table_header(&[
        "preset",
        "target (pupil)",
        "document",
        "encode",
        "decoys' weight: start × scale",
        "at focus: draws read (worst margin, worst legibility)",
        "−0.25 D: draws read (worst margin)",
        "+0.25 D: draws read (worst margin)",
        "pupil −0.5 / +0.5 mm: margin",
        "held-out people who read: known font or learned reader; legibility ≥ 0.22",
        "and refocusing −1 to +2 D: known font or learned reader; legibility ≥ 0.22",
    ]);
    let mut summary = table_header(&[
        "display",
        "document",
        "security",
        "targets (pupils)",
        "read at focus, every draw",
        "read at −0.25 and +0.25 D, every draw",
        "read in all three",
        "worst margin at focus (range over targets)",
        "people at the seat who read: known font or learned reader",
        "legibility ≥ 0.22",
        "refocusing −1 to +2 D: known font or learned reader",
        "refocusing: legibility ≥ 0.22",
        "encode, median (max)",
    ]);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0xD0C5);
    for &name in PRESETS {
        // Every preset's digits are drawn whether it runs or not, so a run of some presets sees the same documents
        // as a run of all.
        let digits: Vec<String> = (0..setup.targets)
            .map(|_| (0..8).map(|_| char::from(b'0' + rng.gen_range(0..10u8))).collect())
            .collect();
        if !only.is_empty() && !only.iter().any(|o| o == name) {
            continue;
        }
        let display = DisplayGeometry::preset(name)?;
        let cache = TransportCache::default();
        let mut tally = Tally::default();
        for (k, digits) in digits.iter().enumerate() {
            let target = held_out_target(k, setup);
            let view = |person: &VisionProfile, j: u32| -> Result<Observer> {
                let topts = TransportOptions {
                    sub_rays: EvaluationOptions::default().sub_rays,
                    seed: look_seed(j),
                    ..Default::default()
                };
                Ok(Observer::new(
                    &display,
                    person,
                    EyePosition::default(),
                    &topts,
                    options.optics,
                    &cache,
                )?)
            };
            let g = view(&target, 0)?.grid();
            let doc = setup.documents.draw(
                font.as_ref(),
                digits,
                (display.holes_x * 4, display.holes_y * 4),
                (g.width, g.height),
                setup.hint,
            )?;
            let reference = Reference::new(&doc.image, g.width, g.height, OBJECTIVE_LEVEL, DEFAULT_THRESHOLD);
            let spec = JobSpec {
                display: display.clone(),
                target: target.clone(),
                target_label: format!("held-out target {k}"),
                observers: vec![],
                document: doc.image.clone(),
                decoy: None,
                options: EncodeOptions {
                    document_text: doc.hint.clone(),
                    ..options.clone()
                },
            };
            let t = Instant::now();
            let encoded = encode(&spec, &cache, &|_| {}, &AtomicBool::new(false));
            let seconds = t.elapsed().as_secs_f64();
            tally.seconds.push(seconds);
            let pupil = target.pupil_diameter_mm;
            tally.pupils.push(pupil);
            let enc = match encoded {
                Ok(enc) => enc,
                // Refused before the solve (text too small for the legibility judge on this display) or after it
                // (the target cannot read): either way the target is not shown the document.
                Err(e @ (PipelineError::TargetCannotRead { .. } | PipelineError::Invalid { .. })) => {
                    tally.failed += 1;
                    writeln!(
                        rows,
                        "| `{name}` | {k} ({pupil:.1} mm) | {} | {seconds:.0} s | **{e}** | | | | | | |",
                        doc.text
                    )?;
                    eprintln!("{}", rows.lines().last().unwrap_or(""));
                    continue;
                }
                Err(e) => return Err(e.into()),
            };
            let Judged {
                n,
                at_focus: (at_focus, focus_worst),
                near: (near, near_worst),
                far: (far, far_worst),
                pupils,
                people,
                by_font,
                by_legibility,
                refocusing,
            } = judge(&view, &doc, &reference, &enc.light_field, &target, setup)?;
            tally.read_focus += u32::from(at_focus == n);
            tally.read_refocused += u32::from(near == n && far == n);
            tally.read_all += u32::from(at_focus == n && near == n && far == n);
            tally.margins.push(focus_worst.margin);
            tally.people += people;
            tally.by_font += by_font;
            tally.by_legibility += by_legibility;
            tally.refocusing[0] += refocusing[0];
            tally.refocusing[1] += refocusing[1];
            let mark = |r: u32| if r == n { String::new() } else { " **misread**".into() };
            writeln!(
                rows,
                "| `{name}` | {k} ({pupil:.1} mm) | {} | {seconds:.0} s | {:.3} × {:.3} | {at_focus} of {n} ({:+.3}, {:.2}){} | {near} of {n} ({:+.3}){} | {far} of {n} ({:+.3}){} | {:+.3}, {:+.3} | {by_font}; {by_legibility} of {} | {}; {} of {} |",
                doc.text,
                options.decoy_weight_on(&display),
                enc.solver.decoy_weight_scale,
                focus_worst.margin,
                focus_worst.legibility,
                mark(at_focus),
                near_worst.margin,
                mark(near),
                far_worst.margin,
                mark(far),
                pupils[0].margin,
                pupils[1].margin,
                people,
                refocusing[0],
                refocusing[1],
                people,
            )?;
            eprintln!("{}", rows.lines().last().unwrap_or(""));
        }
        writeln!(summary, "{}", tally.row(name, &doc_name, &options))?;
    }
    let md = format!("{summary}\n{rows}");
    std::fs::write(out.join("defaults.md"), &md)?;
    Ok(md)
}

/// What the experiment measured of one encoded light field `l`.
struct Judged {
    /// Kernel draws per look.
    n: u32,
    /// The target at its focus, −0.25 D and +0.25 D: draws read, and the worst look.
    at_focus: (u32, Look),
    near: (u32, Look),
    far: (u32, Look),
    /// The target with its pupil 0.5 mm narrower and wider, one draw each.
    pupils: [Look; 2],
    /// Held-out people at the seat, those the known-font attacker or the learned reader reads, and those at
    /// legibility ≥ 0.22.
    people: u32,
    by_font: u32,
    by_legibility: u32,
    /// Of the people, those the known-font attacker or the learned reader reads, and those at legibility ≥ 0.22,
    /// at some focus of
    /// their accommodation range ([`Accommodation::default`]).
    refocusing: [u32; 2],
}

/// Judges `l` for `target` and `setup.population` held-out people at the seat, each look through `view`
/// (a person and a kernel draw) read by `doc`'s attacker and scored against `reference`.
fn judge(
    view: &dyn Fn(&VisionProfile, u32) -> Result<Observer>,
    doc: &Document,
    reference: &Reference,
    l: &[f32],
    target: &VisionProfile,
    setup: &Setup,
) -> Result<Judged> {
    // The learned reader too, where one was trained on the document's layout (eyekey's PIN slip on `secure`).
    let learned = LearnedReader::for_document(&doc.attacker, (reference.width as u32, reference.height as u32));
    let look = |o: &Observer| -> Look {
        let lum = luminance(&o.view(l));
        let read = doc.attacker.read(&lum);
        Look {
            reads: read.correct,
            learned: learned.as_ref().is_some_and(|r| r.read(&lum).correct),
            margin: read.margin,
            legibility: reference.score("", &lum, luminance_of(o.white)).legibility,
        }
    };
    let n = setup.target_looks.max(1);
    // The person's looks under every kernel draw: how many read, and the worst.
    let draws = |person: &VisionProfile| -> Result<(u32, Look)> {
        let mut worst = Look {
            reads: true,
            learned: true,
            margin: f64::INFINITY,
            legibility: f64::INFINITY,
        };
        let mut read = 0;
        for j in 0..n {
            let s = look(&view(person, j)?);
            read += u32::from(s.reads);
            worst.reads &= s.reads;
            worst.margin = worst.margin.min(s.margin);
            worst.legibility = worst.legibility.min(s.legibility);
        }
        Ok((read, worst))
    };
    let pupil = |dp: f64| view(&target.with_pupil_changed(dp), 0).map(|o| look(&o));
    let people = sample_population(
        setup.population as usize,
        EvaluationOptions::default().seed,
        Default::default(),
    );
    let (mut by_font, mut by_legibility, mut refocusing) = (0, 0, [0, 0]);
    let range = Accommodation::default();
    for person in &people {
        // Own focus first (the range's first state), then every other focus until both judges have read.
        let mut any = [false, false];
        for a in range.states(person) {
            let s = look(&view(&Accommodation::accommodated(person, a), 0)?);
            let read = [s.reads || s.learned, s.legibility >= DEFAULT_THRESHOLD];
            if a == 0.0 {
                by_font += u32::from(read[0]);
                by_legibility += u32::from(read[1]);
            }
            any = [any[0] || read[0], any[1] || read[1]];
            if any == [true, true] {
                break;
            }
        }
        refocusing[0] += u32::from(any[0]);
        refocusing[1] += u32::from(any[1]);
    }
    Ok(Judged {
        n,
        at_focus: draws(target)?,
        near: draws(&target.refocused(-0.25))?,
        far: draws(&target.refocused(0.25))?,
        pupils: [pupil(-0.5)?, pupil(0.5)?],
        people: people.len() as u32,
        by_font,
        by_legibility,
        refocusing,
    })
}

/// Held-out target `k`: a person sampled with a seed no encoder or evaluation uses; with `wide_pupils`, viewing
/// through the `k`-th of pupils spread evenly over 3–7 mm.
fn held_out_target(k: usize, setup: &Setup) -> VisionProfile {
    let seed = 0xD0C5_0000 + k as u64;
    if setup.wide_pupils {
        let pupil = 3.0 + 4.0 * (k as f64 + 0.5) / f64::from(setup.targets.max(1));
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        sample_person_with_pupil(&mut rng, Default::default(), pupil)
    } else {
        sample_population(1, seed, Default::default()).remove(0)
    }
}

/// One display's figures over its targets.
#[derive(Default)]
struct Tally {
    pupils: Vec<f64>,
    seconds: Vec<f64>,
    margins: Vec<f64>,
    failed: u32,
    read_focus: u32,
    read_refocused: u32,
    read_all: u32,
    people: u32,
    by_font: u32,
    by_legibility: u32,
    refocusing: [u32; 2],
}

impl Tally {
    fn row(&self, display: &str, document: &str, options: &EncodeOptions) -> String {
        let n = self.pupils.len();
        let range = |v: &[f64]| {
            let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            (lo, hi)
        };
        let (plo, phi) = range(&self.pupils);
        let margins = match range(&self.margins) {
            _ if self.margins.is_empty() => "–".to_string(),
            (lo, hi) => format!("{lo:+.3} to {hi:+.3}"),
        };
        let mut seconds = self.seconds.clone();
        seconds.sort_by(f64::total_cmp);
        let median = seconds.get(seconds.len() / 2).copied().unwrap_or(0.0);
        let pct = |a: u32, b: u32| 100.0 * f64::from(a) / f64::from(b.max(1));
        let failed = if self.failed > 0 {
            format!(" ({} refused)", self.failed)
        } else {
            String::new()
        };
        format!(
            "| `{display}` | {document} | {} | {n} ({plo:.1}–{phi:.1} mm) | {} of {n}{failed} | {} of {n} | {} of {n} | {margins} | {} of {} ({:.1} %) | {} of {} ({:.1} %) | {} of {} ({:.1} %) | {} of {} ({:.1} %) | {median:.0} s ({:.0} s) |",
            match options.draws {
                1 => format!("{:?}", options.security).to_lowercase(),
                n => format!("{:?}, best of {n} draws", options.security).to_lowercase(),
            },
            self.read_focus,
            self.read_refocused,
            self.read_all,
            self.by_font,
            self.people,
            pct(self.by_font, self.people),
            self.by_legibility,
            self.people,
            pct(self.by_legibility, self.people),
            self.refocusing[0],
            self.people,
            pct(self.refocusing[0], self.people),
            self.refocusing[1],
            self.people,
            pct(self.refocusing[1], self.people),
            seconds.last().copied().unwrap_or(0.0),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wide_pupil_targets_span_three_to_seven_millimetres_and_are_known_over_seven_and_a_half() {
        let setup = Setup {
            targets: 20,
            population: 0,
            target_looks: 1,
            hint: true,
            wide_pupils: true,
            documents: Documents::PinSlips,
        };
        let pupils: Vec<f64> = (0..20).map(|k| held_out_target(k, &setup).pupil_diameter_mm).collect();
        assert!(
            (pupils[0] - 3.1).abs() < 1e-12 && (pupils[19] - 6.9).abs() < 1e-12,
            "{pupils:?}"
        );
        let t = held_out_target(0, &setup);
        assert_eq!(t.zernike_pupil_diameter_mm, Some(7.5));
        // Widened by 0.5 mm, the eye is still inside what was measured.
        assert!((t.with_pupil_changed(0.5).pupil_diameter_mm - 3.6).abs() < 1e-12);
    }

    #[test]
    fn each_document_is_read_right_by_its_own_attacker_from_the_page() {
        let page = (56, 56);
        for (documents, font) in [
            (Documents::PinSlips, None),
            (
                Documents::InFont {
                    font: "DejaVuSansMono.ttf".into(),
                    lines: true,
                },
                Some(DocFont::load("DejaVuSansMono.ttf").expect("tests/fonts/install.sh installs DejaVu")),
            ),
        ] {
            let doc = documents.draw(font.as_ref(), "48210937", page, page, true).unwrap();
            let read = doc.attacker.read(&eyekey_core::evaluation::image_luminance(&doc.image));
            assert!(read.correct, "{}: {read:?}", doc.text);
            assert_eq!(read.characters, if font.is_some() { 8 } else { 4 });
        }
    }
}
