//! Views for calibrating the legibility threshold against the known-font attacker and OCR
//! (`eyekey experiment calibrate`).
//!
//! Every view shows a random 4-digit PIN, in one of several fonts (eyekey's 5×7 and TrueType fonts from Debian's
//! packages, [`super::fonts::CALIBRATION_FONTS`]) and layouts ([`super::fonts::CALIBRATION_LAYOUTS`]: alone or under
//! a label, large or small), and the views span the range from plainly legible to unreadable:
//!
//! - `plain`: the PIN on an ordinary 2D display, seen by sampled people with an uncorrected defocus of up to
//!   ±2 D (blurred but often legible);
//! - `target`, `person`, `camera`: the PIN encoded by the multiplex encoder with 0, 2, 6 or 12 population
//!   decoys of weight 0.1, 0.3 or 1.0, seen by its target, by people sampled from the population statistics,
//!   and by an ideal camera-like eye (standard cones, 4 mm aperture) focused within ±1 D.
//!
//! Each view is scored with [`eyekey_core::evaluation::Reference::score`] (legibility and plain NCC), read by the
//! known-font attacker for its own font and layout ([`eyekey_core::evaluation::KnownFontAttacker`]) and written as the picture an attacker
//! would start from: luminance stretched to 0..255, upscaled ×4 (bilinear), 8-bit grey. `views.csv` lists
//! `file,text,legibility,ncc,known_font,characters_right,kind,font,layout`; `calibration.md` tabulates the
//! known-font attacker's reads against legibility, over all fonts and per font, and derives both bars
//! ([`known_font_table`]): the might-read threshold everybody but the target is held under and the reads
//! threshold the target must reach;
//! `benches/calibrate_ocr.sh` OCRs the same views.

use eyekey_core::physics::transport::TransportCache;
use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::{Context, Result};
use image::{GrayImage, Luma, RgbImage};
use rand::{Rng, SeedableRng};

use super::fonts::{draw_layout, DocFont, DrawnText};

use eyekey_core::encoding::pipeline::{encode, DecoyKind, EncodeOptions, JobSpec, OBJECTIVE_LEVEL};
use eyekey_core::evaluation::{luminance, stretch_to_unit, Reference, DEFAULT_THRESHOLD, READS_THRESHOLD};
use eyekey_core::physics::display::DisplayGeometry;
use eyekey_core::physics::observer::{plain_light_field_for_image, Observer, Optics};
use eyekey_core::physics::population::{sample_person, SamplingScope};
use eyekey_core::physics::profile::VisionProfile;
use eyekey_core::physics::transport::{EyePosition, TransportOptions};
use eyekey_core::physics::zernike::Prescription;

/// Upscaling factor of the written views.
pub const UPSCALE: u32 = 4;

/// How the calibration views are made.
#[derive(Clone, Debug)]
struct Setup {
    display: DisplayGeometry,
    /// The forward model of the encodings and the views.
    optics: Optics,
    /// Sub-rays of the encoder's operators.
    sub_rays: u32,
    /// Sub-rays of the viewers' operators (with their own jitter seed).
    view_sub_rays: u32,
    max_iterations: u32,
    /// Population decoys of the encodings (cycled together with `weights`).
    decoys: Vec<u32>,
    /// Decoy weights.
    weights: Vec<f64>,
    /// Sampled people looking at each encoding.
    people_per_encoding: usize,
    /// Camera-like views of each encoding.
    cameras_per_encoding: usize,
    /// Sampled people kept in the viewing pool (their operators are reused between encodings).
    pool: usize,
    /// The fonts the documents are drawn in ([`super::fonts::DocFont::load`] names), cycled with the layouts.
    fonts: Vec<String>,
}

impl Setup {
    fn standard() -> Self {
        Self {
            // 56×56 lenslets: a line of four 5×7 digits at two pixels per font dot (48 pixels) fits with a
            // margin. The lenslet optics resolve their views under diffraction (docs/design.md §2.7).
            display: DisplayGeometry {
                holes_x: 56,
                holes_y: 56,
                ..DisplayGeometry::lenslet()
            },
            optics: Optics::Wave,
            sub_rays: 8,
            view_sub_rays: 12,
            max_iterations: 100,
            decoys: vec![0, 2, 6, 12],
            weights: vec![0.1, 0.3, 1.0],
            people_per_encoding: 10,
            cameras_per_encoding: 2,
            pool: 30,
            fonts: super::fonts::CALIBRATION_FONTS.iter().map(|f| f.to_string()).collect(),
        }
    }
}

/// The document: one line of four digits, black on white, on the retinal grid (one pixel per hole) at
/// `scale` pixels per font dot.
pub fn pin_document(pin: &str, width: u32, height: u32, scale: u32) -> RgbImage {
    eyekey_core::imaging::glyphs::render_text(&[pin], width, height, scale)
}

/// One calibration document: the PIN, the document drawn in some font and layout with its attacker, and a tag
/// naming both.
struct Document {
    pin: String,
    drawn: DrawnText,
    font: String,
    layout: String,
}

/// Writes `count` views with known text, their legibility and the known-font attacker's readings into
/// `out_dir` (`view_<k>.png`, `views.csv`, `calibration.md`); returns the calibration table.
pub fn calibration_views(out_dir: &Path, count: usize, seed: u64) -> Result<String> {
    views_with(out_dir, count, seed, &Setup::standard())
}

struct View {
    text: String,
    legibility: f64,
    ncc: f64,
    /// The known-font attacker read every digit right.
    known_font: bool,
    /// Digits the known-font attacker got right.
    characters_right: u32,
    kind: String,
    font: String,
    layout: String,
    luminance: Vec<f32>,
}

/// The attacker's starting picture: luminance stretched to its own range, upscaled, 8-bit grey.
fn attacker_picture(lum: &[f32], width: u32, height: u32) -> GrayImage {
    let stretched = stretch_to_unit(lum);
    let small = GrayImage::from_fn(width, height, |x, y| {
        let v = stretched[(y * width + x) as usize];
        Luma([(v.clamp(0.0, 1.0) * 255.0).round() as u8])
    });
    image::imageops::resize(
        &small,
        width * UPSCALE,
        height * UPSCALE,
        image::imageops::FilterType::Triangle,
    )
}

fn random_pin<R: Rng>(rng: &mut R) -> String {
    format!("{:04}", rng.gen_range(0..10_000u32))
}

/// Writes the views as they come: `view_<k>.png` each, and the lines of `views.csv`.
struct ViewWriter<'a> {
    out_dir: &'a Path,
    /// Retinal grid of the views.
    width: u32,
    height: u32,
    /// Views written so far.
    written: usize,
    csv: String,
    /// Each view's (legibility, known-font read, digits right, kind's first word).
    rows: Vec<CalibrationRow>,
}

impl<'a> ViewWriter<'a> {
    fn new(out_dir: &'a Path, width: u32, height: u32) -> Self {
        Self {
            out_dir,
            width,
            height,
            written: 0,
            csv: String::from("file,text,legibility,ncc,known_font,characters_right,kind,font,layout\n"),
            rows: Vec::new(),
        }
    }

    /// Saves the view's attacker picture as the next `view_<k>.png` and adds its line to the table.
    fn push(&mut self, v: View) -> Result<()> {
        let file = format!("view_{}.png", self.written);
        attacker_picture(&v.luminance, self.width, self.height)
            .save(self.out_dir.join(&file))
            .with_context(|| format!("writing {file}"))?;
        writeln!(
            self.csv,
            "{file},{},{:.6},{:.6},{},{},{},{},{}",
            v.text, v.legibility, v.ncc, v.known_font, v.characters_right, v.kind, v.font, v.layout
        )?;
        self.rows.push(CalibrationRow {
            legibility: v.legibility,
            read: v.known_font,
            characters_right: v.characters_right,
            kind: v.kind.split(' ').next().unwrap_or("").to_string(),
            font: v.font,
        });
        self.written += 1;
        Ok(())
    }

    /// Writes `views.csv` and `calibration.md`; returns the calibration table.
    fn finish(self) -> Result<String> {
        std::fs::write(self.out_dir.join("views.csv"), self.csv).context("writing views.csv")?;
        let md = known_font_table(&self.rows)?;
        std::fs::write(self.out_dir.join("calibration.md"), &md).context("writing calibration.md")?;
        Ok(md)
    }
}

/// Scores what observer `o` sees of light field `l` against document `d`: legibility, NCC and the reading of the
/// known-font attacker for its font and layout (made for a retinal grid of one pixel per hole, as `o`'s is).
fn score(d: &Document, o: &Observer, l: &[f32], kind: String) -> Result<View> {
    let g = o.grid();
    let doc = &d.drawn.document;
    let reference = Reference::new(doc, g.width, g.height, OBJECTIVE_LEVEL, DEFAULT_THRESHOLD)
        .with_known_font(d.drawn.attacker.clone());
    let lum = luminance(&o.view(l));
    let white = eyekey_core::evaluation::luminance_of(o.white);
    let s = reference.score("", &lum, white);
    let read = s.known_font.expect("the reference has a known-font attacker");
    Ok(View {
        text: d.pin.clone(),
        legibility: s.legibility,
        ncc: s.ncc,
        known_font: read.correct,
        characters_right: read.characters_right,
        kind,
        font: d.font.clone(),
        layout: d.layout.clone(),
        luminance: lum,
    })
}

/// What every view of one calibration run shares.
struct Views<'a> {
    setup: &'a Setup,
    seed: u64,
    cache: TransportCache,
    /// The viewers' transport options: the evaluation's own sub-ray jitter, different from every encoder's.
    topts: TransportOptions,
    /// The fonts of the documents.
    fonts: Vec<DocFont>,
    /// Sampled people who look at the encodings.
    pool: Vec<VisionProfile>,
    /// (decoys, weight) combinations of the encodings, visited `stride` apart (a stride coprime to their
    /// number, so all are visited).
    combos: Vec<(u32, f64)>,
    stride: usize,
    cancel: AtomicBool,
    started: Instant,
}

impl<'a> Views<'a> {
    /// Prepares a run; draws the viewing pool from `rng`.
    fn new(setup: &'a Setup, seed: u64, rng: &mut impl Rng) -> Result<Self> {
        let started = Instant::now();
        let topts = TransportOptions {
            sub_rays: setup.view_sub_rays,
            seed: seed ^ 0xCA11_B8A7,
            ..Default::default()
        };
        let fonts = setup
            .fonts
            .iter()
            .map(|f| DocFont::load(f))
            .collect::<Result<Vec<_>>>()?;
        let pool = (0..setup.pool.max(1))
            .map(|_| sample_person(&mut *rng, SamplingScope::default()))
            .collect();
        let combos: Vec<(u32, f64)> = setup
            .decoys
            .iter()
            .flat_map(|&k| setup.weights.iter().map(move |&w| (k, w)))
            .collect();
        let stride = (combos.len() / 3 + 1..combos.len())
            .find(|s| gcd(*s, combos.len()) == 1)
            .unwrap_or(1);
        Ok(Self {
            setup,
            seed,
            cache: TransportCache::default(),
            topts,
            fonts,
            pool,
            combos,
            stride,
            cancel: AtomicBool::new(false),
            started,
        })
    }

    /// Document `k`: a random PIN in font `k` mod the fonts, in layout `k / fonts` mod the layouts, one pixel per
    /// hole.
    fn document(&self, k: usize, rng: &mut impl Rng) -> Result<Document> {
        let d = &self.setup.display;
        let font = &self.fonts[k % self.fonts.len()];
        let layouts = &super::fonts::CALIBRATION_LAYOUTS;
        let layout = &layouts[(k / self.fonts.len()) % layouts.len()];
        let pin = random_pin(rng);
        let drawn = draw_layout(font, layout, &pin, d.holes_x, d.holes_y, (d.holes_x, d.holes_y))?;
        Ok(Document {
            pin,
            drawn,
            font: font.name().to_string(),
            layout: layout.name(),
        })
    }

    /// A viewer's operator on the display.
    fn observer(&self, person: &VisionProfile) -> Result<Observer> {
        Ok(Observer::new(
            &self.setup.display,
            person,
            EyePosition::default(),
            &self.topts,
            self.setup.optics,
            &self.cache,
        )?)
    }

    /// View `k` of the plain display: a sampled person with an uncorrected defocus (more of them near focus).
    fn plain_view(&self, k: usize, rng: &mut impl Rng) -> Result<View> {
        let d = &self.setup.display;
        let doc = self.document(k, rng)?;
        let mut person = sample_person(&mut *rng, SamplingScope::default());
        let u: f64 = rng.gen_range(-1.0..=1.0);
        let defocus = 2.0 * u * u.abs();
        person.prescription = Some(Prescription {
            sphere_d: defocus,
            cylinder_d: 0.0,
            axis_deg: 0.0,
        });
        let o = self.observer(&person)?;
        let kind = format!("plain defocus={defocus:+.2}D pupil={:.1}mm", person.pupil_diameter_mm);
        score(&doc, &o, &plain_light_field_for_image(d, &doc.drawn.document), kind)
    }

    /// Encodes document `doc` for `target` with `decoys` noise decoys of `weight` (view set `e`).
    fn encode(&self, e: usize, doc: &RgbImage, target: &VisionProfile, decoys: u32, weight: f64) -> Result<Vec<f32>> {
        let spec = JobSpec {
            display: self.setup.display.clone(),
            target: target.clone(),
            target_label: "calibration".into(),
            observers: vec![],
            document: doc.clone(),
            decoy: None,
            options: EncodeOptions {
                population_decoys: decoys,
                near_pupil_decoys: 0,
                decoy: DecoyKind::Noise,
                decoy_weight: Some(weight),
                optics: self.setup.optics,
                seed: Some(self.seed.wrapping_mul(1000).wrapping_add(e as u64)),
                sub_rays: self.setup.sub_rays,
                max_iterations: self.setup.max_iterations,
                evaluation_population: 0,
                leak_weight: 0.0,
                ensure_target_reads: false,
                ..Default::default()
            },
        };
        let enc = encode(&spec, &self.cache, &|_| {}, &self.cancel)
            .map_err(|err| anyhow::anyhow!("encoding view set {e}: {err}"))?;
        Ok(enc.light_field)
    }

    /// The viewers of view set `e`, labelled: its target, camera-like eyes (the first in focus, the others
    /// focused at random within ±1 D), then people from the pool.
    fn viewers(
        &self,
        e: usize,
        target: &VisionProfile,
        tag: &str,
        rng: &mut impl Rng,
    ) -> Result<Vec<(String, Observer)>> {
        let mut batch: Vec<(String, Observer)> = vec![(format!("target {tag}"), self.observer(target)?)];
        for c in 0..self.setup.cameras_per_encoding {
            let focus = if c == 0 { 0.0 } else { rng.gen_range(-1.0..=1.0) };
            let camera = VisionProfile {
                pupil_diameter_mm: 4.0,
                prescription: Some(Prescription {
                    sphere_d: focus,
                    cylinder_d: 0.0,
                    axis_deg: 0.0,
                }),
                ..VisionProfile::perfect()
            };
            batch.push((format!("camera focus={focus:+.2}D {tag}"), self.observer(&camera)?));
        }
        let per = self.setup.people_per_encoding;
        for i in 0..per {
            let p = &self.pool[(e * per + i) % self.pool.len()];
            batch.push((format!("person {tag}"), self.observer(p)?));
        }
        Ok(batch)
    }

    /// View set `e`: a random PIN encoded for a sampled target with the set's (decoys, weight), written as seen
    /// by each of its viewers until `count` views exist.
    fn view_set(&self, e: usize, out: &mut ViewWriter, count: usize, rng: &mut impl Rng) -> Result<()> {
        let (decoys, weight) = self.combos[(e * self.stride) % self.combos.len()];
        let doc = self.document(e, rng)?;
        let scope = SamplingScope {
            pupil_spread: false,
            ..Default::default()
        };
        let target = sample_person(&mut *rng, scope);
        let t = Instant::now();
        let l = self.encode(e, &doc.drawn.document, &target, decoys, weight)?;
        let tag = format!(
            "decoys={decoys} weight={weight} font={} layout={}",
            doc.font, doc.layout
        );
        let mut legs = Vec::new();
        for (kind, o) in self.viewers(e, &target, &tag, rng)? {
            if out.written >= count {
                break;
            }
            let v = score(&doc, &o, &l, kind)?;
            legs.push(v.legibility);
            out.push(v)?;
        }
        eprintln!(
            "view set {e}: {tag}: target {:.2}, others {} ({:.1} s; {} views, {:.0} s total)",
            legs.first().copied().unwrap_or(0.0),
            legs.iter()
                .skip(1)
                .map(|v| format!("{v:.2}"))
                .collect::<Vec<_>>()
                .join(" "),
            t.elapsed().as_secs_f64(),
            out.written,
            self.started.elapsed().as_secs_f64()
        );
        Ok(())
    }
}

/// Writes `count` views with `setup`: a quarter plain (when `count` ≥ 2), the rest of encodings, view set
/// after view set.
fn views_with(out_dir: &Path, count: usize, seed: u64, setup: &Setup) -> Result<String> {
    std::fs::create_dir_all(out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let views = Views::new(setup, seed, &mut rng)?;
    let mut out = ViewWriter::new(out_dir, setup.display.holes_x, setup.display.holes_y);
    let n_plain = if count >= 2 { count / 4 } else { 0 };
    for k in 0..n_plain {
        out.push(views.plain_view(k, &mut rng)?)?;
    }
    let mut e = 0usize;
    while out.written < count {
        views.view_set(e, &mut out, count, &mut rng)?;
        e += 1;
    }
    out.finish()
}

/// One calibration view as the table sees it.
#[derive(Clone, Debug)]
struct CalibrationRow {
    legibility: f64,
    /// The known-font attacker read every digit.
    read: bool,
    characters_right: u32,
    /// `plain`, `target`, `person` or `camera`.
    kind: String,
    /// The document's font.
    font: String,
}

/// Maximum-likelihood logistic fit P(read) = 1/(1 + exp(−(a + b·legibility))) by Newton's method (the
/// log-likelihood is concave, so Newton converges from zero); `None` when the reads are separable or absent.
fn logistic_fit(rows: &[CalibrationRow]) -> Option<(f64, f64)> {
    let (mut a, mut b) = (0.0f64, 0.0f64);
    for _ in 0..100 {
        let (mut ga, mut gb, mut haa, mut hab, mut hbb) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for r in rows {
            let p = 1.0 / (1.0 + (-(a + b * r.legibility)).exp());
            let y = if r.read { 1.0 } else { 0.0 };
            let w = p * (1.0 - p);
            ga += y - p;
            gb += (y - p) * r.legibility;
            haa += w;
            hab += w * r.legibility;
            hbb += w * r.legibility * r.legibility;
        }
        let det = haa * hbb - hab * hab;
        if det.abs() < 1e-12 {
            return None;
        }
        let (da, db) = ((hbb * ga - hab * gb) / det, (haa * gb - hab * ga) / det);
        a += da;
        b += db;
        if !(a.is_finite() && b.is_finite()) || b.abs() > 1e3 {
            return None;
        }
        if da.abs() + db.abs() < 1e-10 {
            return Some((a, b));
        }
    }
    None
}

/// The calibration table: the known-font attacker's reads per legibility bin, the logistic fit, the error rates
/// of candidate thresholds and the threshold this calibration supports: the lowest legibility at which the
/// attacker read any view, rounded down to 0.01 (a secrecy judge errs towards *readable*).
fn known_font_table(rows: &[CalibrationRow]) -> Result<String> {
    let mut md = String::new();
    writeln!(
        md,
        "| legibility | views | read by the known-font attacker | success | mean digits right | views (read) by kind |"
    )?;
    writeln!(md, "| --- | --- | --- | --- | --- | --- |")?;
    for bin in 0..10 {
        let (lo, hi) = (bin as f64 / 10.0, (bin + 1) as f64 / 10.0);
        let in_bin: Vec<&CalibrationRow> = rows
            .iter()
            .filter(|r| r.legibility >= lo && (r.legibility < hi || (bin == 9 && r.legibility <= 1.0)))
            .collect();
        if in_bin.is_empty() {
            continue;
        }
        let read = in_bin.iter().filter(|r| r.read).count();
        let digits = in_bin.iter().map(|r| r.characters_right as f64).sum::<f64>() / in_bin.len() as f64;
        let mut kinds: std::collections::BTreeMap<&str, (usize, usize)> = Default::default();
        for r in &in_bin {
            let e = kinds.entry(r.kind.as_str()).or_default();
            e.0 += 1;
            e.1 += usize::from(r.read);
        }
        let kinds: Vec<String> = kinds.iter().map(|(k, (n, r))| format!("{k} {n} ({r})")).collect();
        writeln!(
            md,
            "| {lo:.1}–{hi:.1} | {} | {read} | {:.0} % | {digits:.1} | {} |",
            in_bin.len(),
            100.0 * read as f64 / in_bin.len() as f64,
            kinds.join(", ")
        )?;
    }
    let lowest = rows
        .iter()
        .filter(|r| r.read)
        .map(|r| r.legibility)
        .fold(f64::INFINITY, f64::min);
    let highest_missed = rows
        .iter()
        .filter(|r| !r.read)
        .map(|r| r.legibility)
        .fold(f64::NEG_INFINITY, f64::max);
    writeln!(md)?;
    if lowest.is_finite() {
        writeln!(
            md,
            "- Lowest legibility at which the known-font attacker read a view: **{lowest:.3}**."
        )?;
    } else {
        writeln!(md, "- The known-font attacker read no view.")?;
    }
    if highest_missed.is_finite() {
        writeln!(
            md,
            "- Highest legibility of a view it could not read: {highest_missed:.3}."
        )?;
    }
    if let Some((a, b)) = logistic_fit(rows) {
        let at = |p: f64| ((p / (1.0 - p)).ln() - a) / b;
        writeln!(
            md,
            "- Logistic fit P(read) = 1/(1+exp(−({a:.2} + {b:.2}·legibility))): 10 % at {:.3}, **50 % at {:.3}**, 90 % at {:.3}.",
            at(0.1),
            at(0.5),
            at(0.9)
        )?;
    }
    writeln!(md)?;
    writeln!(
        md,
        "| threshold | views below | of them read (false negatives) | views at or above | of them not read (false positives) |"
    )?;
    writeln!(md, "| --- | --- | --- | --- | --- |")?;
    let chosen = if lowest.is_finite() {
        (lowest * 100.0).floor() / 100.0
    } else {
        1.0
    };
    let mut candidates = vec![0.1, 0.2, 0.3, 0.38, 0.4, 0.5, 0.6, 0.7, chosen];
    candidates.sort_by(f64::total_cmp);
    candidates.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    for t in candidates {
        let below: Vec<&CalibrationRow> = rows.iter().filter(|r| r.legibility < t).collect();
        let above: Vec<&CalibrationRow> = rows.iter().filter(|r| r.legibility >= t).collect();
        let fneg = below.iter().filter(|r| r.read).count();
        let fpos = above.iter().filter(|r| !r.read).count();
        let pct = |k: usize, n: usize| if n == 0 { 0.0 } else { 100.0 * k as f64 / n as f64 };
        let label = if (t - chosen).abs() < 1e-9 {
            format!("{t:.2} (supported)")
        } else {
            format!("{t:.2}")
        };
        writeln!(
            md,
            "| {label} | {} | {fneg} ({:.1} %) | {} | {fpos} ({:.1} %) |",
            below.len(),
            pct(fneg, below.len()),
            above.len(),
            pct(fpos, above.len())
        )?;
    }
    writeln!(md)?;
    writeln!(
        md,
        "Threshold this calibration supports: **{chosen:.2}** (the lowest legibility at which the known-font attacker read a view, rounded down to 0.01); the evaluation's `DEFAULT_THRESHOLD` is {DEFAULT_THRESHOLD}."
    )?;
    reads_table(&mut md, rows, logistic_fit(rows))?;
    Ok(md)
}

/// Views (at or above `t`, read among them) of `rows`.
fn at_or_above(rows: &[&CalibrationRow], t: f64) -> (usize, usize) {
    let above: Vec<&&CalibrationRow> = rows.iter().filter(|r| r.legibility >= t).collect();
    (above.len(), above.iter().filter(|r| r.read).count())
}

/// Fewest views at or above a candidate reads bar, per font, for the font to count in choosing it.
const READS_MIN_VIEWS: usize = 10;

/// The reads bar the calibration supports: the lowest legibility t (in steps of 0.01) such that at least 99 % of
/// the views within 0.1 above it (all fonts together), of every font's views at or above it (fonts with
/// [`READS_MIN_VIEWS`] or more there) and of all views at or above it are read; 1.0 when nothing qualifies.
fn supported_reads_bar(rows: &[CalibrationRow]) -> f64 {
    let mut fonts: Vec<&str> = rows.iter().map(|r| r.font.as_str()).collect();
    fonts.sort_unstable();
    fonts.dedup();
    let all: Vec<&CalibrationRow> = rows.iter().collect();
    let most = |(n, read): (usize, usize)| read as f64 >= 0.99 * n as f64;
    let holds = |t: f64| {
        let band: Vec<&CalibrationRow> = rows
            .iter()
            .filter(|r| r.legibility >= t && r.legibility < t + 0.1)
            .collect();
        !band.is_empty()
            && most((band.len(), band.iter().filter(|r| r.read).count()))
            && most(at_or_above(&all, t))
            && fonts.iter().all(|f| {
                let of: Vec<&CalibrationRow> = rows.iter().filter(|r| r.font == *f).collect();
                let (n, read) = at_or_above(&of, t);
                n < READS_MIN_VIEWS || most((n, read))
            })
    };
    (0..=100).map(|k| k as f64 / 100.0).find(|&t| holds(t)).unwrap_or(1.0)
}

/// The target's side: per font, what the known-font attacker read, and the reads bar the views support.
fn reads_table(md: &mut String, rows: &[CalibrationRow], fit: Option<(f64, f64)>) -> Result<()> {
    let bar = supported_reads_bar(rows);
    writeln!(md)?;
    writeln!(
        md,
        "| font | views | read | lowest legibility read | highest not read | at or above {bar:.2}: read | at or above {READS_THRESHOLD:.2}: read |"
    )?;
    writeln!(md, "| --- | --- | --- | --- | --- | --- | --- |")?;
    let mut fonts: Vec<&str> = rows.iter().map(|r| r.font.as_str()).collect();
    fonts.sort_unstable();
    fonts.dedup();
    let mut line = |name: &str, of: Vec<&CalibrationRow>| -> Result<()> {
        let read = of.iter().filter(|r| r.read).count();
        let lowest = of
            .iter()
            .filter(|r| r.read)
            .map(|r| r.legibility)
            .fold(f64::INFINITY, f64::min);
        let missed = of
            .iter()
            .filter(|r| !r.read)
            .map(|r| r.legibility)
            .fold(f64::NEG_INFINITY, f64::max);
        let cell = |v: f64| if v.is_finite() { format!("{v:.3}") } else { "–".into() };
        let frac = |(n, k): (usize, usize)| format!("{k} of {n}");
        writeln!(
            md,
            "| {name} | {} | {read} | {} | {} | {} | {} |",
            of.len(),
            cell(lowest),
            cell(missed),
            frac(at_or_above(&of, bar)),
            frac(at_or_above(&of, READS_THRESHOLD))
        )?;
        Ok(())
    };
    for f in &fonts {
        line(f, rows.iter().filter(|r| r.font == *f).collect())?;
    }
    line("all", rows.iter().collect())?;
    writeln!(md)?;
    writeln!(
        md,
        "Reads bar this calibration supports: **{bar:.2}** (the lowest legibility from which the known-font attacker reads at least 99 % of every font's views, of all views and of those within 0.1 above it); the evaluation's `READS_THRESHOLD` is {READS_THRESHOLD}."
    )?;
    if let Some((a, b)) = fit {
        writeln!(
            md,
            "The logistic fit, one curve for every font and kind, puts 99 % at {:.3}: its tails are heavier than the views' (the 0.8–0.9 band is read at the rate printed above).",
            ((0.99f64 / 0.01).ln() - a) / b
        )?;
    }
    Ok(())
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_views_and_a_parseable_table() {
        let dir = tempfile::tempdir().unwrap();
        let setup = Setup {
            optics: Optics::Geometric,
            display: DisplayGeometry {
                aperture: Default::default(),
                holes_x: 28,
                holes_y: 28,
                views_u: 3,
                views_v: 3,
                ..DisplayGeometry::paper()
            },
            sub_rays: 2,
            view_sub_rays: 2,
            max_iterations: 5,
            decoys: vec![0, 2],
            weights: vec![0.3],
            people_per_encoding: 2,
            cameras_per_encoding: 1,
            pool: 2,
            fonts: vec!["5x7".into(), "DejaVuSans.ttf".into()],
        };
        let md = views_with(dir.path(), 6, 1, &setup).unwrap();
        assert!(md.contains("| legibility | views |"), "{md}");
        assert_eq!(md, std::fs::read_to_string(dir.path().join("calibration.md")).unwrap());
        let csv = std::fs::read_to_string(dir.path().join("views.csv")).unwrap();
        let mut lines = csv.lines();
        assert_eq!(
            lines.next(),
            Some("file,text,legibility,ncc,known_font,characters_right,kind,font,layout")
        );
        let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
        assert_eq!(rows.len(), 6);
        let mut kinds = std::collections::BTreeSet::new();
        for r in &rows {
            assert_eq!(r.len(), 9, "{r:?}");
            assert!(r[1].len() == 4 && r[1].chars().all(|c| c.is_ascii_digit()), "{r:?}");
            let leg: f64 = r[2].parse().unwrap();
            let ncc: f64 = r[3].parse().unwrap();
            assert!((0.0..=1.0).contains(&leg) && leg + 1e-9 >= ncc.abs(), "{r:?}");
            let read: bool = r[4].parse().unwrap();
            let right: u32 = r[5].parse().unwrap();
            assert!(right <= 4 && (right == 4) == read, "{r:?}");
            kinds.insert(r[6].split(' ').next().unwrap().to_string());
            let img = image::open(dir.path().join(r[0])).unwrap().to_luma8();
            assert_eq!(img.dimensions(), (28 * UPSCALE, 28 * UPSCALE));
        }
        assert!(kinds.contains("plain") && kinds.contains("target"), "{kinds:?}");
        // A sharp plain view of the document is legible.
        let doc = pin_document("4821", 24, 24, 1);
        let lum = eyekey_core::evaluation::image_luminance(&doc);
        assert!(eyekey_core::evaluation::legibility(&lum, &lum, 24, 24) > 0.99);
    }

    fn row(legibility: f64, read: bool) -> CalibrationRow {
        CalibrationRow {
            legibility,
            read,
            characters_right: if read { 4 } else { 1 },
            kind: "person".into(),
            font: "5x7".into(),
        }
    }

    #[test]
    fn logistic_fit_matches_the_saturated_model_by_hand() {
        // Two legibility levels with 1 of 4 and 3 of 4 read: the two-parameter fit reproduces both rates, so
        // a = logit(1/4) = −ln 3 and a + b = logit(3/4) = ln 3.
        let rows: Vec<CalibrationRow> = [(0.0, 1), (1.0, 3)]
            .iter()
            .flat_map(|&(x, k)| (0..4).map(move |i| row(x, i < k)))
            .collect();
        let (a, b) = logistic_fit(&rows).unwrap();
        assert!((a + 3f64.ln()).abs() < 1e-8, "{a}");
        assert!((b - 2.0 * 3f64.ln()).abs() < 1e-8, "{b}");
        // Perfectly separated reads have no finite maximum.
        assert!(logistic_fit(&[row(0.1, false), row(0.9, true)]).is_none());
    }

    #[test]
    fn the_supported_reads_bar_is_where_every_font_is_read_at_99_percent() {
        // Font a: ten views read at 0.80, one missed at 0.65; font b: ten read at 0.75, one missed at 0.72. At 0.72
        // font b is read in 10 of 11 views (and the band 0.72–0.82 in 20 of 21); from 0.73 every view is read.
        let mut rows: Vec<CalibrationRow> = Vec::new();
        for (font, read_at, missed_at) in [("a", 0.80, 0.65), ("b", 0.75, 0.72)] {
            rows.extend((0..10).map(|_| CalibrationRow {
                font: font.into(),
                ..row(read_at, true)
            }));
            rows.push(CalibrationRow {
                font: font.into(),
                ..row(missed_at, false)
            });
        }
        assert!((supported_reads_bar(&rows) - 0.73).abs() < 1e-12);
        // Two hundred more views of font a read at 0.60 and two missed there: the band from 0.60 is read at 99 %
        // and font a at 0.60 too, but font b's miss at 0.72 still holds the bar above it.
        rows.extend((0..200).map(|_| CalibrationRow {
            font: "a".into(),
            ..row(0.60, true)
        }));
        rows.extend((0..2).map(|_| CalibrationRow {
            font: "a".into(),
            ..row(0.60, false)
        }));
        assert!((supported_reads_bar(&rows) - 0.73).abs() < 1e-12);
        // No view read: no bar.
        assert_eq!(supported_reads_bar(&[row(0.9, false)]), 1.0);
    }

    #[test]
    fn the_supported_threshold_is_the_lowest_legibility_read() {
        let rows = vec![row(0.1, false), row(0.27, true), row(0.5, false), row(0.8, true)];
        let md = known_font_table(&rows).unwrap();
        assert!(md.contains("supports: **0.27**"), "{md}");
        assert!(
            md.contains("| 0.27 (supported) | 1 | 0 (0.0 %) | 3 | 1 (33.3 %) |"),
            "{md}"
        );
        assert!(md.contains("| 0.30 | 2 | 1 (50.0 %) | 2 | 1 (50.0 %) |"), "{md}");
    }
}
