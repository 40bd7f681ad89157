"""Synthetic images of known truth for the tests of the study tools (test_reference_floor.py, test_run_spread.py)."""
import importlib.util
import os
import sys

import numpy as np


def test_arguments(name):
    """(SCRIPT, OUTDIR) from the command line, OUTDIR created; exits 0 with "SKIPPED" (ctest's skip) without
    OpenImageIO's Python module, which the tools read images with."""
    if len(sys.argv) != 3:
        sys.exit(f"usage: {name}.py SCRIPT OUTDIR")
    if importlib.util.find_spec("OpenImageIO") is None:
        print(f"{name}: SKIPPED (no OpenImageIO Python module: python3-openimageio)")
        sys.exit(0)
    os.makedirs(sys.argv[2], exist_ok=True)
    return sys.argv[1], sys.argv[2]


def write_pfm(path, img):
    """An (h, w, 3) array, top row first, as a little-endian PFM (OpenImageIO reads it)."""
    h, w, _ = img.shape
    with open(path, "wb") as f:
        f.write(b"PF\n%d %d\n-1.0\n" % (w, h))
        f.write(np.ascontiguousarray(img[::-1], dtype="<f4").tobytes())  # PFM rows run bottom to top


def true_image(h, w, cx, cy, spread):
    """A smooth true image: a Gaussian highlight at (cx, cy) of squared width `spread` over a dim colour ramp, then
    a band 50x brighter (a highlight, from 3/4 of the width) and a band of exact black (from 7/8: both renders 0)."""
    y, x = np.mgrid[0:h, 0:w]
    t = np.stack([0.05 + 2.0 * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / spread) + 0.3 * (x / w) * c
                  for c in (1, 0.8, 0.5)], axis=2)
    t[:, 3 * w // 4:7 * w // 8] *= 50.0
    t[:, 7 * w // 8:] = 0.0
    return t
