#!/usr/bin/env python3
"""Writes the wavy water surface of the swimming-pool scene (scenes/render/geometry/pool.xml) as a binary PLY.

    python3 tools/make_pool_surface.py scenes/render/meshes            # -> scenes/render/meshes/pool-surface.ply

The surface is the height field y = h(x, z) over the pool's opening, x in [-W/2, W/2], z in [-D/2, D/2]
(metres, y up, still water at y = 0; the scene places it with its transform), sampled on a regular grid and
split into triangles along alternating diagonals. h is a sum of a few sine waves of different directions,
wavelengths (0.35 to 1.1 m) and phases, small enough (steepest slope about 0.2) that the surface focuses light
a metre or so below it: the moving-caustic pattern of a pool floor (specular-diffuse-specular transport when
seen through the surface). Vertex normals are the analytic normals of h, (-dh/dx, 1, -dh/dz) normalised, so
the shading is smooth at any grid resolution. Deterministic: fixed waves, no random numbers; the file is the
same byte for byte on every run.

The PLY holds x, y, z, nx, ny, nz (float32) per vertex and uchar-int index lists; triangles are wound
counter-clockwise seen from above, so the geometric normal points up, into the air (dielectric: int_ior is
the water's, below the surface).
"""
import argparse
import math
import pathlib
import struct

import numpy as np

# (amplitude m, wavelength m, direction in degrees from +x towards +z, phase rad)
WAVES = [
    (0.018, 1.10, 20.0, 0.3),
    (0.012, 0.75, 75.0, 1.7),
    (0.009, 0.55, -35.0, 4.1),
    (0.006, 0.42, 130.0, 2.6),
    (0.004, 0.35, 200.0, 5.2),
]


def height_and_gradient(x, z):
    h = np.zeros_like(x)
    hx = np.zeros_like(x)
    hz = np.zeros_like(x)
    for a, lam, deg, phase in WAVES:
        k = 2 * math.pi / lam
        dx, dz = math.cos(math.radians(deg)), math.sin(math.radians(deg))
        arg = k * (dx * x + dz * z) + phase
        h += a * np.sin(arg)
        c = a * k * np.cos(arg)
        hx += c * dx
        hz += c * dz
    return h, hx, hz


def build(width, depth, spacing):
    nx = int(round(width / spacing)) + 1
    nz = int(round(depth / spacing)) + 1
    xs = np.linspace(-width / 2, width / 2, nx)
    zs = np.linspace(-depth / 2, depth / 2, nz)
    x, z = np.meshgrid(xs, zs, indexing="xy")  # shape (nz, nx): row = z, column = x
    h, hx, hz = height_and_gradient(x, z)
    n = np.stack([-hx, np.ones_like(h), -hz], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    verts = np.concatenate([np.stack([x, h, z], axis=-1), n], axis=-1).reshape(-1, 6).astype("<f4")
    faces = []
    for j in range(nz - 1):
        for i in range(nx - 1):
            a = j * nx + i  # (x_i, z_j)
            b = a + 1  # (x_i+1, z_j)
            c = a + nx  # (x_i, z_j+1)
            d = c + 1
            # Seen from above (+y) with x right and z down the page, (a, c, b) is counter-clockwise about +y:
            # (c - a) x (b - a) = (+z) x (+x) = +y.
            if (i + j) % 2 == 0:
                faces += [(a, c, b), (b, c, d)]
            else:
                faces += [(a, c, d), (a, d, b)]
    return verts, np.array(faces, dtype="<i4"), h


def write_ply(path, verts, faces):
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        "comment swimming-pool water surface, tools/make_pool_surface.py\n"
        f"element vertex {len(verts)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\n"
        f"element face {len(faces)}\n"
        "property list uchar int vertex_indices\nend_header\n"
    )
    face_rec = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face_rec["n"] = 3
    face_rec["i"] = faces
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(verts.tobytes())
        f.write(face_rec.tobytes())


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("outdir", type=pathlib.Path, help="directory for pool-surface.ply")
    ap.add_argument("--width", type=float, default=3.0, help="extent in x (m), default 3")
    ap.add_argument("--depth", type=float, default=4.0, help="extent in z (m), default 4")
    ap.add_argument("--spacing", type=float, default=0.04, help="grid spacing (m), default 0.04")
    a = ap.parse_args()
    verts, faces, h = build(a.width, a.depth, a.spacing)
    a.outdir.mkdir(parents=True, exist_ok=True)
    out = a.outdir / "pool-surface.ply"
    write_ply(out, verts, faces)
    slope = np.degrees(np.arccos(verts[:, 4].min()))
    print(f"{out}: {len(verts)} vertices, {len(faces)} triangles, height in [{h.min():.4f}, {h.max():.4f}] m, "
          f"steepest normal tilt {slope:.1f} deg, {out.stat().st_size} bytes")


if __name__ == "__main__":
    main()
