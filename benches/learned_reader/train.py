"""Learned readers against eyekey's frames (docs/experiments.md §0b).

Reads the views `eyekey experiment reader-views` wrote (views.json, views.f32), splits the encodings into
training and test sets (the test set: the last --test encodings; nothing of a test encoding, neither its seed
nor its target nor its people, is trained on), and for each condition trains per character cell:

- a multinomial logistic regression (its L2 strength chosen on a validation fifth of the training encodings);
- a small neural network (one hidden layer of 128 ReLU units, early stopping).

Each cell's crop is normalised to zero mean and unit variance first (contrast and polarity of a view vary; the
network can learn either polarity, the linear model only the one it sees most). On the test encodings it reports
per-digit accuracy, whole PINs read, the PIN within the reader's ten most probable guesses, and the matched filter's
whole-PIN reads on the same views, with 95 % intervals from a bootstrap over test encodings (a cluster bootstrap:
one encoding's people share its frames). A learning curve repeats the seat's training on fewer encodings.

Prints a Markdown table.
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from sklearn.linear_model import LogisticRegression
from sklearn.neural_network import MLPClassifier


def load(views: Path):
    manifest = json.loads((views / "views.json").read_text())
    x = np.fromfile(views / "views.f32", dtype="<f4").reshape(len(manifest["records"]), manifest["features"])
    return manifest, x


def cells(manifest, x):
    """Per cell: the records' crops, each normalised to zero mean and unit variance."""
    out, at = [], 0
    for _, _, w, h in manifest["cells"]:
        c = x[:, at : at + w * h].astype(np.float64)
        c = c - c.mean(axis=1, keepdims=True)
        c = c / np.maximum(c.std(axis=1, keepdims=True), 1e-9)
        out.append(c)
        at += w * h
    return out


def logistic(xs, ys, seed):
    """Multinomial logistic regression, C picked on the last fifth of the training rows (grouped by encoding)."""
    n = len(ys)
    cut = int(0.8 * n)
    best, best_acc = 1.0, -1.0
    for c in (0.001, 0.01, 0.1, 1.0):
        m = LogisticRegression(C=c, max_iter=3000, random_state=seed).fit(xs[:cut], ys[:cut])
        acc = m.score(xs[cut:], ys[cut:])
        if acc > best_acc:
            best, best_acc = c, acc
    return LogisticRegression(C=best, max_iter=3000, random_state=seed).fit(xs, ys)


def mlp(xs, ys, seed):
    return MLPClassifier(
        hidden_layer_sizes=(128,),
        alpha=1e-3,
        early_stopping=True,
        validation_fraction=0.2,
        max_iter=400,
        random_state=seed,
    ).fit(xs, ys)


def probabilities(model, xs):
    """Probabilities over the ten digits (a digit never seen in training gets 0)."""
    p = np.zeros((xs.shape[0], 10))
    p[:, model.classes_.astype(int)] = model.predict_proba(xs)
    return p


def ranks(probs, truth):
    """For each record: how many PINs are more probable than the true one (0: read), cells independent."""
    logp = [np.log(np.maximum(p, 1e-300)) for p in probs]
    out = np.empty(len(truth), dtype=np.int64)
    for r in range(len(truth)):
        joint = logp[0][r][:, None, None, None]
        joint = joint + logp[1][r][None, :, None, None] + logp[2][r][None, None, :, None] + logp[3][r][None, None, None, :]
        true = sum(logp[k][r][truth[r][k]] for k in range(4))
        out[r] = int((joint > true).sum())
    return out


def interval(hit, groups, rng, n=1000):
    """95 % cluster-bootstrap interval of the mean of `hit` over the groups (test encodings)."""
    keys = np.unique(groups)
    per = {k: hit[groups == k] for k in keys}
    means = []
    for _ in range(n):
        pick = rng.choice(keys, size=len(keys), replace=True)
        h = np.concatenate([per[k] for k in pick])
        means.append(h.mean())
    return np.percentile(means, 2.5), np.percentile(means, 97.5)


def pct(v):
    return f"{100 * v:.1f} %"


def export(args, manifest, crops, enc, cond, truth):
    """The shipped linear reader: per cell, softmax(W·x + b) over the ten digits, x the cell's crop normalised to
    zero mean and unit variance, fitted on every encoding's seat views."""
    rows = np.isin(cond, ["seat", "seat_refocused"])
    models = []
    for k in range(len(manifest["cells"])):
        fit = logistic(crops[k][rows], truth[rows, k], args.seed)
        weights = np.zeros((10, crops[k].shape[1]))
        bias = np.full(10, -1e3)
        weights[fit.classes_.astype(int)] = fit.coef_
        bias[fit.classes_.astype(int)] = fit.intercept_
        models.append({"c": fit.C, "weights": weights.round(6).tolist(), "bias": bias.round(6).tolist()})
    out = {
        "preset": manifest["preset"],
        "grid": manifest["grid"],
        "cells": manifest["cells"],
        "made": (
            f"benches/learned_reader/train.py --export on `eyekey experiment reader-views` output: "
            f"{len(np.unique(enc[rows]))} encodings ({manifest['options']}), {int(rows.sum())} views of fresh "
            f"people at the seat, at their own focus and refocused to the target's spherical equivalent"
        ),
        "models": models,
    }
    args.export.write_text(json.dumps(out) + "\n")
    print(f"wrote {args.export}: {out['made']}\n", file=sys.stderr)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("views", type=Path, nargs="+", help="directories written by `eyekey experiment reader-views`")
    ap.add_argument("--test", type=int, default=40, help="test encodings (the last ones)")
    ap.add_argument("--curve", type=int, nargs="*", default=[30, 60], help="smaller training sets for the curve")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--export",
        type=Path,
        help="also fit the linear reader on every encoding's seat views (own focus and refocused) and write its "
        "weights here as JSON, for the evaluation (data/readers/)",
    )
    args = ap.parse_args()

    manifests, xs = zip(*(load(v) for v in args.views))
    manifest = dict(manifests[0])
    manifest["records"] = [r for m in manifests for r in m["records"]]
    x = np.concatenate(xs)
    crops = cells(manifest, x)
    rec = manifest["records"]
    enc = np.array([r["encoding"] for r in rec])
    cond = np.array([r["condition"] for r in rec])
    truth = np.array([[int(c) for c in r["truth"]] for r in rec])
    mf = np.array([r["matched_filter_correct"] for r in rec])
    encodings = np.unique(enc)
    test_set = set(encodings[-args.test :].tolist())
    train_all = [e for e in encodings if e not in test_set]
    is_test = np.array([e in test_set for e in enc])
    rng = np.random.default_rng(args.seed)
    print(
        f"`{manifest['preset']}`, {manifest['options']}: {len(train_all)} training and {len(test_set)} test encodings, "
        f"{len(rec)} views, {manifest['features']} floats each.\n"
    )
    print(
        "| condition | reader | training encodings (views) | digits right | whole PINs read (95 %) | "
        "within ten guesses | matched filter on the same views |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- |")

    def run(condition, trained_on, n_train, kind):
        train_enc = set(train_all[:n_train])
        tr = np.array([e in train_enc for e in enc]) & np.isin(cond, trained_on)
        te = is_test & np.isin(cond, condition)
        if tr.sum() == 0 or te.sum() == 0:
            return
        probs = []
        for k in range(4):
            fit = (logistic if kind == "logistic" else mlp)(crops[k][tr], truth[tr, k], args.seed)
            probs.append(probabilities(fit, crops[k][te]))
        pred = np.stack([p.argmax(axis=1) for p in probs], axis=1)
        digits = (pred == truth[te]).mean()
        rk = ranks(probs, truth[te])
        whole = (rk == 0).astype(float)
        lo, hi = interval(whole, enc[te], rng)
        mf_lo, mf_hi = interval(mf[te].astype(float), enc[te], rng)
        source = "" if list(trained_on) == list(condition) else f" (trained on {', '.join(trained_on)})"
        print(
            f"| {', '.join(condition)} | {kind}{source} | {n_train} ({int(tr.sum())}) | {pct(digits)} | "
            f"{pct(whole.mean())} ({pct(lo)}–{pct(hi)}) | {pct((rk < 10).mean())} | "
            f"{pct(mf[te].mean())} ({pct(mf_lo)}–{pct(mf_hi)}) |"
        )
        sys.stdout.flush()

    if args.export:
        export(args, manifest, crops, enc, cond, truth)

    n = len(train_all)
    cameras = sorted({c for c in cond if c.startswith("camera")})
    for kind in ("logistic", "mlp"):
        for condition in (["seat"], ["seat_refocused"], ["beside"], cameras, ["target"]):
            run(condition, condition, n, kind)
        run(["seat_refocused"], ["seat"], n, kind)
        run(["target"], ["seat"], n, kind)
        for m in args.curve:
            if m < n:
                run(["seat"], ["seat"], m, kind)


if __name__ == "__main__":
    main()
