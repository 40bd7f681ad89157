#!/usr/bin/python3
"""tools/reference_floor.py against a known answer (ctest: converge.reference_floor).

    test_reference_floor.py SCRIPT OUTDIR

A true image T (smooth, with dark and bright regions) and per-pixel noise levels are drawn with a fixed seed; two
halves A and B (T plus Gaussian noise of standard deviation s) and, for --spp, a reference R of 4x less variance
and an independent render of the given variance. The tool's floor must match the exact expectation of what a
noisy reference adds, E[(R - T)^2] / (R^2 + 0.01) averaged over pixels and channels, computed here from the known
T over 12 independent draws of the noise: within 5 standard errors of the per-draw spread plus 1 %, the estimate's
own bias for the relative MSE at this noise level (its denominator holds the noisy reference, docs/studies/mlt.md;
-0.8 % for the halves and -0.2 % with --spp over 400 draws). The image has a band 50x brighter and a band of exact
black. A floor off by a factor 2 (the halves' variance instead of their mean's) fails by far. Skipped (exit 0, "SKIPPED") without OpenImageIO's Python module.
"""
import os
import subprocess
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from synthetic_images import test_arguments, true_image, write_pfm  # noqa: E402


def floor_of(script, a, b, extra, out):
    pa, pb = os.path.join(out, "a.pfm"), os.path.join(out, "b.pfm")
    write_pfm(pa, a)
    write_pfm(pb, b)
    r = subprocess.run([sys.executable, script, pa, pb, "--margin", "2"] + extra, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"reference_floor.py failed: {r.stderr}")
    return float(r.stdout.split("floor_rel_mse =")[1].split()[0])


def main():
    script, out = test_arguments("test_reference_floor")
    rng = np.random.default_rng(12)
    t = true_image(64, 80, 30, 15, 60.0)  # with a band 50x brighter and one of exact black
    s = np.where(t > 0, 0.01 + 0.03 * t, 0.0)  # per-pixel standard deviation of one half, small against T
    inner = (slice(2, -2), slice(2, -2))
    failures = []
    for mode in ("halves", "spp"):
        est, tru = [], []
        for _ in range(12):
            if mode == "halves":
                a = t + s * rng.standard_normal(t.shape)
                b = t + s * rng.standard_normal(t.shape)
                r, extra = 0.5 * (a + b), []
            else:  # the reference A of 8192 spp, B an independent render of 2048 spp (4x the variance)
                a = t + 0.5 * s * rng.standard_normal(t.shape)
                b = t + s * rng.standard_normal(t.shape)
                r, extra = a, ["--spp", "8192", "2048"]
            est.append(floor_of(script, a.astype(np.float32), b.astype(np.float32), extra, out))
            ri, ti = r[inner].astype(np.float32).astype(float), t[inner]
            tru.append(((ri - ti) ** 2 / (ri * ri + 0.01)).mean())
        est, tru = np.array(est), np.array(tru)
        d = est - tru
        tol = 5 * d.std(ddof=1) / np.sqrt(len(d)) + 0.01 * tru.mean()
        print(f"{mode}: floor estimate {est.mean():.6g}, true {tru.mean():.6g}, difference {d.mean():.3g} "
              f"(tolerance {tol:.3g})")
        if abs(d.mean()) > tol:
            failures.append(mode)
    if failures:
        sys.exit(f"test_reference_floor: the floor is wrong for {', '.join(failures)}")
    print("test_reference_floor: passed")


if __name__ == "__main__":
    main()
