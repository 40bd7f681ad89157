#!/usr/bin/env python3
"""PSSMLT/G's sigma matched to delayed rejection's first-stage acceptance, as the thesis' equal-time protocol does.

    tools/match_gaussian_sigma.py scenes/render/mlt-study.xml -D geometry=door -D res=256 [--spp 2] [-t 2]
                                  [--record FILE]

1. Renders the scene briefly with `variant=drmlt-orbital` (DR with its default stages: kelemen_pair, then the
   orbital move) and reads the acceptance of its small first-stage steps, `mlt.acceptance.stage1_small` (the
   statistic `kelvin` prints at the end of a render; docs/mlt.md "Outputs and statistics").
2. Finds by bisection on log(sigma) the `sigma` of `variant=pssmlt-gaussian` (parts/mlt-pssmlt-gaussian.xml) whose
   small-step acceptance is the same, within --tolerance (default 0.01; the protocol asks for 0.02): first from
   the default 1/64 outwards by factors of 4 until the target is bracketed, then halving the bracket.
   Acceptance falls as sigma grows; each evaluation is a deterministic render (fixed --seed and --spp), so the
   search repeats exactly.

Prints the matched sigma (one number) on stdout, the evaluations on stderr, and with --record writes them to FILE
(`sigma = ...`, `target_acceptance = ...`, then one `sigma acceptance` line per evaluation).
Every -D is passed to both renders (geometry, res, technique, direct_samples, normalization ...).
"""
import argparse
import math
import os
import re
import subprocess
import sys
import tempfile


def acceptance(kelvin, scene, defines, extra, spp, seed, threads):
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [kelvin, scene, "--spp", str(spp), "--seed", str(seed), "-t", str(threads),
               "-o", os.path.join(tmp, "m.exr")]
        for d in defines + extra:
            cmd += ["-D", d]
        r = subprocess.run(cmd, capture_output=True, text=True)
    out = r.stdout + r.stderr
    if r.returncode != 0:
        sys.exit(f"match_gaussian_sigma: {' '.join(cmd)} failed ({r.returncode}):\n{out.strip()}")
    m = re.search(r"mlt\.acceptance\.stage1_small\s+([0-9.eE+-]+)", out)
    if not m:
        sys.exit(f"match_gaussian_sigma: no mlt.acceptance.stage1_small in the output of {' '.join(cmd)}")
    return float(m.group(1))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", help="the study scene (scenes/render/mlt-study.xml: variant and sigma parameters)")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="K=V", help="scene parameter")
    ap.add_argument("--kelvin", default=os.environ.get("KELVIN", "build/bin/kelvin"))
    ap.add_argument("--spp", type=int, default=2, help="mutations per pixel of each render (default 2)")
    ap.add_argument("--seed", type=int, default=7, help="seed of every render (default 7)")
    ap.add_argument("-t", "--threads", type=int, default=0, help="threads (default: all cores)")
    ap.add_argument("--tolerance", type=float, default=0.01, help="|acceptance - target| to stop at (default 0.01)")
    ap.add_argument("--max-evaluations", type=int, default=14)
    ap.add_argument("--reference-variant", default="drmlt-orbital")
    ap.add_argument("--record", help="write the search to this file")
    a = ap.parse_args()
    if any(d.startswith(("variant=", "sigma=")) for d in a.defines):
        sys.exit("match_gaussian_sigma: variant and sigma are set by the tool")

    def run(extra):
        return acceptance(a.kelvin, a.scene, a.defines, extra, a.spp, a.seed, a.threads)

    target = run([f"variant={a.reference_variant}"])
    print(f"{a.reference_variant}: first-stage small-step acceptance {target:.4g}", file=sys.stderr)
    evals = []

    def f(sigma):
        acc = run(["variant=pssmlt-gaussian", f"sigma={sigma:.8g}"])
        evals.append((sigma, acc))
        print(f"  pssmlt-gaussian sigma {sigma:.6g}: acceptance {acc:.4g}", file=sys.stderr)
        return acc

    # Bracket: lo has acceptance above the target, hi below (acceptance falls with sigma).
    s = 1 / 64
    acc = f(s)
    lo = hi = None
    if acc >= target:
        lo = s
        while hi is None and len(evals) < a.max_evaluations and abs(acc - target) > a.tolerance:
            s = min(s * 4, 0.5)
            acc = f(s)
            if acc >= target:
                lo = s
            else:
                hi = s
            if s >= 0.5:
                break
    else:
        hi = s
        while lo is None and len(evals) < a.max_evaluations and abs(acc - target) > a.tolerance:
            s = s / 4
            acc = f(s)
            if acc < target:
                hi = s
            else:
                lo = s
    best = min(evals, key=lambda e: abs(e[1] - target))
    while abs(best[1] - target) > a.tolerance and lo is not None and hi is not None \
            and len(evals) < a.max_evaluations:
        s = math.sqrt(lo * hi)
        acc = f(s)
        if acc >= target:
            lo = s
        else:
            hi = s
        best = min(evals, key=lambda e: abs(e[1] - target))
    sigma, acc = best
    ok = abs(acc - target) <= max(a.tolerance, 0.02)
    print(f"matched sigma {sigma:.6g}: acceptance {acc:.4g} against {target:.4g}"
          + ("" if ok else " (NOT within 0.02: the search ran out of evaluations or bracket)"), file=sys.stderr)
    if a.record:
        with open(a.record, "w") as fh:
            fh.write(f"# tools/match_gaussian_sigma.py {a.scene} {' '.join('-D ' + d for d in a.defines)} "
                     f"--spp {a.spp} --seed {a.seed}\n")
            fh.write(f"sigma = {sigma:.8g}\nacceptance = {acc:.6g}\ntarget_acceptance = {target:.6g}\n"
                     f"reference_variant = {a.reference_variant}\nwithin_tolerance = {ok}\n")
            fh.write("# evaluations: sigma acceptance\n")
            for e in evals:
                fh.write(f"{e[0]:.8g} {e[1]:.6g}\n")
    print(f"{sigma:.8g}")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
