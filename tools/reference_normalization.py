#!/usr/bin/env python3
"""The normalisation b of pssmlt / drmlt (`normalization`, thesis Sec. 4.3.3) from a reference image.

    tools/reference_normalization.py REF.exr                         # direct_samples = -1: the chains render everything
    tools/reference_normalization.py REF.exr --direct DIRECT.exr     # direct_samples > 0: b of the chains' part only
    tools/reference_normalization.py REF.exr --direct DIRECT.exr -v  # the terms, on stderr
    tools/reference_normalization.py WIDE.exr --margin 4 [--direct WIDE-DIRECT.exr]  # references that cover the margin

Prints b (one number) on stdout: give it to the integrator as `normalization`.

What b is (src/mlt/integrator.cpp, docs/mlt.md "The estimator"): the chains' film position is uniform over the
image grown by the reconstruction filter's radius r on every side, the domain D = [-r, w + r] x [-r, h + r] in
pixel units, and a state's camera contribution is multiplied by the area |D|. So b = E[pi] = the integral over D of
the luminance of the radiance that reaches the film, L(p) (pixel units: a pixel has area 1). The image the
integrator develops is I_j = integral of f(p - c_j) L(p) dp (f: the normalised filter, c_j: pixel j's centre), which
is also what the pixel loop's filter importance sampling gives a reference render. Hence, with
W(p) = sum_j f(p - c_j) (1 inside the image away from its border; less in the margin and along the border),

    b = sum_j lum(I_j)  +  integral over D of L(p) (1 - W(p)) dp.

The first term is the reference's luminance summed over its pixels. The second, the margin term, needs L outside
the image, which the reference does not have: it is estimated with L constant over each pixel cell, continued
beyond the image by the nearest border pixel (the filter is separable, so it is a sum of products of 1D
integrals, computed exactly from the filter's CDF). For the default Gaussian (stddev 0.5, r = 2) the margin term
is 4 * 2 / w of b or so (8 % at 64 x 64, 3 % at 256 x 256), and the extrapolation can miss a good part of it
where the image changes at its border (measured: +1.8 % on the door's direct light at 64 x 64).

Exact alternative, --margin M: the reference is rendered wider, M more pixels on every side with the field of
view widened to match (tan(fov'/2) = tan(fov/2) (w + 2M) / w; the inner w x h pixels are then those of the
ordinary render), so it sees the margin. With M >= 2r, b = the sum over the wide image's pixel cells of
lum(I') times the cell's area inside D: the wide image's own border deficit lies outside D, and what remains is
the filter's blur across D's edge (second order). tools/convergence_reports.sh renders its references so, with
M = 4, and crops the inner image for the error measurements.

With direct_samples > 0 the integrator renders direct light (paths of 1 and 2 edges: emitters seen directly and
one bounce, `path` with max_depth 2) apart and its chains cover paths of 3 or more edges only; b is then the
integral of the chains' part: b(full reference) - b(direct-only reference), the latter from a `path` render with
max_depth = 2 of the same scene (--direct). Both integrals use the same margin estimate.

Luminance: Y = 0.212671 R + 0.715160 G + 0.072169 B (kelvin::luminance). Images are read through OpenImageIO's
Python module (Debian: python3-openimageio, installed by tools/setup.sh), in full float precision.
"""
import argparse
import math
import os
import pathlib
import sys

import numpy as np

LUM = np.array([0.212671, 0.715160, 0.072169])


def read_rgb(path):
    """float64 array (h, w, 3) of R, G, B, top row first, read in full float precision by OpenImageIO's Python
    module (Debian: python3-openimageio, installed by tools/setup.sh); an image with fewer than three channels, or
    without R, G, B among more (a drmlt image has stage channels too), is refused."""
    try:
        import OpenImageIO as oiio
    except ImportError:
        sys.exit("reference_normalization: the OpenImageIO Python module is missing (Debian: python3-openimageio)")
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        sys.exit(f"reference_normalization: could not read {path}: {oiio.geterror().strip()}")
    try:
        spec = inp.spec()
        names = list(spec.channelnames)
        pixels = inp.read_image(0, 0, 0, spec.nchannels, "float")
    finally:
        inp.close()
    if pixels is None:
        sys.exit(f"reference_normalization: could not read {path}: {oiio.geterror().strip()}")
    pixels = np.asarray(pixels, dtype=np.float64).reshape(spec.height, spec.width, spec.nchannels)
    if all(c in names for c in ("R", "G", "B")):
        idx = [names.index(c) for c in ("R", "G", "B")]
    elif spec.nchannels >= 3:
        idx = [0, 1, 2]
    else:
        sys.exit(f"reference_normalization: {path}: {spec.nchannels} channel(s), not R, G, B")
    return pixels[:, :, idx]


class Filter1D:
    """One axis of a separable reconstruction filter, normalised: radius and CDF."""

    def __init__(self, kind, param):
        self.kind = kind
        if kind == "gaussian":
            self.sigma = param
            self.radius = 4 * param
            self.erf_r = math.erf(self.radius / (param * math.sqrt(2)))
        elif kind == "box":
            self.radius = param
        else:
            raise ValueError(kind)

    def cdf(self, x):
        x = np.clip(x, -self.radius, self.radius)
        if self.kind == "box":
            return (x + self.radius) / (2 * self.radius)
        from math import erf
        v = np.vectorize(lambda t: erf(t / (self.sigma * math.sqrt(2))))(x)
        return 0.5 + 0.5 * v / self.erf_r


def axis_weights(n, filt):
    """Cells of one axis of the domain [-r, n + r]: pixel columns -m .. n-1+m (m = ceil(r)), clipped to the
    domain. Returns (length of each cell, integral over each cell of W1(x) = sum over the n pixels of f(x - c))."""
    r = filt.radius
    m = int(math.ceil(r - 1e-12))
    idx = np.arange(-m, n + m)
    lo = np.maximum(idx, -r)
    hi = np.minimum(idx + 1, n + r)
    length = np.maximum(hi - lo, 0.0)
    centres = np.arange(n) + 0.5
    # integral over [lo, hi] of f(x - c) = F(hi - c) - F(lo - c), summed over the pixel centres c
    a = (filt.cdf(hi[:, None] - centres[None, :]) - filt.cdf(lo[:, None] - centres[None, :])).sum(axis=1)
    return m, length, a


def integrate(img, filt):
    """(b, pixel sum, margin term) of an RGB image."""
    lum = img @ LUM
    h, w = lum.shape
    mx, lx, ax = axis_weights(w, filt)
    my, ly, ay = axis_weights(h, filt)
    assert mx == my
    ext = np.pad(lum, mx, mode="edge")  # L continued beyond the border by the nearest pixel
    total = float(ly @ ext @ lx)  # integral over D of L (cellwise constant)
    covered = float(ay @ ext @ ax)  # integral over D of L W (same approximation)
    pixel_sum = float(lum.sum())
    margin = total - covered
    return pixel_sum + margin, pixel_sum, margin


def integrate_wide(img, filt, margin):
    """(b, pixel sum of the inner image, margin term) of a reference with `margin` extra pixels on every side."""
    lum = img @ LUM
    H, W = lum.shape
    r = filt.radius

    def cover(n):  # area of each cell of the wide axis inside D = [margin - r, n - margin + r]
        idx = np.arange(n)
        return np.clip(np.minimum(idx + 1, n - margin + r) - np.maximum(idx, margin - r), 0, 1)

    b = float(cover(H) @ lum @ cover(W))
    inner = float(lum[margin:H - margin, margin:W - margin].sum())
    return b, inner, b - inner


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("reference", type=pathlib.Path, help="the full reference (EXR or PFM, R, G, B)")
    ap.add_argument("--direct", type=pathlib.Path,
                    help="a direct-only reference (path, max_depth 2) of the same scene: b of the chains' part "
                         "(direct_samples > 0)")
    ap.add_argument("--filter", choices=["gaussian", "box"], default="gaussian",
                    help="the film's reconstruction filter (default gaussian, hdrfilm's default)")
    ap.add_argument("--stddev", type=float, default=0.5, help="gaussian stddev in pixels (default 0.5)")
    ap.add_argument("--radius", type=float, default=0.5, help="box radius in pixels (default 0.5)")
    ap.add_argument("--margin", type=int, default=0,
                    help="the references have this many extra pixels on every side (rendered with a widened field "
                         "of view); at least 2 x the filter radius (4 for the default Gaussian)")
    ap.add_argument("-v", "--verbose", action="store_true", help="print the terms on stderr")
    a = ap.parse_args()
    filt = Filter1D(a.filter, a.stddev if a.filter == "gaussian" else a.radius)

    if a.margin and a.margin < 2 * filt.radius:
        sys.exit(f"reference_normalization: --margin {a.margin} is below 2 x the filter radius ({2 * filt.radius:g})")

    def integral(img):
        return integrate_wide(img, filt, a.margin) if a.margin else integrate(img, filt)

    full = read_rgb(a.reference)
    if not np.all(np.isfinite(full)):
        sys.exit(f"reference_normalization: {a.reference} has non-finite pixels")
    b, s, m = integral(full)
    if a.verbose:
        h, w, _ = full.shape
        print(f"{a.reference}: {w} x {h} (margin {a.margin}), filter {a.filter} radius {filt.radius:g}: pixel sum {s:.6g} + margin "
              f"{m:.6g} ({100 * m / b if b else 0:.2f} %) = {b:.6g}", file=sys.stderr)
    if a.direct:
        d = read_rgb(a.direct)
        if d.shape != full.shape:
            sys.exit(f"reference_normalization: {a.direct} is {d.shape[1]} x {d.shape[0]}, "
                     f"{a.reference} is {full.shape[1]} x {full.shape[0]}")
        bd, sd, md = integral(d)
        if a.verbose:
            print(f"{a.direct}: direct only: pixel sum {sd:.6g} + margin {md:.6g} = {bd:.6g}; "
                  f"chains' part {b - bd:.6g} ({100 * (b - bd) / b if b else 0:.1f} % of the full integral)",
                  file=sys.stderr)
        b -= bd
    if not b > 0:
        sys.exit(f"reference_normalization: the integral is {b:g}, not positive (no light for the chains?)")
    print(f"{b:.9g}")


if __name__ == "__main__":
    main()
