#!/usr/bin/env python3
"""OCR calibration of eyekey's legibility threshold.

Reads the views written by `eyekey experiment calibrate` (view_<k>.png, views.csv), OCRs every view the way an
attacker would (enhancement variants, tesseract with a digits whitelist, a view counts as read when ANY variant
gives exactly the true PIN), bins the views by legibility, fits the threshold and writes the calibration table.
"""

import argparse
import csv
import math
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from PIL import Image, ImageFilter, ImageOps

UPSCALE = 4  # the views are written at 4× the retinal grid
CROP = 2  # retinal-grid pixels cropped at each edge (the display's dark frame); the documents keep a margin
TESS_ARGS = ["--psm", "7", "-c", "tessedit_char_whitelist=0123456789"]


def otsu(a):
    """Otsu's threshold of a uint8 array."""
    hist = np.bincount(a.ravel(), minlength=256).astype(np.float64)
    p = hist / hist.sum()
    omega = np.cumsum(p)
    mu = np.cumsum(p * np.arange(256))
    mu_t = mu[-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma_b = (mu_t * omega - mu) ** 2 / (omega * (1.0 - omega))
    sigma_b = np.nan_to_num(sigma_b)
    return int(np.argmax(sigma_b))


def stretch(a, cut=1.0):
    """Autocontrast of a float array to 0..255 with `cut` % clipped at each end."""
    lo, hi = np.percentile(a, [cut, 100.0 - cut])
    if hi - lo < 1e-9:
        lo, hi = a.min(), a.max() + 1e-9
    return np.clip((a - lo) / (hi - lo) * 255.0, 0, 255).astype(np.uint8)


def gauss(img, sigma_px):
    return img.filter(ImageFilter.GaussianBlur(sigma_px)) if sigma_px > 0 else img


def flat_field(a, img, size):
    """Background normalisation: divide by the local background (grey closing of `size` px, then blurred)."""
    bg = np.asarray(img.filter(ImageFilter.MaxFilter(size)).filter(ImageFilter.GaussianBlur(size)), dtype=np.float64)
    return a / (bg + 1.0)


def enhancements(img):
    """(name, image) pairs at the written resolution (4× the retinal grid): what an attacker tries."""
    out = []
    a = np.asarray(img, dtype=np.float64)
    out.append(("autocontrast", Image.fromarray(stretch(a))))
    med = img.filter(ImageFilter.MedianFilter(3 * UPSCALE - 1))
    out.append(("median3", Image.fromarray(stretch(np.asarray(med, dtype=np.float64)))))
    for s in (0.7, 1.0, 1.5):  # σ in retinal-grid pixels (the legibility score uses 0.7 and 1.5)
        g = gauss(img, s * UPSCALE)
        b = np.asarray(g, dtype=np.float64)
        out.append((f"gauss{s}", Image.fromarray(stretch(b))))
        sb = stretch(b)
        out.append((f"gauss{s}_otsu", Image.fromarray(np.where(sb > otsu(sb), 255, 0).astype(np.uint8))))
        # Flat-field: removes the darkening towards the display's edges and slow shading.
        out.append((f"gauss{s}_flat", Image.fromarray(stretch(flat_field(b, g, 4 * UPSCALE + 1)))))
    # Background removal: subtract the large-scale structure (σ = 6 grid px), then light denoising.
    hp = np.asarray(gauss(img, 0.7 * UPSCALE), dtype=np.float64) - np.asarray(gauss(img, 6 * UPSCALE), dtype=np.float64)
    out.append(("highpass", Image.fromarray(stretch(hp))))
    return out


def variants(img):
    """Every enhancement in both polarities at several sizes, frame edge cropped, padded with a white border."""
    c = CROP * UPSCALE
    img = img.crop((c, c, img.width - c, img.height - c))
    res = []
    for name, e in enhancements(img):
        for pol, p in (("pos", e), ("neg", ImageOps.invert(e))):
            for f in (2, 3, 4, 6, 8):  # final pixels per retinal-grid pixel
                w, h = p.width * f // UPSCALE, p.height * f // UPSCALE
                r = p if f == UPSCALE else p.resize((w, h), Image.LANCZOS if f < UPSCALE else Image.BICUBIC)
                res.append((f"{name}/{pol}/x{f}", ImageOps.expand(r, 10 * f, fill=255)))
    return res


def tesseract(paths):
    """Texts tesseract reads in each image (whitespace removed); one process for the whole list, falling back
    to one process per image when it crashes (it can die on degenerate images)."""
    env = dict(os.environ, OMP_THREAD_LIMIT="1")
    lst = os.path.join(os.path.dirname(paths[0]), "list.txt")
    with open(lst, "w") as f:
        f.write("\n".join(paths) + "\n")
    r = subprocess.run(["tesseract", lst, "stdout"] + TESS_ARGS, capture_output=True, text=True, env=env)
    if r.returncode == 0:
        pages = ["".join(p.split()) for p in r.stdout.split("\f")][: len(paths)]
        return pages + [""] * (len(paths) - len(pages))
    if len(paths) == 1:
        return [""]
    return [tesseract([p])[0] for p in paths]


def ocr_view(job):
    """OCRs one view; returns (index, read, hits, best_digits, first_hit_variant, variants tried)."""
    index, path, text = job
    img = Image.open(path).convert("L")
    vs = variants(img)
    pages = [""] * len(vs)
    with tempfile.TemporaryDirectory() as tmp:
        names, keep = [], []
        for k, (_, v) in enumerate(vs):
            lo, hi = v.getextrema()
            if hi - lo < 8:  # blank: nothing to read
                continue
            n = os.path.join(tmp, f"{k}.png")
            v.save(n)
            names.append(n)
            keep.append(k)
        if names:
            for k, p in zip(keep, tesseract(names)):
                pages[k] = p
    hits = [vs[k][0] for k, p in enumerate(pages) if p == text]
    best_digits = max(sum(a == b for a, b in zip(p, text)) if len(p) == len(text) else 0 for p in pages)
    return index, bool(hits), len(hits), best_digits, hits[0] if hits else "", len(vs)


OBSERVATIONS = """## What this calibration does and does not say

- **OCR is a weaker reader than a person.** Tesseract reads sharp views (legibility ≥ 0.9) every time, but noise
  defeats it long before it defeats a person: looking at the views, the digits of many views with legibility
  0.25–0.45 that OCR could not read (decoy-masked views seen by sampled people, and moderately defocused plain
  views) are recognisable by eye, a few down to about 0.2. Stronger denoising (Gaussian σ up to 3 grid pixels,
  flat-fielding, binarisation) did not let tesseract read any of them. The threshold is therefore a calibrated
  lower bound on what an automated attacker reads, not a bound on what a person can read: a claim that a
  population "cannot read" should also be reported at a stricter threshold (0.2 is a reasonable human bound
  from these views), and an attacker who knows the font and matches digit templates would do better than OCR.
- **NCC ranks views well but depends on the document.** OCR success is near zero below 0.5 and rises steeply
  above it, and no view below the threshold was read. But the same legibility means different readability for
  different layouts: at equal legibility OCR reads 2 px/dot digits far more often than 1 px/dot digits (table
  above), and by eye the small digits stay recognisable at lower legibility than OCR manages. The threshold holds
  for short lines of digits like these PIN slips; other documents (paragraphs of text, images) need their own
  calibration.
- **What NCC cannot see.** A view whose digits are legible but shifted, scaled or distorted relative to the
  document scores low; none of the simulated viewers here shifts the image (tilt is removed, the eye sits at the
  design position), so this did not arise, but a viewer displaced from the design eye position could produce it.
"""


def logistic_fit(x, y, iters=100):
    """Maximum-likelihood logistic regression P(read) = 1/(1+exp(-(a + b·x))) by Newton's method."""
    X = np.stack([np.ones_like(x), x], axis=1)
    w = np.zeros(2)
    for _ in range(iters):
        p = 1.0 / (1.0 + np.exp(-(X @ w)))
        g = X.T @ (y - p)
        H = X.T @ (X * (p * (1 - p))[:, None]) + 1e-9 * np.eye(2)
        step = np.linalg.solve(H, g)
        w += step
        if np.abs(step).max() < 1e-10:
            break
    return w


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("views", help="directory with views.csv and view_<k>.png")
    ap.add_argument("--out", default="docs/legibility-ocr.md")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 2)
    ap.add_argument("--command", default="bash benches/calibrate_ocr.sh")
    ap.add_argument("--generate-seconds", type=float, default=float("nan"))
    ap.add_argument("--reuse", action="store_true", help="re-analyse the OCR results stored in VIEWS/ocr.csv")
    ap.add_argument("--ocr-seconds", type=float, default=float("nan"), help="with --reuse: OCR time to report")
    args = ap.parse_args()

    with open(os.path.join(args.views, "views.csv")) as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        r["legibility"] = float(r["legibility"])
        r["ncc"] = float(r["ncc"])
        r["class"] = r["kind"].split(" ")[0]
    t0 = time.time()
    n_variants = len(variants(Image.open(os.path.join(args.views, rows[0]["file"])).convert("L")))
    if args.reuse:
        with open(os.path.join(args.views, "ocr.csv")) as f:
            done = {r["file"]: r for r in csv.DictReader(f)}
        for r in rows:
            d = done[r["file"]]
            r.update(read=d["read"] == "1", hits=int(d["hits"]), digits=int(d["best_digits"]), first=d["first_variant"])
        ocr_seconds = args.ocr_seconds
    else:
        jobs = [(k, os.path.join(args.views, r["file"]), r["text"]) for k, r in enumerate(rows)]
        with ProcessPoolExecutor(max_workers=args.jobs) as ex:
            for k, read, hits, digits, first, _ in ex.map(ocr_view, jobs, chunksize=4):
                rows[k].update(read=read, hits=hits, digits=digits, first=first)
                if (k + 1) % 50 == 0:
                    print(f"OCR: {k + 1}/{len(jobs)} views, {time.time() - t0:.0f} s", flush=True)
        ocr_seconds = time.time() - t0
    with open(os.path.join(args.views, "ocr.csv"), "w", newline="") as f:
        wr = csv.writer(f)
        wr.writerow(["file", "text", "legibility", "ncc", "kind", "read", "hits", "best_digits", "first_variant"])
        for r in rows:
            wr.writerow([r["file"], r["text"], f"{r['legibility']:.4f}", f"{r['ncc']:.4f}", r["kind"], int(r["read"]), r["hits"], r["digits"], r["first"]])
    version = subprocess.run(["tesseract", "--version"], capture_output=True, text=True).stdout.splitlines()[0]

    leg = np.array([r["legibility"] for r in rows])
    read = np.array([1.0 if r["read"] else 0.0 for r in rows])
    n = len(rows)

    # Per-bin table (0.1 wide).
    bins = []
    for b in range(10):
        lo, hi = b / 10, (b + 1) / 10
        sel = [r for r in rows if lo <= r["legibility"] < hi or (b == 9 and r["legibility"] >= 1.0)]
        k = sum(r["read"] for r in sel)
        kinds = {}
        for r in sel:
            kinds.setdefault(r["class"], [0, 0])
            kinds[r["class"]][0] += 1
            kinds[r["class"]][1] += r["read"]
        bins.append((lo, hi, len(sel), k, kinds, np.mean([r["digits"] for r in sel]) if sel else float("nan")))

    # Threshold candidates.
    ever = min((r["legibility"] for r in rows if r["read"]), default=float("nan"))
    nonempty = [(lo, len_, k) for lo, _, len_, k, _, _ in bins if len_ > 0]
    bin50 = float("nan")
    for i, (lo, _, _) in enumerate(nonempty):
        if all(k / m >= 0.5 for _, m, k in nonempty[i:]):
            bin50 = lo
            break
    a, b = logistic_fit(leg, read)
    logit = lambda p: (math.log(p / (1 - p)) - a) / b if b > 0 else float("nan")
    p50, p10, p90 = logit(0.5), logit(0.1), logit(0.9)

    def rates(t):
        below = leg < t
        fn = int(((read == 1) & below).sum())
        fp = int(((read == 0) & ~below).sum())
        return fn, int(below.sum()), fp, int((~below).sum())

    # The chosen threshold: the lowest legibility at which the OCR attacker read any view, rounded down to 0.01.
    # A secrecy judge must not call readable views unreadable, so it sits at the bottom of OCR's range, not at
    # its 50 % point.
    chosen = math.floor(ever * 100) / 100
    fn, nb, fp, na = rates(chosen)

    # Markdown.
    L = []
    w = L.append
    w("# Legibility threshold calibrated against OCR\n")
    w("`eyekey evaluate` and the experiments call a view *readable* when its legibility score "
      "(`evaluate::legibility`: the best |NCC| between the view's luminance and the document's luminance after "
      "Gaussian denoising with σ ∈ {0, 0.7, 1.5} px) reaches `evaluate::DEFAULT_THRESHOLD`. "
      "This page ties that number to what an OCR attacker actually reads.\n")
    w("## How\n")
    w(f"- `{args.command}` builds the release binary, runs `eyekey experiment calibrate` "
      f"(source: `src/calibration.rs`), then `benches/calibrate_ocr.py` on its output.")
    w("- Views: a random 4-digit PIN (the 5×7 bitmap font, one line, at 2 px per font dot so that the digits fill "
      "the width but for a 4 px margin, or at 1 px per dot like the experiments' PIN slips) on a 56×56-hole "
      "display with the `secure` preset's optics (9×9 views, 0.3 mm pitch, 500 mm); the retinal grid has one "
      "pixel per hole. Kinds: `plain` — the PIN on an ordinary 2D display "
      "seen by sampled people with an uncorrected defocus of up to ±2 D; `target`, `person`, `camera` — the PIN "
      "encoded by the multiplex encoder (0, 2, 6 or 12 population decoys showing noise masks, decoy weight 0.1, "
      "0.3 or 1.0, 100 solver iterations, 8 sub-rays) seen (12 sub-rays) by its target, by people sampled from the population "
      "statistics, and by an ideal eye with standard cones and a 4 mm aperture focused within ±1 D. Every view "
      "uses a sub-ray jitter seed different from the encoder's.")
    w("- Each view is scored by `Reference::score` and written as an attacker's starting picture: luminance "
      "stretched to 0..255, upscaled ×4 (bilinear).")
    w(f"- OCR: {version} (Debian package `tesseract-ocr`), `--psm 7 -c tessedit_char_whitelist=0123456789`, on "
      f"{n_variants} variants per view: the frame's outer {CROP} grid pixels cropped, then 12 enhancements "
      "(autocontrast; 3×3 median; Gaussian denoising σ = 0.7, 1.0 and 1.5 grid px, each alone, Otsu-binarised and "
      "flat-fielded by dividing by the local background; background removal by subtracting a σ = 6 px blur), each "
      "in both polarities, at 2, 3, 4, 6 and 8 output pixels per grid pixel, with a white border. A view counts as **read** "
      "when ANY variant returns exactly the true 4 digits: the attacker's best case.")
    w(f"- {n} views; generating them took {args.generate_seconds:.0f} s and OCR {ocr_seconds:.0f} s "
      f"({args.jobs} workers) on a 2-core machine shared with other builds.\n")
    w("## Results\n")
    w("| legibility | views | read by OCR | OCR success | mean digits right (best variant) | views (read) by kind |")
    w("| --- | --- | --- | --- | --- | --- |")
    for lo, hi, m, k, kinds, dig in bins:
        kinds_s = ", ".join(f"{c} {v[0]} ({v[1]})" for c, v in sorted(kinds.items()))
        rate = f"{100 * k / m:.0f} %" if m else "–"
        dig_s = f"{dig:.1f}" if m else "–"
        w(f"| {lo:.1f}–{hi:.1f} | {m} | {k} | {rate} | {dig_s} | {kinds_s} |")
    w("")
    w(f"- Lowest legibility at which OCR read a view: **{ever:.3f}**.")
    w(f"- Lowest bin edge above which every bin has OCR success ≥ 50 %: **{bin50:.1f}**.")
    w(f"- Logistic fit P(read) = 1/(1+exp(−({a:.2f} + {b:.2f}·legibility))): 10 % at {p10:.3f}, "
      f"**50 % at {p50:.3f}**, 90 % at {p90:.3f}.\n")
    w("Error rates of candidate thresholds (a false negative is a view judged unreadable that OCR read; a false "
      "positive, one judged readable that OCR could not read):\n")
    w("| threshold | views below | of them read by OCR (false negatives) | views at or above | of them not read (false positives) |")
    w("| --- | --- | --- | --- | --- |")
    cands = sorted({round(x, 2) for x in (0.2, 0.3, 0.4, 0.5, 0.6, 0.7, chosen, bin50, p10, p50) if not math.isnan(x)})
    for t in cands:
        f1, n1, f2, n2 = rates(t)
        mark = " (chosen)" if abs(t - chosen) < 1e-9 else ""
        w(f"| {t:.2f}{mark} | {n1} | {f1} ({100 * f1 / max(n1, 1):.1f} %) | {n2} | {f2} ({100 * f2 / max(n2, 1):.1f} %) |")
    w("")
    w("## Threshold\n")
    w(f"`DEFAULT_THRESHOLD` = **{chosen:.2f}**: the lowest legibility at which the OCR attacker read any view, "
      "rounded down to 0.01. A secrecy judge has to err towards *readable*: a threshold at OCR's 50 % point "
      f"({p50:.2f}) would call views unreadable that OCR reads up to half the time. "
      f"Below it, OCR read {fn} of {nb} views ({100 * fn / max(nb, 1):.1f} %); at or above it, OCR failed on "
      f"{fp} of {na} ({100 * fp / max(na, 1):.1f} %).\n")
    per_kind = {}
    for r in rows:
        per_kind.setdefault(r["class"], []).append(r)
    w("By kind:\n")
    w("| kind | views | read by OCR | legibility range | read below the threshold |")
    w("| --- | --- | --- | --- | --- |")
    for c, rs in sorted(per_kind.items()):
        ls = [r["legibility"] for r in rs]
        below = sum(1 for r in rs if r["read"] and r["legibility"] < chosen)
        w(f"| {c} | {len(rs)} | {sum(r['read'] for r in rs)} | {min(ls):.2f}–{max(ls):.2f} | {below} |")
    w("")
    w("By text size (pixels per font dot on the retinal grid), OCR success per legibility bin:\n")
    sizes = sorted({r["kind"].split("scale=")[-1] for r in rows})
    w("| legibility | " + " | ".join(f"{z} px/dot: read / views" for z in sizes) + " |")
    w("| --- |" + " --- |" * len(sizes))
    for lo in range(10):
        cells = []
        for z in sizes:
            sel = [r for r in rows if r["kind"].split("scale=")[-1] == z and lo / 10 <= r["legibility"] < (lo + 1) / 10 + (lo == 9)]
            cells.append(f"{sum(r['read'] for r in sel)} / {len(sel)}")
        w(f"| {lo / 10:.1f}–{(lo + 1) / 10:.1f} | " + " | ".join(cells) + " |")
    w("")
    w(OBSERVATIONS)
    md = "\n".join(L) + "\n"
    if os.path.dirname(args.out):
        os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as f:
        f.write(md)
    print(f"{n} views, {int(read.sum())} read by OCR ({version}); OCR {ocr_seconds:.0f} s")
    for lo, hi, m, k, _, _ in bins:
        if m:
            print(f"  legibility {lo:.1f}-{hi:.1f}: {k:>4}/{m:<4} read ({100 * k / m:5.1f} %)")
    print(f"lowest legibility read: {ever:.3f}; bin rule (all bins above >= 50 %): {bin50:.1f}")
    print(f"logistic: 10 % at {p10:.3f}, 50 % at {p50:.3f}, 90 % at {p90:.3f}")
    print(f"chosen threshold {chosen:.2f}: false negatives {fn}/{nb} ({100 * fn / max(nb, 1):.1f} %), "
          f"false positives {fp}/{na} ({100 * fp / max(na, 1):.1f} %)")
    print(f"wrote {args.out} and {os.path.join(args.views, 'ocr.csv')}")


if __name__ == "__main__":
    sys.exit(main())
