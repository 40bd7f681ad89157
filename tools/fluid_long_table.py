#!/usr/bin/env python3
"""Summarise the long-time fluid runs of `tools/convergence_reports.sh fluid-long` as a Markdown table.

Usage: fluid_long_table.py DIR

DIR holds one run folder per (scene, solver, run), named <scene>_<label>_r<run> (the folder `kelvin -o
DIR/<name>.exr` writes, with its diagnostics.csv; a name without _r<run> is one run), and a file seconds.txt of
"<name> <wall seconds>" lines. For each (scene, solver) the table gives the median over its runs, and the range, of:
the energy and enstrophy at the end relative to the start (the exact ratios are 1: both scenes are inviscid), the 2D
runs' vorticity RMSE against the exact (steady) Taylor-Green field, the 3D rings' speed (a least-squares fit of the
|omega| centroid's z against time) relative to the exact ring's, the same by the impulse centroid (the CSV's
impulse_centroid_z, whose signed weights let Monte Carlo noise cancel; runs without the column leave it empty), and
the wall seconds.

The exact ring (vortex_ring.xml: R 1, Gamma 1, Gaussian core 0.2, inviscid) is the axisymmetric vortex-ring-element
solution of include/kelvin/fluid/axisymmetric_rings.h, fitted the same way over the scene's 21 states: its |omega| centroid
moves at 0.2457 over t in [0, 2] (lattice sigma/8; 0.2455 at sigma/6), 0.986 of Saffman's asymptotic 0.2491; its impulse
centroid (tools/ring_reference.cpp, the column impulse_centroid_z at t = 0, 0.1, ..., 2) at 0.2461.
"""
import csv
import re
import statistics
import sys
from pathlib import Path

EXACT_RING = 0.2457  # the exact ring's fitted speed over [0, 2] (see above)
EXACT_RING_IMPULSE = 0.2461  # the same by the impulse centroid


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def fit_speed(times, zs):
    n = len(times)
    mt, mz = sum(times) / n, sum(zs) / n
    num = sum((t - mt) * (z - mz) for t, z in zip(times, zs))
    den = sum((t - mt) ** 2 for t in times)
    return num / den if den > 0 else float("nan")


def main():
    if len(sys.argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    root = Path(sys.argv[1])
    seconds = {}
    sec_file = root / "seconds.txt"
    if sec_file.exists():
        for line in sec_file.read_text().splitlines():
            name, value = line.split()
            seconds[name] = float(value)
    runs = {}  # (scene_label) -> list of metric dicts
    for csv_path in sorted(root.glob("*/diagnostics.csv")):
        name = csv_path.parent.name
        r = rows(csv_path)
        if len(r) < 2:
            continue
        first, last = r[0], r[-1]
        m = {"end": float(last["time"]),
             "energy": float(last["kinetic_energy"]) / float(first["kinetic_energy"]),
             "enstrophy": float(last["enstrophy"]) / float(first["enstrophy"]),
             "seconds": seconds.get(name, float("nan"))}
        if last.get("vorticity_rmse_exact", "") not in ("", None):
            m["rmse"] = float(last["vorticity_rmse_exact"])
        if "centroid_z" in first:
            m["speed"] = fit_speed([float(x["time"]) for x in r], [float(x["centroid_z"]) for x in r]) / EXACT_RING
        if "impulse_centroid_z" in first:
            m["impulse_speed"] = (fit_speed([float(x["time"]) for x in r], [float(x["impulse_centroid_z"]) for x in r]) /
                                  EXACT_RING_IMPULSE)
        runs.setdefault(re.sub(r"_r[0-9]+$", "", name), []).append(m)

    def cell(values, fmt):
        if not values:
            return ""
        med = statistics.median(values)
        if len(values) == 1:
            return format(med, fmt)
        return f"{format(med, fmt)} [{format(min(values), fmt)}, {format(max(values), fmt)}]"

    out = ["| run | runs | end time | energy(t)/energy(0) | enstrophy(t)/enstrophy(0) | vorticity RMSE vs exact | "
           "ring speed / exact ring's | by the impulse centroid | wall s |", "|---|---|---|---|---|---|---|---|---|"]
    for name, ms in sorted(runs.items()):
        col = {k: [m[k] for m in ms if k in m] for k in ("energy", "enstrophy", "rmse", "speed", "impulse_speed",
                                                         "seconds")}
        out.append(f"| {name} | {len(ms)} | {ms[0]['end']:g} | {cell(col['energy'], '.3f')} | "
                   f"{cell(col['enstrophy'], '.3f')} | {cell(col['rmse'], '.3g')} | {cell(col['speed'], '.3f')} | "
                   f"{cell(col['impulse_speed'], '.3f')} | {cell(col['seconds'], '.1f')} |")
    print("\n".join(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
