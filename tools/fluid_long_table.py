#!/usr/bin/env python3
"""Summarise the long-time fluid runs of `tools/convergence_reports.sh fluid-long` as a Markdown table.

Usage: fluid_long_table.py DIR

DIR holds one run folder per (scene, solver), named <scene>_<label> (the folder `kelvin -o DIR/<scene>_<label>.exr`
writes, with its diagnostics.csv), and a file seconds.txt of "<scene>_<label> <wall seconds>" lines. For each run the
table gives the energy and enstrophy at the end relative to the start (the exact ratios are 1: both scenes are
inviscid), the 2D runs' vorticity RMSE against the exact (steady) Taylor-Green field, and the 3D rings' speed (a
least-squares fit of the centroid's z against time) relative to Saffman's speed for the ring as set up.
"""
import csv
import math
import sys
from pathlib import Path

SAFFMAN = 1.0 / (4 * math.pi) * (math.log(8 * 1.0 / 0.2) - 0.558)  # vortex_ring.xml: R 1, Gamma 1, sigma 0.2


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
    out = ["| run | end time | energy(t)/energy(0) | enstrophy(t)/enstrophy(0) | vorticity RMSE vs exact | "
           "ring speed / Saffman | wall s |", "|---|---|---|---|---|---|---|"]
    for csv_path in sorted(root.glob("*/diagnostics.csv")):
        name = csv_path.parent.name
        r = rows(csv_path)
        if len(r) < 2:
            continue
        first, last = r[0], r[-1]
        energy = float(last["kinetic_energy"]) / float(first["kinetic_energy"])
        enstrophy = float(last["enstrophy"]) / float(first["enstrophy"])
        rmse = last.get("vorticity_rmse_exact", "")
        speed = ""
        if "centroid_z" in first:
            ts = [float(x["time"]) for x in r]
            zs = [float(x["centroid_z"]) for x in r]
            speed = f"{fit_speed(ts, zs) / SAFFMAN:.3f}"
        rmse_s = f"{float(rmse):.3g}" if rmse not in ("", None) else ""
        out.append(f"| {name} | {float(last['time']):g} | {energy:.3f} | {enstrophy:.3f} | {rmse_s} | {speed} | "
                   f"{seconds.get(name, float('nan')):.1f} |")
    print("\n".join(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
