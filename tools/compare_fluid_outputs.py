#!/usr/bin/env python3
"""Runs every shipped fluid scene with two kelvin binaries and compares their outputs file by file.

For refactors that must not change a simulation: the CSV values (timing columns aside), PNG frames, EXR pixel data
(the renderTimeSeconds attribute masked) and VDB files (the file UUID masked) must be identical. Scenes that take a
`solver` parameter run with each of mcfluid, stable_fluids, flip and vortex_particles.

    tools/compare_fluid_outputs.py OLD/bin/kelvin build/bin/kelvin [--work DIR] [--scenes GLOB]

Exit 0 when everything matches; otherwise lists the differing files and exits 1.
"""
import argparse
import csv
import glob
import os
import subprocess
import sys
import tempfile

SOLVERS = ["mcfluid", "stable_fluids", "flip", "vortex_particles"]
THREE_D = {"bunny3d", "bunny3d_soup", "fence", "sphere_obstacle", "abc", "taylor_green_3d", "vortex_ring", "leapfrog"}


def masked(path):
    data = bytearray(open(path, "rb").read())
    key = b"renderTimeSeconds\x00double\x00\x08\x00\x00\x00"
    at = data.find(key)
    if at >= 0:
        data[at + len(key):at + len(key) + 8] = bytes(8)
    if path.endswith(".vdb"):
        data[21:57] = bytes(36)  # the file's UUID
    return bytes(data)


def csv_values(path):
    rows = list(csv.reader(open(path)))
    drop = {i for i, name in enumerate(rows[0]) if "second" in name}
    return [[v for i, v in enumerate(row) if i not in drop] for row in rows]


def files(root):
    return sorted(os.path.relpath(os.path.join(d, f), root) for d, _, fs in os.walk(root) for f in fs)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old")
    ap.add_argument("new")
    ap.add_argument("--work", default=None, help="folder for the outputs (default: a temporary one)")
    ap.add_argument("--scenes", default=os.path.join(os.path.dirname(__file__), "..", "scenes", "fluid", "*.xml"))
    args = ap.parse_args()
    work = args.work or tempfile.mkdtemp(prefix="kelvin-compare-")
    diffs = []
    runs = 0
    for scene in sorted(glob.glob(args.scenes)):
        name = os.path.splitext(os.path.basename(scene))[0]
        solvers = SOLVERS if 'name="solver"' in open(scene).read() else [None]
        for solver in solvers:
            tag = name + ("-" + solver if solver else "")
            common = ["-D", "end=0.3", "-D", "every=1", "-D", "spp=4", "-q", "-t", "2", "--seed", "3", "-D",
                      "res=10" if name in THREE_D else "res=16"]
            if solver:
                common += ["-D", "solver=" + solver]
            codes = []
            for which, exe in (("old", args.old), ("new", args.new)):
                out = os.path.join(work, which, tag)
                os.makedirs(out, exist_ok=True)
                r = subprocess.run([exe, scene] + common + ["-o", os.path.join(out, "run.exr")],
                                   capture_output=True, text=True, timeout=600)
                codes.append(r.returncode)
            runs += 1
            a, b = os.path.join(work, "old", tag), os.path.join(work, "new", tag)
            if codes[0] != codes[1]:
                diffs.append(f"{tag}: exit codes {codes[0]} and {codes[1]}")
            if files(a) != files(b):
                diffs.append(f"{tag}: different files ({len(files(a))} and {len(files(b))})")
            for rel in set(files(a)) & set(files(b)):
                fa, fb = os.path.join(a, rel), os.path.join(b, rel)
                same = csv_values(fa) == csv_values(fb) if rel.endswith(".csv") else masked(fa) == masked(fb)
                if not same:
                    diffs.append(f"{tag}: {rel} differs")
    for d in diffs:
        print(d)
    print(f"compare_fluid_outputs: {runs} runs in {work}: {'identical' if not diffs else f'{len(diffs)} differences'}")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
