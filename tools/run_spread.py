#!/usr/bin/python3
"""A study's error without the reference's noise: the spread between its independent runs (docs/studies/mlt.md).

    tools/run_spread.py STUDY_DIR [--baseline CONFIG]

STUDY_DIR is a `kelvin converge` output directory whose checkpoint images were all kept (`--images all`, as
tools/convergence_reports.sh runs the mlt studies). For two independent runs X_i and X_j of one configuration
(different seeds, the same distribution),

    E[(X_i - X_j)^2] / 2 = Var(X)        per pixel and channel,

so the mean over the pairs of runs of (X_i - X_j)^2 / 2 / (R^2 + eps), averaged over pixels and channels like
`kelvin converge`'s relative MSE (include/kelvin/core/metrics.h; R the study's reference, only as the weight;
eps the study's epsilon), estimates the variance part of one run's relative MSE against the true image. Unlike the
relative MSE measured against R it carries no floor from R's own noise, and R's noise only changes the weights,
the same for every configuration. What it leaves out is the squared bias of a run's mean (for MLT with the
normalisation supplied: the start-up bias and the normalisation's error); the measured relative MSE minus the
reference's floor (tools/reference_floor.py) minus this spread is of that order, up to the floor's own error.
Images: the EXR that `kelvin converge` writes beside each PNG the CSV names, or the named file itself when it is
not a PNG (any format OpenImageIO reads).

One row per configuration: at every checkpoint, the mean over pairs with its jackknife standard error over runs
(leave one run out), and the ratio to the baseline configuration's (default: the first) with the ratio's
jackknife standard error (the runs of different configurations are independent). Needs at least 3 runs per
configuration for the standard errors (2 give the estimate only). Bad input: one line naming it, exit 2.
"""
import argparse
import csv
import itertools
import math
import os
import sys
from collections import defaultdict

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from mlt_study_table import read_study  # noqa: E402
from reference_normalization import read_rgb  # noqa: E402


def fail(msg):
    print(f"run_spread: {msg}", file=sys.stderr)
    sys.exit(2)


def load(path):
    try:
        img = read_rgb(path)
    except SystemExit as e:  # read_rgb's one-line message, under this tool's name and bad input's exit code
        fail(str(e.code).replace("reference_normalization: ", "").splitlines()[0])
    if not np.isfinite(img).all():
        fail(f"{path} holds NaN or infinite pixels")
    return img


def read_settings(d):
    p = os.path.join(d, "convergence.settings")
    if not os.path.exists(p):
        fail(f"{d}: no convergence.settings (not a `kelvin converge` output directory)")
    s = {}
    for line in open(p):
        if line.startswith("#") or ":" not in line:
            continue
        k, _, v = line.partition(":")
        s[k.strip()] = v.strip()
    return s


def pair_matrix(images, w):
    """d[i, j] = mean over pixels and channels of (X_i - X_j)^2 / 2 * w."""
    n = len(images)
    d = np.zeros((n, n))
    for i, j in itertools.combinations(range(n), 2):
        d[i, j] = d[j, i] = float(np.mean((images[i] - images[j]) ** 2 * w)) / 2
    return d


def spread(d, keep):
    """Mean of d over the pairs of the runs in `keep`."""
    k = list(keep)
    return float(np.mean([d[i, j] for i, j in itertools.combinations(k, 2)]))


def jackknife(d, stat=spread):
    """(estimate, jackknife standard error, leave-one-out values) of the mean over pairs."""
    n = d.shape[0]
    est = stat(d, range(n))
    if n < 3:
        return est, math.nan, []
    loo = np.array([stat(d, [k for k in range(n) if k != i]) for i in range(n)])
    se = math.sqrt((n - 1) / n * float(np.sum((loo - loo.mean()) ** 2)))
    return est, se, loo


def fmt(v):
    return "%.3g" % v if np.isfinite(v) else "-"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("study")
    ap.add_argument("--baseline", help="the configuration the ratios are to (default: the first)")
    args = ap.parse_args()
    d = args.study
    settings = read_settings(d)
    ref_path = settings.get("reference", "")
    if not ref_path or ref_path == "exact solution" or not os.path.exists(ref_path):
        fail(f"{d}/convergence.settings: reference image '{ref_path}' not found")
    try:
        eps = float(settings.get("epsilon", "0.01"))
    except ValueError:
        fail(f"{d}/convergence.settings: cannot read epsilon '{settings.get('epsilon')}'")
    cp = os.path.join(d, "convergence.csv")
    if not os.path.exists(cp):
        fail(f"{d}: no convergence.csv")
    images = defaultdict(dict)  # (config, target) -> run -> path of the EXR
    try:
        rows, configs, targets = read_study(d)
        if rows and "image" not in rows[0]:
            fail(f"{cp}: no image column (a simulation study?)")
        for r in rows:
            if r["image"]:
                p = os.path.join(d, r["image"])
                stem, ext = os.path.splitext(p)
                images[(r["config"], r["target"])][int(r["run"])] = stem + ".exr" if ext.lower() == ".png" else p
    except (KeyError, ValueError, TypeError, csv.Error) as e:
        fail(f"{cp}: not a convergence table ({type(e).__name__}: {e})")
    baseline = args.baseline or (configs[0] if configs else None)
    if baseline not in configs:
        fail(f"--baseline '{baseline}': no such configuration in {cp} ({', '.join(configs)})")
    ref = load(ref_path)
    w = 1.0 / (ref * ref + eps)
    stats = {}
    for key, runs in images.items():
        if len(runs) < 2:
            continue
        imgs = [load(runs[k]) for k in sorted(runs)]
        for k, img in zip(sorted(runs), imgs):
            if img.shape != ref.shape:
                fail(f"{runs[k]} is {img.shape[1]}x{img.shape[0]} but the reference {ref_path} is "
                     f"{ref.shape[1]}x{ref.shape[0]}")
        stats[key] = jackknife(pair_matrix(imgs, w))
    if not stats:
        fail(f"{d}: fewer than 2 runs with kept images per configuration (run the study with --images all)")

    out = [f"- reference (the weights only): {ref_path}; epsilon {eps:g}",
           "- spread: mean over pairs of runs of (X_i - X_j)^2 / 2 / (R^2 + eps), the variance part of one run's "
           "rMSE, +- its jackknife standard error; ratio to " + baseline + " +- its standard error"]
    out.append("")
    head = ["variant", "runs"]
    for t in targets:
        head += [f"spread at {t}", f"x {baseline} at {t}"]
    out.append("| " + " | ".join(head) + " |")
    out.append("|" + "---|" * len(head))
    for c in configs:
        cells = [c, str(max((len(images[(c, t)]) for t in targets), default=0))]
        for t in targets:
            if (c, t) not in stats or (baseline, t) not in stats:
                cells += ["", ""]
                continue
            est, se, _ = stats[(c, t)]
            best, bse, _ = stats[(baseline, t)]
            cells.append(f"{fmt(est)} +- {fmt(se)}")
            if c == baseline:
                cells.append("1")
            else:
                ratio = est / best
                rse = ratio * math.sqrt((se / est) ** 2 + (bse / best) ** 2) if est > 0 and best > 0 else math.nan
                cells.append(f"{fmt(ratio)} +- {fmt(rse)}")
        out.append("| " + " | ".join(cells) + " |")
    print("\n".join(out))


if __name__ == "__main__":
    main()
