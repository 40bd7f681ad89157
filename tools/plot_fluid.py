#!/usr/bin/python3
"""Plots of the per-step diagnostics CSV that every Kelvin fluid simulation writes (docs/fluid.md).

    tools/plot_fluid.py RUN [MORE ...] [--labels A,B,...] [--out PREFIX] [--table FILE]
    tools/plot_fluid.py --montage RUN[,RUN...] --steps 0,20,40 [--labels A,B,...] [--dye] --out FILE.png

RUN is a run's folder (what `kelvin scene.xml -o out/run.exr` writes into out/run/) or its diagnostics CSV.

Writes PREFIX.png and PREFIX.svg (default PREFIX: RUN/plot for the first run): one panel per
diagnostic against simulated time, one curve per CSV (e.g. mcfluid, vortex_particles and stable_fluids runs of
the same scene):
  kinetic energy (noise-corrected for mcfluid; dashed: the raw estimate when it differs), enstrophy,
  circulation, max |omega|, wall time per step (log scale), and the vorticity RMSE against the exact solution
  when the initial condition has one (column vorticity_rmse_exact; log scale).
Prints (and with --table writes) a Markdown table per CSV: steps, end time, mean seconds per step, energy and
enstrophy at the end relative to t = 0, and the final RMSE against the exact solution.

--montage puts the frames RUN/vorticity_NNNN.png (or RUN/dye_NNNN.png with --dye) of several runs side by side: one
row per run, one column per step, titled with the simulated time from RUN/diagnostics.csv (like the thesis' Figure
5.10). (Every run also writes RUN/montage.png by itself: up to 8 of its frames, without titles.)

Needs Python 3 with matplotlib (Debian: python3-matplotlib; tools/setup.sh installs it). Exit status 2 on bad
input (a missing file, a CSV without the expected columns).
"""
import argparse
import csv
import math
import os
import sys

REQUIRED = ["step", "time", "kinetic_energy", "enstrophy", "circulation", "max_abs_vorticity", "seconds"]


def fail(msg):
    print(f"plot_fluid.py: {msg}", file=sys.stderr)
    sys.exit(2)


def number(s):
    try:
        return float(s) if s != "" else math.nan
    except ValueError:
        return math.nan


def read_csv(path):
    if not os.path.isfile(path):
        fail(f"'{path}' does not exist")
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        fail(f"'{path}' has no data rows")
    missing = [c for c in REQUIRED if c not in rows[0]]
    if missing:
        fail(f"'{path}' lacks the column(s) {', '.join(missing)} (is it a Kelvin fluid diagnostics CSV?)")
    cols = {k: [number(r[k]) for r in rows] for k in rows[0].keys() if k is not None}
    return cols


def summary(label, c):
    steps = [s for s in c["seconds"][1:] if not math.isnan(s)]
    e, z = c["kinetic_energy"], c["enstrophy"]
    last = c.get("vorticity_rmse_exact", [math.nan])[-1]  # NaN when the exact solution is unknown at the end
    return {
        "label": label,
        "steps": int(c["step"][-1]),
        "time": c["time"][-1],
        "sec": sum(steps) / len(steps) if steps else math.nan,
        "energy": e[-1] / e[0] if e[0] else math.nan,
        "enstrophy": z[-1] / z[0] if z[0] else math.nan,
        "rmse": last,
    }


def table(rows):
    out = ["| run | steps | t | s/step | energy(t)/energy(0) | enstrophy(t)/enstrophy(0) | vorticity RMSE vs exact |",
           "|---|---|---|---|---|---|---|"]
    for r in rows:
        rmse = "—" if math.isnan(r["rmse"]) else f"{r['rmse']:.3g}"
        out.append(f"| {r['label']} | {r['steps']} | {r['time']:.3g} | {r['sec']:.3g} | {r['energy']:.4f} | "
                   f"{r['enstrophy']:.4f} | {rmse} |")
    return "\n".join(out) + "\n"


def run_dir(path):
    """A run's folder from the folder itself or its diagnostics.csv."""
    return os.path.dirname(path) if path.endswith(".csv") else path


def run_csv(path):
    """A run's diagnostics CSV from the folder or the CSV itself."""
    return path if path.endswith(".csv") else os.path.join(path, "diagnostics.csv")


def run_label(path):
    """The run's name: its folder's name (a CSV not named diagnostics.csv: its own name)."""
    if path.endswith(".csv") and os.path.basename(path) != "diagnostics.csv":
        return os.path.splitext(os.path.basename(path))[0]
    return os.path.basename(os.path.normpath(run_dir(path))) or "run"


def frame_path(run, step, dye):
    kind = "dye" if dye else "vorticity"
    for digits in range(4, 13):
        p = os.path.join(run_dir(run), f"{kind}_{step:0{digits}d}.png")
        if os.path.isfile(p):
            return p
    fail(f"no frame {os.path.join(run_dir(run), f'{kind}_{step:04d}.png')} (was the run made with output_every "
         f"dividing {step}?)")


def montage(a, plt, image):
    prefixes = a.montage.split(",")
    labels = a.labels.split(",") if a.labels else [run_label(p) for p in prefixes]
    if len(labels) != len(prefixes):
        fail(f"{len(labels)} label(s) for {len(prefixes)} run(s)")
    if not a.steps:
        fail("--montage needs --steps")
    steps = [int(x) for x in a.steps.split(",")]
    if not a.out:
        fail("--montage needs --out FILE.png")
    times = {}
    for p in prefixes:
        if os.path.isfile(run_csv(p)):
            c = read_csv(run_csv(p))
            times[p] = dict(zip((int(x) for x in c["step"]), c["time"]))
    size = a.cell
    fig, axes = plt.subplots(len(prefixes), len(steps), figsize=(size * len(steps), size * len(prefixes) + 0.3),
                             squeeze=False)
    for r, (p, lab) in enumerate(zip(prefixes, labels)):
        for c, st in enumerate(steps):
            ax = axes[r][c]
            ax.imshow(image.imread(frame_path(p, st, a.dye)), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                t = times.get(p, {}).get(st)
                ax.set_title(f"t = {t:g}" if t is not None else f"step {st}", fontsize=9)
            if c == 0:
                ax.set_ylabel(lab, fontsize=9)
    fig.tight_layout(pad=0.3)
    fig.savefig(a.out, dpi=a.dpi or 100)
    print(f"wrote {a.out}", file=sys.stderr)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("csv", nargs="*", help="runs: folders written by a fluid simulation, or their diagnostics CSVs")
    ap.add_argument("--montage", help="comma-separated run folders whose frames to put side by side")
    ap.add_argument("--steps", help="--montage: comma-separated steps (columns)")
    ap.add_argument("--dye", action="store_true", help="--montage: the dye frames")
    ap.add_argument("--cell", type=float, default=1.3, help="--montage: inches per frame")
    ap.add_argument("--dpi", type=int, default=0, help="resolution of the PNG (default 110; --montage 100)")
    ap.add_argument("--labels", help="comma-separated curve labels (default: the file names)")
    ap.add_argument("--out", help="output prefix (default: <first csv>_plot)")
    ap.add_argument("--table", help="also write the summary table (Markdown) to this file")
    ap.add_argument("--title", default="", help="figure title")
    a = ap.parse_args()
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.image as image
        import matplotlib.pyplot as plt
    except ImportError:
        fail("matplotlib is missing (Debian: apt-get install python3-matplotlib; run with /usr/bin/python3)")
    if a.montage:
        montage(a, plt, image)
        return
    if not a.csv:
        fail("give at least one CSV (or --montage)")

    labels = a.labels.split(",") if a.labels else [run_label(p) for p in a.csv]
    if len(labels) != len(a.csv):
        fail(f"{len(labels)} label(s) for {len(a.csv)} run(s)")
    runs = [(lab, read_csv(run_csv(p))) for lab, p in zip(labels, a.csv)]
    first = a.csv[0]
    if first.endswith(".csv") and os.path.basename(first) != "diagnostics.csv":
        out = a.out or os.path.splitext(first)[0] + "_plot"
    else:
        out = a.out or os.path.join(run_dir(first), "plot")

    has_exact = any(any(not math.isnan(v) for v in c.get("vorticity_rmse_exact", [])) for _, c in runs)
    panels = [("kinetic_energy", "kinetic energy  ½∫|u|²", False), ("enstrophy", "enstrophy  ½∫ω²", False),
              ("circulation", "circulation  ∫ω", False), ("max_abs_vorticity", "max |ω|", False),
              ("seconds", "wall time per step (s)", True)]
    if has_exact:
        panels.append(("vorticity_rmse_exact", "vorticity RMSE vs exact", True))
    cols = 3
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    for ax, (key, title, logy) in zip(axes.flat, panels):
        raw_drawn = False
        for lab, c in runs:
            t, y = c["time"], c.get(key, [])
            pts = [(ti, yi) for ti, yi in zip(t, y) if not math.isnan(yi) and (not logy or yi > 0)]
            if key == "seconds":
                pts = pts[1:] if pts and pts[0][0] == 0 else pts  # state 0 has no step
            if not pts:
                continue
            line, = ax.plot([p[0] for p in pts], [p[1] for p in pts], label=lab, lw=1.5)
            if key == "kinetic_energy" and "kinetic_energy_raw" in c:
                raw = c["kinetic_energy_raw"]
                if any(abs(r - e) > 1e-12 * max(1.0, abs(e)) for r, e in zip(raw, y) if not math.isnan(r)):
                    ax.plot(t, raw, ls="--", lw=1, color=line.get_color(),
                            label=f"{lab}: raw (before the noise correction)")
                    raw_drawn = True
        if raw_drawn and ax is not axes.flat[0]:
            ax.legend(fontsize=7)  # the dashed lines are named where they are drawn
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("t")
        if logy:
            ax.set_yscale("log")
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=8)
    if a.title:
        fig.suptitle(a.title)
    fig.tight_layout()
    for ext in (".png", ".svg"):
        fig.savefig(out + ext, dpi=a.dpi or 110)
    md = table([summary(lab, c) for lab, c in runs])
    print(md, end="")
    if a.table:
        with open(a.table, "w") as f:
            f.write(md)
    print(f"wrote {out}.png, {out}.svg" + (f", {a.table}" if a.table else ""), file=sys.stderr)


if __name__ == "__main__":
    main()
