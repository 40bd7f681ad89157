#!/usr/bin/python3
"""Summarise the leapfrogging-rings runs of `tools/convergence_reports.sh fluid-leapfrog` as a Markdown table.

Usage: fluid_leapfrog_table.py DIR [--sigma 0.2] [--times 2,4] [--title TEXT] [--plot FILE.png]

DIR holds one run folder per (solver, run), named <label>_r<run> (the folder `kelvin -o DIR/<name>.exr` writes, with
its diagnostics.csv and its core1_r, core1_z, core1_circulation, core2_... columns), a file seconds.txt of
"<name> <wall seconds>" lines, and reference.csv, written by build/bin/ring_reference (the exact inviscid dynamics
of the same rings, the same core columns found the same way on a meridian grid of the solvers' spacing).

Per run, from the two cores of each state (sorted by z in the CSV):
  - merged: a state is merged when fewer than two cores are found, when they are closer than 1.5 sigma, or when the
    weaker holds less than a third of the stronger's circulation (a filament of the merged core, not a ring); the
    merger time is the first merged state after the last stretch of at least 0.2 time units with two rings apart (a
    second maximum that comes and goes more briefly is part of the merged core); "-" when the run ends with two
    rings apart;
  - passes before the merger: a pass is the rear ring going through the front one. The two cores orbit each other in
    the (r, z) plane, the rear one inner while it catches up; sorted by z, a pass is where the front core goes from
    outer to inner (r_front - r_rear from + to -) while their z differ less than their r (which tells it from the
    half-way point, where the front core turns outer again with the two at equal r and far apart in z). A state
    with one core between the two sides (the cores too close for two maxima while passing) counts too, and so does a
    state merged by the rule above (two maxima closer than 1.5 sigma: one ring's core seen twice; or a filament);
    the pass time is the zero of r_front - r_rear interpolated between the states on each side. After a pass, another
    counts only once the cores have been through the half-way point (z differing more than r), so the order of two
    cores at nearly the same z flickering in the noise is one pass;
  - the energy (kinetic_energy, mcfluid's noise-corrected) and the impulse (impulse_z) at the times of --times
    (default t = 2 and t = 4) relative to t = 0 (the exact ratios are 1);
  - the ring speed: the least-squares slope over the run of the circulation-weighted mean z of the cores found,
    and relative to the reference's;
  - wall seconds.
The table gives, per solver, the median over its runs and the range [min, max]. The reference's row is one run.
With --plot, a figure of each state's core z and r against time, one row of panels per solver (every run, the first
dark), the reference in black on each.
"""
import argparse
import csv
import math
import re
import statistics
import sys
from pathlib import Path

APART = 0.2  # time the two cores must stay apart to count as two rings again after a merged state


def read_rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def cores_of(row):
    """The cores of one state as (r, z, circulation), sorted by z (the CSV's order)."""
    out = []
    for k in range(1, 10):
        r = row.get(f"core{k}_r")
        if r is None:
            break
        if r == "":
            continue
        out.append((float(r), float(row[f"core{k}_z"]), float(row[f"core{k}_circulation"])))
    return out


def merged(cores, sigma):
    if len(cores) < 2:
        return True
    (r1, z1, c1), (r2, z2, c2) = cores[0], cores[1]
    if math.hypot(r2 - r1, z2 - z1) < 1.5 * sigma:
        return True
    return min(c1, c2) < max(c1, c2) / 3


def analyse(rows, sigma, at_times=(2.0, 4.0)):
    times = [float(r["time"]) for r in rows]
    cores = [cores_of(r) for r in rows]
    flags = [merged(c, sigma) for c in cores]
    # The merger: the first merged state after the last time the rings were apart (unmerged) for APART time units in
    # a row; a second maximum that comes and goes more briefly is part of the merged core, not a ring.
    step = times[1] - times[0] if len(times) > 1 else 0.0
    after = 0  # the index after the last long unmerged stretch
    i = 0
    while i < len(rows):
        if flags[i]:
            i += 1
            continue
        j = i
        while j < len(rows) and not flags[j]:
            j += 1
        if j == len(rows) or times[j - 1] - times[i] + step >= APART - 1e-9:
            after = j
        i = j
    merger, end_two = None, len(rows)
    if after < len(rows):
        merger, end_two = times[after], after
    # Passes: + to - of r_front - r_rear across states with two cores (one-core states between them allowed).
    passes = []
    prev = None  # (time, dr, dz) of the last state with two cores
    armed = True  # a pass counts only after the half-way point (dz > |dr|) since the last one
    for i in range(end_two):
        c = cores[i]
        if len(c) < 2 or flags[i]:  # one core, or two too close to be two rings (one ring's core seen twice)
            continue
        dr, dz = c[1][0] - c[0][0], c[1][1] - c[0][1]
        if dz > abs(dr):
            armed = True
        if armed and prev is not None and prev[1] > 0 and dr < 0 and min(prev[2], dz) < max(abs(prev[1]), abs(dr)):
            t0, dr0 = prev[0], prev[1]
            passes.append(t0 + (times[i] - t0) * dr0 / (dr0 - dr))
            armed = False
        prev = (times[i], dr, dz)

    def at(t, column):
        best = min(range(len(rows)), key=lambda i: abs(times[i] - t))
        if abs(times[best] - t) > 1e-6 + 0.51 * (times[1] - times[0] if len(times) > 1 else 0):
            return float("nan")
        v = rows[best].get(column, "")
        return float(v) if v != "" else float("nan")

    def ratio(t, column):
        return at(t, column) / at(0, column) if column in rows[0] else float("nan")

    # Ring speed: slope of the circulation-weighted mean z of the cores.
    ts, zs = [], []
    for t, c in zip(times, cores):
        w = sum(x[2] for x in c)
        if c and w > 0:
            ts.append(t)
            zs.append(sum(x[1] * x[2] for x in c) / w)
    speed = float("nan")
    if len(ts) > 1:
        mt, mz = sum(ts) / len(ts), sum(zs) / len(zs)
        den = sum((t - mt) ** 2 for t in ts)
        speed = sum((t - mt) * (z - mz) for t, z in zip(ts, zs)) / den if den > 0 else float("nan")
    energy = "kinetic_energy"
    return {
        "passes": len(passes),
        "pass_times": passes,
        "merger": merger,
        "end": times[-1],
        "E": [ratio(t, energy) for t in at_times],
        "P": [ratio(t, "impulse_z") for t in at_times],
        "speed": speed,
    }


def fmt_range(values, f="{:.3f}"):
    v = [x for x in values if x is not None and not (isinstance(x, float) and math.isnan(x))]
    if not v:
        return "-"
    m = statistics.median(v)
    if len(v) == 1 or min(v) == max(v):
        return f.format(m) + ("" if len(v) == len(values) else f" ({len(v)}/{len(values)})")
    s = f"{f.format(m)} [{f.format(min(v))}, {f.format(max(v))}]"
    return s + ("" if len(v) == len(values) else f" ({len(v)}/{len(values)})")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir")
    ap.add_argument("--sigma", type=float, default=0.2, help="the rings' Gaussian core radius (merger distance)")
    ap.add_argument("--times", default="2,4", help="the times of the energy and impulse columns")
    ap.add_argument("--title", default="R 1, sigma 0.2, 0.6 apart", help="the rings, for the figure's title")
    ap.add_argument("--plot", default=None, help="write the core-track figure here (needs matplotlib)")
    args = ap.parse_args()
    times = [float(t) for t in args.times.split(",")]
    d = Path(args.dir)
    seconds = {}
    if (d / "seconds.txt").exists():
        for line in (d / "seconds.txt").read_text().splitlines():
            name, value = line.split()
            seconds[name] = float(value)
    runs = {}
    for csvp in sorted(d.glob("*/diagnostics.csv")):
        name = csvp.parent.name
        m = re.fullmatch(r"(.+)_r(\d+)", name)
        label, run = (m.group(1), int(m.group(2))) if m else (name, 1)
        rows = read_rows(csvp)
        if not rows or "core1_z" not in rows[0]:
            print(f"fluid_leapfrog_table: {csvp} has no core columns; skipped", file=sys.stderr)
            continue
        a = analyse(rows, args.sigma, times)
        a["seconds"] = seconds.get(name, float("nan"))
        a["rows"] = rows
        runs.setdefault(label, []).append((run, a))
    ref = None
    if (d / "reference.csv").exists():
        rrows = read_rows(d / "reference.csv")
        ref = analyse(rrows, args.sigma, times)
        ref["seconds"] = float(rrows[-1].get("seconds", "nan") or "nan")
        ref["rows"] = rrows
        # The reference's impulse and "energy": it conserves both (the impulse column is its own; energy: exact).
        ref["E"] = [1.0 for _ in times]
    if not runs and ref is None:
        sys.exit(f"fluid_leapfrog_table: no run folders with a diagnostics.csv and no reference.csv in {d}")

    def tname(t):
        return f"{t:g}"

    ecols = " | ".join(f"E({tname(t)})/E(0)" for t in times)
    pcols = " | ".join(f"P({tname(t)})/P(0)" for t in times)
    print(f"| solver | runs | passes before merger | pass times | merger t | {ecols} | {pcols} | ring speed | "
          "speed / exact | wall s |")
    print("|---|---|---|---|---|" + "---|" * (2 * len(times)) + "---|---|---|")
    ref_speed = ref["speed"] if ref else float("nan")

    def line(label, items):
        n = len(items)
        max_passes = max(a["passes"] for a in items)
        pass_cols = []
        for p in range(max_passes):
            pass_cols.append(fmt_range([a["pass_times"][p] if p < len(a["pass_times"]) else None for a in items],
                                       "{:.2f}"))
        merger = [a["merger"] for a in items]
        merger_text = fmt_range(merger, "{:.1f}") if any(x is not None for x in merger) else "- (two rings at the end)"
        print(f"| {label} | {n} | {fmt_range([a['passes'] for a in items], '{:.0f}')} | "
              f"{'; '.join(pass_cols) if pass_cols else '-'} | {merger_text} | "
              + "".join(f"{fmt_range([a['E'][k] for a in items])} | " for k in range(len(times)))
              + "".join(f"{fmt_range([a['P'][k] for a in items])} | " for k in range(len(times)))
              + f"{fmt_range([a['speed'] for a in items])} | "
              f"{fmt_range([a['speed'] / ref_speed for a in items])} | "
              f"{fmt_range([a['seconds'] for a in items], '{:.1f}')} |")

    if ref:
        line("exact (ring_reference)", [ref])
    for label in sorted(runs, key=lambda s: (s.split("-")[0] != "mcfluid", s)):
        line(label, [a for _, a in sorted(runs[label], key=lambda x: x[0])])

    if ref and "ring1_z" in ref["rows"][0] and "ring2_z" in ref["rows"][0]:
        # The reference also follows each ring's own elements: where their impulse centroids cross.
        cross, prev = [], None
        for row in ref["rows"]:
            t, dz = float(row["time"]), float(row["ring2_z"]) - float(row["ring1_z"])
            if prev is not None and (prev[1] > 0) != (dz > 0):
                cross.append(prev[0] + (t - prev[0]) * prev[1] / (prev[1] - dz))
            prev = (t, dz)
        print(f"\nThe exact rings' own elements (impulse centroids z = sum z r^2 g / sum r^2 g of each ring's elements) "
              f"change order at t = {', '.join(f'{t:.2f}' for t in cross) if cross else 'never'}.")

    if args.plot:
        try:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
        except ImportError:
            print("fluid_leapfrog_table: matplotlib is missing; no plot", file=sys.stderr)
            return
        labels = sorted(runs, key=lambda s: (s.split("-")[0] != "mcfluid", s))
        fig, axes = plt.subplots(len(labels), 2, figsize=(10, 2.3 * len(labels) + 0.6), sharex=True, squeeze=False)

        def scatter(ax_z, ax_r, rows, **kw):
            t, z, r = [], [], []
            for row in rows:
                for c in cores_of(row):
                    t.append(float(row["time"]))
                    r.append(c[0])
                    z.append(c[1])
            ax_z.plot(t, z, linestyle="none", **kw)
            ax_r.plot(t, r, linestyle="none", **kw)

        for k, label in enumerate(labels):
            az, ar = axes[k]
            if ref:
                scatter(az, ar, ref["rows"], marker=".", markersize=2.5, color="black", label="exact")
            for j, (run, a) in enumerate(sorted(runs[label], key=lambda x: x[0])):
                scatter(az, ar, a["rows"], marker="o", markersize=3 if j == 0 else 2, alpha=1 if j == 0 else 0.35,
                        color="tab:red", label=label if j == 0 else None)
            az.set_ylabel("core z")
            ar.set_ylabel("core r")
            az.legend(loc="upper left", fontsize=8)
            az.grid(alpha=0.3)
            ar.grid(alpha=0.3)
        axes[-1][0].set_xlabel("t")
        axes[-1][1].set_xlabel("t")
        fig.suptitle(f"Leapfrogging rings ({args.title}): cores of the azimuthal mean of omega_theta", fontsize=10)
        fig.tight_layout()
        fig.savefig(args.plot, dpi=110)


if __name__ == "__main__":
    main()
