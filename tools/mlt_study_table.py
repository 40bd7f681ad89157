#!/usr/bin/python3
"""The table of an MLT equal-time study (docs/studies/mlt.md), in Markdown on stdout.

    tools/mlt_study_table.py STUDY_DIR          # STUDY_DIR: a `kelvin converge` output directory

One row per configuration: the median over runs, with the interquartile range [Q1, Q3], of the relative MSE and of
L1 at every checkpoint; then the medians over runs of the mutations per pixel at the last checkpoint, of the
mutations per second, of the small-step, large-step and second-stage acceptance and of the second stage's share
of the path-evaluation time (convergence_stats.csv: the counters of each whole run). When a configuration uses
the h2mc mutation, a second table gives the medians over runs of its counters (mlt.h2mc.*): H2MC proposals and
their acceptance, derivative evaluations, the shares of them that were not differentiable (unsupported, mismatch,
too long, next to a discontinuity) and that fell back to the isotropic Gaussian for a small Hessian, the share of
the run's time spent in derivatives (seconds_derivatives / run.seconds: meaningful with one thread), the time per
derivative evaluation and its inverse, and the share of the run's time spent in the kernel's Gaussian proposals
(seconds_gaussians / run.seconds). When a configuration uses the langevin mutation, a table of the same columns
(without the small Hessian: Langevin takes gradients only) gives its counters (mlt.langevin.*). Above the table: the
normalisation, the matched sigma and the reference's error floor when the study directory holds normalization.txt,
sigma.txt and reference_floor.txt (as tools/convergence_reports.sh leaves them); with the floor, a column gives the
median rMSE at the last checkpoint minus it. Quartiles are numpy's (linear interpolation); with fewer than 2 runs
only the median is shown.
"""
import csv
import os
import sys
from collections import defaultdict

import numpy as np


def fmt(v):
    return "%.3g" % v


def med_iqr(vals):
    vals = np.asarray(vals, dtype=float)
    if len(vals) == 0:
        return ""
    m = fmt(np.median(vals))
    if len(vals) < 2:
        return m
    q1, q3 = np.percentile(vals, [25, 75])
    return f"{m} [{fmt(q1)}, {fmt(q3)}]"


def read_study(d):
    """(rows, configurations, checkpoint targets) of STUDY_DIR/convergence.csv, the latter two in order of first
    appearance."""
    rows = list(csv.DictReader(open(os.path.join(d, "convergence.csv"))))
    configs, targets = [], []
    for r in rows:
        if r["config"] not in configs:
            configs.append(r["config"])
        if r["target"] not in targets:
            targets.append(r["target"])
    return rows, configs, targets


def derivative_table(configs, stats, kernel, label):
    """The lines of the table of the derivative-based kernel's counters (mlt.KERNEL.*) of the configurations that
    use it, or no lines."""
    p = "mlt." + kernel + "."
    used = [c for c in configs if stats.get(c, {}).get(p + "derivatives")]
    if not used:
        return []
    hessian = kernel == "h2mc"  # langevin takes gradients only: no small-Hessian fallback
    head = ["variant", f"{label} proposals", f"{label} acc.", "derivatives", "not differentiable", "unsupported",
            "mismatch", "too long", "discontinuous"] + (["small Hessian"] if hessian else []) + [
            "time in derivatives", "ms per derivative", "derivatives/s", "time in Gaussians"]
    out = ["", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for c in used:
        s = stats[c]

        def per_run(num, den, scale=1.0):  # median over runs of num / den (a counter never incremented may be absent: 0)
            nums = s.get(num) or [0.0] * len(s.get(den, []))
            v = [scale * a / b for a, b in zip(nums, s.get(den, [])) if b > 0]
            return fmt(np.median(v)) if v else ""

        cells = [c, fmt(np.median(s[p + "proposals"])), fmt(np.median(s[p + "acceptance"])),
                 fmt(np.median(s[p + "derivatives"]))] + \
            [per_run(p + k, p + "derivatives")
             for k in ("not_differentiable", "unsupported", "mismatch", "too_long", "discontinuous") +
             (("small_hessian",) if hessian else ())] + \
            [per_run(p + "seconds_derivatives", "run.seconds"),
             per_run(p + "seconds_derivatives", p + "derivatives", 1e3),
             per_run(p + "derivatives", p + "seconds_derivatives"),
             per_run(p + "seconds_gaussians", "run.seconds")]
        out.append("| " + " | ".join(cells) + " |")
    out.append("")
    out.append(f"(mlt.{kernel}.*: medians over runs; the shares are of the derivative evaluations, the time shares "
               "of the run's seconds; ms per derivative and derivatives/s are of the time in derivatives)")
    return out


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    d = sys.argv[1]
    rows, configs, targets = read_study(d)
    err = defaultdict(lambda: defaultdict(list))  # (config, target) -> metric -> values over runs
    work = defaultdict(list)
    for r in rows:
        c, t = r["config"], r["target"]
        for m in ("rel_mse", "l1"):
            err[(c, t)][m].append(float(r[m]))
    last = max(targets, key=float)
    for r in rows:
        if r["target"] == last:
            work[r["config"]].append(float(r["work"]))
    stats = defaultdict(lambda: defaultdict(list))
    sp = os.path.join(d, "convergence_stats.csv")
    if os.path.exists(sp):
        for r in csv.DictReader(open(sp)):
            try:
                stats[r["config"]][r["counter"]].append(float(r["value"]))
            except ValueError:
                pass

    out = []
    floor = None
    for name in ("normalization.txt", "sigma.txt", "reference_floor.txt"):
        p = os.path.join(d, name)
        if os.path.exists(p):
            for line in open(p):
                if line.startswith(("normalization =", "sigma =", "acceptance =", "target_acceptance =",
                                    "floor_rel_mse =", "floor_rel_mse_se =")):
                    out.append("- " + line.strip())
                if line.startswith("floor_rel_mse ="):
                    try:
                        floor = float(line.split("=")[1])
                    except ValueError:
                        sys.exit(f"mlt_study_table: {p}: cannot read the floor from '{line.strip()}'")
    runs = max((len(v["rel_mse"]) for v in err.values()), default=0)
    unit = rows[0]["unit"] if rows else ""
    out.append(f"- {runs} runs per configuration; median [interquartile range] over runs; "
               f"checkpoints in {rows[0]['trigger'] if rows else ''}")
    out.append("")
    if floor is not None:
        out.append("- rMSE - floor: the median rMSE at the last checkpoint minus the reference's own floor "
                   "(tools/reference_floor.py), the run's error against the true image")
    head = ["variant"] + [f"rMSE at {t}" for t in targets] + (
        [f"rMSE - floor at {last}"] if floor is not None else []) + [f"L1 at {t}" for t in targets] + [
        f"{unit} at {last}", "mutations/s", "small-step acc.", "large-step acc.", "stage-2 acc.", "stage-2 time share"]
    out.append("| " + " | ".join(head) + " |")
    out.append("|" + "---|" * len(head))
    for c in configs:
        s = stats.get(c, {})

        def sm(k):
            v = s.get(k, [])
            return fmt(np.median(v)) if v else ""

        cells = [c] + [med_iqr(err[(c, t)]["rel_mse"]) for t in targets] + \
                ([fmt(np.median(err[(c, last)]["rel_mse"]) - floor)] if floor is not None else []) + \
                [med_iqr(err[(c, t)]["l1"]) for t in targets] + \
                [fmt(np.median(work[c])) if work[c] else "", sm("mlt.mutations_per_second"),
                 sm("mlt.acceptance.stage1_small"), sm("mlt.acceptance.large_step")] + \
                ([sm("mlt.acceptance.stage2"), sm("mlt.stage2_time_share")] if "mlt.stage2_attempts" in s and
                 np.median(s["mlt.stage2_attempts"]) > 0 else ["", ""])
        out.append("| " + " | ".join(cells) + " |")
    for kernel, label in (("h2mc", "H2MC"), ("langevin", "Langevin")):
        out += derivative_table(configs, stats, kernel, label)
    print("\n".join(out))


if __name__ == "__main__":
    main()
