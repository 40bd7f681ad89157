#!/usr/bin/python3
"""The error a noisy reference adds to every variant of a study (docs/studies/mlt.md), from its two halves.

    tools/reference_floor.py HALF_A.exr HALF_B.exr [--margin M] [--eps 0.01]
    tools/reference_floor.py REF.exr OTHER.exr --spp N_REF N_OTHER [--margin M]   # REF itself is the reference

A study's reference R is the mean of two independent renders A and B of the same spp (different seeds). A run X
is measured against R, and since X's error and R's error are independent,

    E[(X - R)^2] = E[(X - T)^2] + E[(R - T)^2]          (T: the true image)

so every variant's measured relative MSE carries the same additive floor E[(R - T)^2] / (R^2 + eps). With
E[(A - B)^2] = 2 Var(half) and Var(R) = Var(half) / 2, that floor is E[(A - B)^2] / 4, estimated pixel by pixel
and averaged like `kelvin converge`'s relative MSE (include/kelvin/core/metrics.h: 1/(NC) sum (x - r)^2 /
(r^2 + eps), eps = 0.01, r the reference R = (A + B) / 2). Subtracted from a measured median it gives the run's own
error; ratios between variants measured against a noisy reference are pulled towards 1 by it.

With --spp the reference is A itself (a study rendered with a single reference) and B an independent render of
the same view at N_OTHER spp: A's and B's variances are in the ratio N_OTHER : N_REF, so E[(A - B)^2] =
Var(A) (1 + N_REF / N_OTHER) and the floor is E[(A - B)^2] N_OTHER / (N_REF + N_OTHER) / (A^2 + eps).

--margin M crops M pixels from every side first (the study's wide references). Prints `floor_rel_mse = F`, its
standard error over pixels (`floor_rel_mse_se`) and the number of pixels.
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from reference_normalization import read_rgb  # noqa: E402


def fail(msg):
    print(f"reference_floor: {msg}", file=sys.stderr)
    sys.exit(2)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--margin", type=int, default=0)
    ap.add_argument("--eps", type=float, default=1e-2)
    ap.add_argument("--spp", type=float, nargs=2, metavar=("N_REF", "N_OTHER"),
                    help="the reference is A (N_REF spp); B is an independent render of N_OTHER spp")
    args = ap.parse_args()
    images = []
    for path in (args.a, args.b):
        try:
            images.append(read_rgb(path))
        except SystemExit as e:  # read_rgb's one-line message, under this tool's name and bad input's exit code
            fail(str(e.code).replace("reference_normalization: ", "").splitlines()[0])
    a, b = images
    if a.shape != b.shape:
        fail(f"{args.a} is {a.shape[1]}x{a.shape[0]} but {args.b} is {b.shape[1]}x{b.shape[0]}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        fail(f"{args.a} or {args.b} holds NaN or infinite pixels")
    m = args.margin
    if m > 0:
        if 2 * m >= min(a.shape[0], a.shape[1]):
            fail(f"--margin {m} leaves no pixel of a {a.shape[1]}x{a.shape[0]} image")
        a, b = a[m:-m, m:-m], b[m:-m, m:-m]
    if args.spp:
        na, nb = args.spp
        if not (na > 0 and nb > 0):
            fail(f"--spp {na:g} {nb:g}: both must be positive")
        r, share = a, nb / (na + nb)  # Var(A) / (Var(A) + Var(B))
    else:
        r, share = 0.5 * (a + b), 0.25  # Var(mean of halves) = E[(A - B)^2] / 4
    per_pixel = ((a - b) ** 2 * share / (r * r + args.eps)).mean(axis=2).ravel()
    floor = per_pixel.mean()
    se = per_pixel.std(ddof=1) / np.sqrt(per_pixel.size)
    print(f"floor_rel_mse = {floor:.6g}")
    print(f"floor_rel_mse_se = {se:.3g}")
    print(f"pixels = {per_pixel.size}")


if __name__ == "__main__":
    main()
