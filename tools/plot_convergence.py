#!/usr/bin/python3
"""Plots of a `kelvin converge` study (docs/convergence.md).

    tools/plot_convergence.py STUDY/convergence.csv [--out DIR] [options]

Writes into DIR (default: plots/ next to the CSV), for each metric M:
  error_vs_seconds_M.png/.svg   error against compute time, log-log: the mean over runs of every
                                configuration (thick line) with a shaded band for the spread across runs
                                (+-1 standard deviation, or min-max with --band minmax), like Figure 4.13 of
                                the thesis; --center median plots the median over runs (band: half the IQR)
  error_vs_work_M.png/.svg      the same against work (samples per pixel, steps)
  error_vs_param_M.png/.svg     when every configuration is named K=NUMBER (a --sweep) or GROUP K=NUMBER (several
                                sweeps of one parameter, e.g. one per solver): the error against the parameter,
                                one curve per group and checkpoint (like the thesis' Figure 5.15)
  error_vs_cost_M.png/.svg      and, for a sweep, the error against compute time, one point per value
and
  summary.md                    per configuration and checkpoint: mean time, work and metrics (+- std)
  time_to_error.md/.csv         how long each configuration takes (mean curve, log-log interpolation between
                                checkpoints) to reach error levels E (--targets, default: the final mean error
                                of every configuration)
  grid.png                      the checkpoint images of run 0, one row per configuration, one column per
                                checkpoint (equal time with --checkpoints), cropped with --crop x,y,w,h (pixels,
                                or fractions of each image when all are <= 1)

Needs Python 3 with matplotlib and numpy (Debian: python3-matplotlib).
"""
import argparse
import csv
import math
import os
import re
import sys
from collections import OrderedDict, defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mpimg  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

COMMON = ["config", "run", "seed", "trigger", "target", "seconds", "work", "unit", "sim_time"]
IMAGE_METRICS = ["mse", "rmse", "rel_mse", "l1", "rel_l1", "max_abs", "ssim"]
FIELD_METRICS = ["rmse", "rel_l2", "max_abs", "l1"]
LABELS = {
    "mse": "MSE", "rmse": "RMSE", "rel_mse": "relative MSE", "l1": "L1", "rel_l1": "relative L1",
    "max_abs": "max error", "ssim": "1 - SSIM", "rel_l2": "relative L2",
}


def fail(msg):
    sys.stderr.write("plot_convergence: error: %s\n" % msg)
    sys.exit(2)


def read_rows(path):
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError as e:
        fail("cannot read %s: %s" % (path, e.strerror))
    if not rows:
        fail("%s has no rows" % path)
    missing = [c for c in COMMON if c not in rows[0]]
    if missing:
        fail("%s is not a kelvin converge CSV (no column %s)" % (path, ", ".join(missing)))
    return rows


def value(row, metric):
    """The plotted value: 1 - SSIM for SSIM (so that lower is better and log axes work)."""
    try:
        v = float(row[metric])
    except (KeyError, ValueError):
        return float("nan")
    return 1.0 - v if metric == "ssim" else v


class Curve:
    """One configuration (and field): per checkpoint, the values of every run."""

    def __init__(self, name):
        self.name = name
        self.points = OrderedDict()  # (trigger, target) -> list of rows

    def add(self, row):
        self.points.setdefault((row["trigger"], float(row["target"])), []).append(row)

    def series(self, metric, x):
        """x (mean over runs), centre (mean, or median with --center median), spread (std, or for the median half
        the interquartile range), min, max of the metric, per checkpoint, sorted by x."""
        out = []
        for rows in self.points.values():
            vals = np.array([value(r, metric) for r in rows])
            xs = np.array([float(r[x]) for r in rows]) if x != "param" else None
            vals = vals[np.isfinite(vals)]
            if len(vals) == 0:
                continue
            out.append((float(np.mean(xs)) if xs is not None else 0.0, centre(vals),
                        spread(vals), float(np.min(vals)), float(np.max(vals)), len(vals)))
        out.sort()
        return [np.array(c) for c in zip(*out)] if out else None


def group(rows):
    """Curves keyed by (field, config) in the order configurations appear."""
    curves = OrderedDict()
    for r in rows:
        key = (r.get("field", ""), r["config"])
        if key not in curves:
            curves[key] = Curve(r["config"] + (" (%s)" % r["field"] if r.get("field") else ""))
        curves[key].add(r)
    return curves


def positive_floor(arrays):
    vals = np.concatenate([a[a > 0] for a in arrays if a is not None and np.any(a > 0)] or [np.array([1e-12])])
    return float(np.min(vals)) * 0.5


def save(fig, out, stem, formats):
    paths = []
    for ext in formats:
        p = os.path.join(out, "%s.%s" % (stem, ext))
        fig.savefig(p, dpi=110, bbox_inches="tight")
        paths.append(p)
    plt.close(fig)
    return paths


CENTER = "mean"  # --center: the statistic over runs that curves and tables report


def centre(vals):
    return float(np.median(vals) if CENTER == "median" else np.mean(vals))


def spread(vals):
    """std for the mean; half the interquartile range for the median (a robust spread)."""
    if CENTER == "median":
        q1, q3 = np.percentile(vals, [25, 75])
        return float(0.5 * (q3 - q1))
    return float(np.std(vals))


def plot_error(curves, metric, x, band, out, formats, title):
    fig, ax = plt.subplots(figsize=(6.0, 4.2))
    any_data = False
    for i, c in enumerate(curves.values()):
        s = c.series(metric, x)
        if s is None:
            continue
        xs, mean, std, lo, hi, n = s
        ok = (xs > 0) & (mean > 0)
        if not np.any(ok):
            continue
        any_data = True
        color = "C%d" % (i % 10)
        ax.plot(xs[ok], mean[ok], "-o", color=color, lw=2, ms=3, label="%s (%d runs)" % (c.name, int(n.max())))
        if band == "std":
            lower, upper = mean - std, mean + std
            floor = np.maximum(lo, 1e-300)
            lower = np.maximum(lower, np.minimum(floor, mean))  # log axes: never below the smallest run
        else:
            lower, upper = lo, hi
        if n.max() > 1:
            ax.fill_between(xs[ok], np.maximum(lower[ok], 1e-300), upper[ok], color=color, alpha=0.2, lw=0)
    if not any_data:
        plt.close(fig)
        return []
    ax.set_xscale("log")
    ax.set_yscale("log")
    xlabel = {"seconds": "compute time (s)", "work": "work (%s)" % unit_of(curves), "sim_time": "simulated time"}[x]
    ax.set_xlabel(xlabel)
    ax.set_ylabel(LABELS.get(metric, metric))
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(title or "%s %s against %s (band: %s)" % (CENTER, LABELS.get(metric, metric), xlabel,
                                                           ("+-1 std" if CENTER == "mean" else "+-half IQR")
                                                           if band == "std" else "min-max"), fontsize=10)
    ax.legend(fontsize=8)
    return save(fig, out, "error_vs_%s_%s" % (x, metric), formats)


def param_label(param, curves):
    """The axis label of a swept scene parameter: the shipped scenes' `spp` is samples per pixel in a render and the
    Monte Carlo sample count n_mc of each velocity estimate in a simulation (whose work unit is steps)."""
    if param == "spp":
        return "spp: n_mc, samples per velocity estimate" if unit_of(curves) == "steps" else "spp: samples per pixel"
    return param


def unit_of(curves):
    for c in curves.values():
        for rows in c.points.values():
            return rows[0]["unit"]
    return ""


SWEEP_NAME = re.compile(r"^(?:(?P<group>.*\S)\s+)?(?P<key>[A-Za-z_]\w*)=(?P<value>[-+0-9.eE]+)$")


def sweep_name(config):
    """(group, parameter, value) of a configuration named 'K=number' or 'GROUP K=number', else None."""
    m = SWEEP_NAME.match(config)
    if not m:
        return None
    try:
        return (m.group("group") or "", m.group("key"), float(m.group("value")))
    except ValueError:
        return None


def sweep_parameter(curves):
    """K if every configuration is named 'K=number' or 'GROUP K=number' (one K, several values), else None."""
    keys, values = set(), set()
    for (_, config) in curves:
        parsed = sweep_name(config)
        if parsed is None:
            return None
        keys.add(parsed[1])
        values.add(parsed[2])
    return keys.pop() if len(keys) == 1 and len(values) > 1 else None


def series_style(keys, key):
    """Colour and line style of a (group, field, trigger, target) series: with several groups (e.g. solvers),
    colour by group and line style by checkpoint; otherwise colour by checkpoint."""
    groups = sorted({k[0] for k in keys})
    checkpoints = sorted({k[1:] for k in keys})
    if len(groups) > 1:
        return "C%d" % (groups.index(key[0]) % 10), ["-", "--", ":", "-."][checkpoints.index(key[1:]) % 4]
    return "C%d" % (checkpoints.index(key[1:]) % 10), "-"


def series_label(group, field, trigger, target):
    name = {"sim_time": "t = %g", "seconds": "%g s", "work": "work %g"}.get(trigger, "%g") % target
    return (group + ", " if group else "") + name + (" (%s)" % field if field else "")


def plot_param(curves, metric, param, out, formats, title):
    """Error against the swept parameter, one curve per checkpoint (and field)."""
    by_cp = defaultdict(list)
    for (field, config), c in curves.items():
        group, _, pv = sweep_name(config)
        for (trigger, target), rows in c.points.items():
            vals = np.array([value(r, metric) for r in rows])
            vals = vals[np.isfinite(vals)]
            if len(vals):
                by_cp[(group, field, trigger, target)].append((pv, float(np.mean(vals)), float(np.std(vals))))
    fig, ax = plt.subplots(figsize=(6.0, 4.2))
    any_data = False
    for key, pts in sorted(by_cp.items()):
        pts.sort()
        p, m, s = (np.array(v) for v in zip(*pts))
        ok = (p > 0) & (m > 0)
        if np.count_nonzero(ok) < 2:
            continue
        any_data = True
        color, style = series_style(by_cp.keys(), key)
        ax.errorbar(p[ok], m[ok], yerr=s[ok], fmt="o", ls=style, ms=3, capsize=2, color=color,
                    label=series_label(*key))
    if not any_data:
        plt.close(fig)
        return []
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(param_label(param, curves))
    ax.set_ylabel(LABELS.get(metric, metric))
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(title or "%s against %s (mean +- std over runs)" % (LABELS.get(metric, metric), param), fontsize=10)
    ax.legend(fontsize=8)
    return save(fig, out, "error_vs_param_%s" % metric, formats)


def plot_cost(curves, metric, param, out, formats, title):
    """Error against compute time across a sweep: one curve per checkpoint, one point per parameter value
    (mean over runs, with the runs' spread as error bars): what each setting costs and buys."""
    by_cp = defaultdict(list)
    for (field, config), c in curves.items():
        group, _, pv = sweep_name(config)
        for (trigger, target), rows in c.points.items():
            vals = np.array([value(r, metric) for r in rows])
            secs = np.array([float(r["seconds"]) for r in rows])
            ok = np.isfinite(vals)
            if np.any(ok):
                by_cp[(group, field, trigger, target)].append(
                    (pv, float(np.mean(secs[ok])), float(np.mean(vals[ok])), float(np.std(vals[ok]))))
    fig, ax = plt.subplots(figsize=(6.0, 4.2))
    any_data = False
    for key, pts in sorted(by_cp.items()):
        pts.sort()
        p, t, m, s = (np.array(v) for v in zip(*pts))
        ok = (t > 0) & (m > 0)
        if np.count_nonzero(ok) < 2:
            continue
        any_data = True
        color, style = series_style(by_cp.keys(), key)
        ax.errorbar(t[ok], m[ok], yerr=s[ok], fmt="o", ls=style, ms=3, capsize=2, color=color,
                    label=series_label(*key))
        for pv, tx, my in zip(p[ok], t[ok], m[ok]):
            ax.annotate("%g" % pv, (tx, my), textcoords="offset points", xytext=(3, 3), fontsize=7, color=color)
    if not any_data:
        plt.close(fig)
        return []
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("compute time (s)")
    ax.set_ylabel(LABELS.get(metric, metric))
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(title or "%s against cost, points labelled by %s" % (LABELS.get(metric, metric), param), fontsize=10)
    ax.legend(fontsize=8)
    return save(fig, out, "error_vs_cost_%s" % metric, formats)


def time_to_error(curve, metric, target):
    """Compute time at which the mean curve first reaches `target` (log-log interpolation), or None."""
    s = curve.series(metric, "seconds")
    if s is None:
        return None
    xs, mean = s[0], s[1]
    for i in range(len(xs)):
        if mean[i] <= target:
            if i == 0 or not (xs[i - 1] > 0 and mean[i - 1] > 0 and mean[i] > 0 and xs[i] > 0):
                return xs[i]
            # straight line between the two checkpoints in log-log
            f = (math.log(target) - math.log(mean[i - 1])) / (math.log(mean[i]) - math.log(mean[i - 1]))
            return math.exp(math.log(xs[i - 1]) + f * (math.log(xs[i]) - math.log(xs[i - 1])))
    return None


def write_table(curves, metric, targets, out):
    if not targets:
        targets = sorted({float(c.series(metric, "seconds")[1][-1]) for c in curves.values()
                          if c.series(metric, "seconds") is not None}, reverse=True)
    names = [c.name for c in curves.values()]
    label = LABELS.get(metric, metric)
    md = ["# Time to reach an error level (%s, mean over runs)" % label, "",
          "Compute seconds until the mean %s first reaches E (log-log interpolation between checkpoints); "
          "'-' : not reached within the study." % label, "",
          "| E | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    rows = [["E"] + names]
    for e in targets:
        cells = []
        for c in curves.values():
            t = time_to_error(c, metric, e)
            cells.append("-" if t is None else "%.3g" % t)
        md.append("| %.3g | " % e + " | ".join(cells) + " |")
        rows.append(["%.6g" % e] + ["" if x == "-" else x for x in cells])
    with open(os.path.join(out, "time_to_error.md"), "w") as f:
        f.write("\n".join(md) + "\n")
    with open(os.path.join(out, "time_to_error.csv"), "w", newline="") as f:
        csv.writer(f).writerows(rows)


def write_summary(curves, metrics, out):
    """summary.md: per configuration and checkpoint, the mean time and work, and each metric's mean +- std over
    runs (or, with --center median, its median [first quartile, third quartile])."""
    lines = ["| configuration | checkpoint | runs | seconds | work | " + " | ".join(LABELS.get(m, m) for m in metrics) + " |",
             "|---|---|---|---|---|" + "---|" * len(metrics)]
    for c in curves.values():
        for (trigger, target), rows in c.points.items():
            secs = np.array([float(r["seconds"]) for r in rows])
            work = np.array([float(r["work"]) for r in rows])
            cells = []
            for m in metrics:
                v = np.array([value(r, m) for r in rows])
                v = v[np.isfinite(v)]
                if len(v) == 0:
                    cells.append("-")
                elif CENTER == "median":  # median [first quartile, third quartile]
                    q1, q3 = np.percentile(v, [25, 75])
                    cells.append("%.3g" % np.median(v) + (" [%.2g, %.2g]" % (q1, q3) if len(v) > 1 else ""))
                else:
                    cells.append("%.3g" % np.mean(v) + (" ± %.2g" % np.std(v) if len(v) > 1 else ""))
            cp = {"sim_time": "t = %g", "seconds": "%g s", "work": "%g " + rows[0]["unit"]}.get(trigger, "%g") % target
            lines.append("| %s | %s | %d | %.3g | %.4g | %s |" % (c.name, cp, len(rows), np.mean(secs), np.mean(work),
                                                                " | ".join(cells)))
    path = os.path.join(out, "summary.md")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return path


def image_grid(rows, csv_dir, crop, out):
    """Run-0 checkpoint images: rows = configurations, columns = checkpoints."""
    cells = OrderedDict()
    columns = []
    for r in rows:
        if r.get("run") != "0" or not r.get("image"):
            continue
        if r.get("field") and r["field"] != rows[0].get("field"):
            continue
        col = (r["trigger"], float(r["target"]))
        if col not in columns:
            columns.append(col)
        cells.setdefault(r["config"], {})[col] = os.path.join(csv_dir, r["image"])
    reference = os.path.join(csv_dir, "images", "reference.png")
    has_ref = os.path.exists(reference)
    if not cells:
        return None
    columns.sort()
    if len(columns) == 1:  # one checkpoint: the configurations side by side, wrapped, the reference last
        panels = [(config, imgs.get(columns[0])) for config, imgs in cells.items()]
        if has_ref:
            panels.append(("reference", reference))
        ncol = min(4, len(panels))
        nrow = (len(panels) + ncol - 1) // ncol
        fig, axes = plt.subplots(nrow, ncol, figsize=(2.2 * ncol, 2.3 * nrow), squeeze=False)
        for k, ax in enumerate(axes.flat):
            ax.set_xticks([])
            ax.set_yticks([])
            if k >= len(panels):
                ax.axis("off")
                continue
            name, path = panels[k]
            if path and os.path.exists(path):
                img = mpimg.imread(path)
                if crop:
                    x, y, w, h = crop
                    if max(crop) <= 1:
                        H, W = img.shape[:2]
                        x, y, w, h = round(x * W), round(y * H), max(1, round(w * W)), max(1, round(h * H))
                    img = img[int(y):int(y + h), int(x):int(x + w)]
                ax.imshow(img, interpolation="nearest")
            ax.set_title(name, fontsize=8)
        trigger, target = columns[0]
        fig.suptitle({"seconds": "%g s", "work": "%g", "sim_time": "t = %g"}.get(trigger, "%g") % target, fontsize=9)
        fig.tight_layout()
        path = os.path.join(out, "grid.png")
        fig.savefig(path, dpi=110)
        plt.close(fig)
        return path
    ncol = len(columns) + (1 if has_ref else 0)
    fig, axes = plt.subplots(len(cells), ncol, figsize=(1.9 * ncol, 1.9 * len(cells)), squeeze=False)

    def show(ax, path):
        img = mpimg.imread(path)
        if crop:
            x, y, w, h = crop
            if max(crop) <= 1:  # fractions of the image (images of several resolutions)
                H, W = img.shape[:2]
                x, y, w, h = int(round(x * W)), int(round(y * H)), max(1, int(round(w * W))), max(1, int(round(h * H)))
            img = img[int(y):int(y + h), int(x):int(x + w)]
        ax.imshow(img, interpolation="nearest")

    for i, (config, imgs) in enumerate(cells.items()):
        for j, col in enumerate(columns):
            ax = axes[i][j]
            ax.set_xticks([])
            ax.set_yticks([])
            if col in imgs and os.path.exists(imgs[col]):
                show(ax, imgs[col])
            if i == 0:
                ax.set_title({"seconds": "%g s", "work": "%g", "sim_time": "t = %g"}.get(col[0], "%g") % col[1],
                             fontsize=8)
            if j == 0:
                ax.set_ylabel(config, fontsize=8)
        if has_ref:
            ax = axes[i][ncol - 1]
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title("reference", fontsize=8)
                show(ax, reference)
            else:
                ax.axis("off")
    fig.tight_layout()
    path = os.path.join(out, "grid.png")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("csv", help="convergence.csv written by kelvin converge")
    ap.add_argument("--out", help="output directory (default: plots/ next to the CSV)")
    ap.add_argument("--metrics", help="comma-separated metrics (default: rel_mse,l1,ssim for renders; "
                                      "rmse,rel_l2,max_abs for fields)")
    ap.add_argument("--main", action="store_true",
                    help="only the study's main metric: rel_mse for renders, rmse for fields (what kelvin converge "
                         "--plot asks for by default)")
    ap.add_argument("--band", choices=["std", "minmax"], default="std",
                    help="spread across runs: std (for --center median: half the interquartile range) or minmax")
    ap.add_argument("--center", choices=["mean", "median"], default="mean",
                    help="statistic over runs of the curves, summary and time-to-error table (default mean; the "
                         "thesis reports medians)")
    ap.add_argument("--targets", help="error levels of the time-to-error table (comma-separated)")
    ap.add_argument("--crop", help="crop of the image grid: x,y,w,h in pixels, or in fractions of each image "
                                   "when all four are at most 1 (for images of several resolutions)")
    ap.add_argument("--formats", default="png,svg", help="plot formats (default png,svg)")
    ap.add_argument("--title", help="title of every plot")
    ap.add_argument("-q", "--quiet", action="store_true", help="do not list the files written")
    a = ap.parse_args(argv)

    global CENTER
    CENTER = a.center
    rows = read_rows(a.csv)
    field_study = "field" in rows[0]
    available = FIELD_METRICS if field_study else IMAGE_METRICS
    if a.metrics and a.main:
        fail("--metrics and --main choose the metrics both: give one")
    if a.main:
        metrics = ["rmse"] if field_study else ["rel_mse"]
    else:
        metrics = a.metrics.split(",") if a.metrics else (["rmse", "rel_l2", "max_abs"] if field_study
                                                          else ["rel_mse", "l1", "ssim"])
    for m in metrics:
        if m not in available:
            fail("--metrics: '%s' is not a column of this study (have %s)" % (m, ", ".join(available)))
    try:
        targets = [float(t) for t in a.targets.split(",")] if a.targets else None
        crop = [float(v) for v in a.crop.split(",")] if a.crop else None
    except ValueError:
        fail("--targets and --crop take comma-separated numbers")
    if crop is not None and len(crop) != 4:
        fail("--crop takes x,y,w,h")
    formats = [f for f in a.formats.split(",") if f]
    out = a.out or os.path.join(os.path.dirname(os.path.abspath(a.csv)), "plots")
    os.makedirs(out, exist_ok=True)

    curves = group(rows)
    written = []
    for m in metrics:
        written += plot_error(curves, m, "seconds", a.band, out, formats, a.title)
        written += plot_error(curves, m, "work", a.band, out, formats, a.title)
    param = sweep_parameter(curves)
    if param:
        for m in metrics:
            written += plot_param(curves, m, param, out, formats, a.title)
            written += plot_cost(curves, m, param, out, formats, a.title)
    written.append(write_summary(curves, metrics, out))
    write_table(curves, metrics[0], targets, out)
    written += [os.path.join(out, "time_to_error.md"), os.path.join(out, "time_to_error.csv")]
    grid = image_grid(rows, os.path.dirname(os.path.abspath(a.csv)), crop, out)
    if grid:
        written.append(grid)
    if not a.quiet:
        for p in written:
            print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
