#!/usr/bin/env python3
"""Writes the meshes of the two H2MC study scenes (docs/studies/mlt.md, "Results: cheap then expensive at equal time"):
the rough torus (scenes/render/geometry/torus.xml) and the chess board (scenes/render/geometry/chess.xml).

    python3 tools/make_h2mc_meshes.py scenes/render/meshes        # -> torus.ply, chess-*.ply there

Files (binary little-endian PLY, float32 positions, uchar-int index lists, triangles wound counter-clockwise
seen from outside, so the geometric normal points out of every closed surface):

- `torus.ply`: the ring torus ((R + r cos v) cos u, r sin v, (R + r cos v) sin u) with R = 1, r = 0.3 (axis
  +y, centred at the origin), 64 x 32 quads split into 4 096 triangles; analytic vertex normals
  (cos v cos u, sin v, cos v sin u), so the rough glass is smooth at this tessellation.
- `chess-pawn.ply`, `chess-rook.ply`, `chess-bishop.ply`: surfaces of revolution about +y of piecewise profiles
  (r, y) in units of a board square (the base sits on y = 0, radius 0.36-0.38; heights 0.97, 1.0 and 1.38);
  48 angular steps. Each profile is a list of smooth pieces: vertex normals are the normals of the revolved
  profile, continuous inside a piece and split where two pieces meet (a crease: the vertex is written once per
  piece, at the same position, so the surface stays closed for the glass pieces). Where a profile reaches the
  axis the piece ends in one pole vertex and a fan of triangles.
- `chess-light.ply`, `chess-dark.ply`: the 32 light and the 32 dark squares of an 8 x 8 board of unit squares,
  x and z in [-4, 4], at y = 0, facing +y; two triangles per square, no vertex normals (flat). Two meshes, so
  each has one constant diffuse reflectance (a textured reflectance is outside H2MC's differentiable set).

Deterministic: no random numbers; the files are the same byte for byte on every run.
"""
import argparse
import math
import pathlib

import numpy as np


def write_ply(path, verts, faces, normals=None, comment=""):
    props = "property float x\nproperty float y\nproperty float z\n"
    data = np.asarray(verts, dtype="<f4")
    if normals is not None:
        props += "property float nx\nproperty float ny\nproperty float nz\n"
        data = np.concatenate([data, np.asarray(normals, dtype="<f4")], axis=1)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"comment {comment}, tools/make_h2mc_meshes.py\n"
        f"element vertex {len(data)}\n{props}"
        f"element face {len(faces)}\n"
        "property list uchar int vertex_indices\nend_header\n"
    )
    rec = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rec["n"] = 3
    rec["i"] = faces
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(np.ascontiguousarray(data).tobytes())
        f.write(rec.tobytes())


def orient(verts, faces, normals):
    """Winds every triangle so that its geometric normal agrees with its vertex normals (outward)."""
    faces = np.asarray(faces, dtype=np.int64)
    p = verts[faces]
    g = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    area = np.linalg.norm(g, axis=1)
    assert area.min() > 1e-12, "degenerate triangle"
    flip = np.einsum("ij,ij->i", g, normals[faces].sum(axis=1)) < 0
    faces[flip] = faces[flip][:, ::-1]
    return faces


def torus(R=1.0, r=0.3, nu=64, nv=32):
    u = 2 * math.pi * np.arange(nu) / nu
    v = 2 * math.pi * np.arange(nv) / nv
    U, V = np.meshgrid(u, v, indexing="ij")  # (nu, nv)
    n = np.stack([np.cos(V) * np.cos(U), np.sin(V), np.cos(V) * np.sin(U)], axis=-1).reshape(-1, 3)
    c = np.stack([R * np.cos(U), np.zeros_like(U), R * np.sin(U)], axis=-1).reshape(-1, 3)
    verts = c + r * n
    faces = []
    for i in range(nu):
        for j in range(nv):
            a, b = i * nv + j, ((i + 1) % nu) * nv + j
            c_, d = i * nv + (j + 1) % nv, ((i + 1) % nu) * nv + (j + 1) % nv
            faces += [(a, b, d), (a, d, c_)]
    return verts, orient(verts, faces, n), n


def arc(cr, cy, rad, a0, a1, k):
    """k + 1 points of the circle of centre (cr, cy) and radius rad in the profile plane, angles a0 to a1 (deg)."""
    t = np.radians(np.linspace(a0, a1, k + 1))
    return [(cr + rad * math.cos(x), cy + rad * math.sin(x)) for x in t]


def line(p0, p1, k=1):
    return [(p0[0] + (p1[0] - p0[0]) * s, p0[1] + (p1[1] - p0[1]) * s) for s in np.linspace(0, 1, k + 1)]


def smooth(*parts):
    """Concatenates point lists into one smooth piece (a shared end point is kept once)."""
    out = []
    for p in parts:
        for q in p:
            if not out or np.hypot(out[-1][0] - q[0], out[-1][1] - q[1]) > 1e-9:
                out.append(q)
    return out


def base(rb, h):
    """The foot shared by the pieces: a flat bottom disc, a short vertical rim and a rounded (torus) edge."""
    return [
        line((0.0, 0.0), (rb, 0.0)),
        line((rb, 0.0), (rb, 0.05)),
        arc(rb - h, 0.05, h, 0, 90, 6),
    ]


def neck(p0, rmin, ymin, k):
    """A concave arc from p0 (below) to the narrowest point (rmin, ymin), where it is vertical."""
    dr, dy = p0[0] - rmin, ymin - p0[1]
    rad = (dr * dr + dy * dy) / (2 * dr)  # circle of centre (rmin + rad, ymin) through p0
    a0 = math.degrees(math.atan2(p0[1] - ymin, p0[0] - rmin - rad))
    return arc(rmin + rad, ymin, rad, a0 % 360, 180, k)


def cap(cy, rad, r0, k):
    """A ball of centre (0, cy) and radius rad from where its radius is r0 (below the equator) to the axis."""
    a0 = -math.degrees(math.acos(r0 / rad))
    return arc(0.0, cy, rad, a0, 90, k)


def pawn():
    head = cap(0.79, 0.175, 0.11, 16)
    return base(0.36, 0.06) + [
        smooth(line((0.30, 0.11), (0.20, 0.16), 2), neck((0.20, 0.16), 0.09, 0.40, 8),
               line((0.09, 0.40), (0.10, 0.52), 2)),
        line((0.10, 0.52), (0.21, 0.55)),
        arc(0.21, 0.575, 0.025, -90, 90, 6),
        line((0.21, 0.60), head[0]),
        head,
    ]


def rook():
    flare = neck((0.29, 0.80), 0.20, 0.62, 6)[::-1]  # from the narrow body out to the top's rim
    return base(0.38, 0.06) + [
        smooth(line((0.32, 0.11), (0.22, 0.20), 2), line((0.22, 0.20), (0.20, 0.62), 6), flare),
        line((0.29, 0.80), (0.29, 1.0), 2),
        line((0.29, 1.0), (0.21, 1.0)),
        line((0.21, 1.0), (0.21, 0.92)),
        line((0.21, 0.92), (0.0, 0.92)),
    ]


def bishop():
    ball = cap(1.315, 0.065, 0.025, 10)
    # the mitre: an egg from r = 0.10 bulging to about 0.18 and closing to r = 0.025 at y = 1.22
    mitre = [(0.10 + 0.09 * math.sin(math.pi * s) ** 0.8 - 0.075 * s ** 2, 0.81 + 0.41 * s)
             for s in np.linspace(0, 1, 13)]
    return base(0.37, 0.06) + [
        smooth(line((0.31, 0.11), (0.19, 0.18), 2), neck((0.19, 0.18), 0.06, 0.52, 6),
               line((0.06, 0.52), (0.08, 0.72), 3)),
        line((0.08, 0.72), (0.20, 0.75)),
        arc(0.20, 0.77, 0.02, -90, 90, 5),
        line((0.20, 0.79), (0.10, 0.81)),
        mitre,
        line(mitre[-1], ball[0]),
        ball,
    ]


# Profiles, from the centre of the bottom up to the axis at the top; each inner list is one smooth piece.
PROFILES = {"pawn": pawn(), "rook": rook(), "bishop": bishop()}


def revolve(profile, n=48):
    """Surface of revolution of the pieces of `profile` about +y, n angular steps; outward vertex normals."""
    phi = 2 * math.pi * np.arange(n) / n
    cphi, sphi = np.cos(phi), np.sin(phi)
    verts, norms, faces = [], [], []

    def ring(r, y, nr, ny):
        base_i = len(verts)
        if r < 1e-9:  # a pole: one vertex, normal along the axis
            verts.append((0.0, y, 0.0))
            norms.append((0.0, math.copysign(1.0, ny), 0.0))
            return [base_i] * n
        for c, s in zip(cphi, sphi):
            verts.append((r * c, y, r * s))
            norms.append((nr * c, ny, nr * s))
        return list(range(base_i, base_i + n))

    for prev, piece in zip([None] + profile[:-1], profile):
        if prev is not None:  # pieces meet (a crease): the surface stays closed
            assert np.allclose(prev[-1], piece[0], atol=1e-9), (prev[-1], piece[0])
        p = np.asarray(piece, dtype=float)
        assert len(p) >= 2
        t = np.gradient(p, axis=0)  # tangent (dr, dy) along the profile
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        nrm = np.stack([t[:, 1], -t[:, 0]], axis=1)  # outward when the profile runs bottom -> top
        rings = [ring(r, y, nr, ny) for (r, y), (nr, ny) in zip(p, nrm)]
        for a, b in zip(rings[:-1], rings[1:]):
            for j in range(n):
                j1 = (j + 1) % n
                q = [(a[j], a[j1], b[j1]), (a[j], b[j1], b[j])]
                for tri in q:
                    if len(set(tri)) == 3:
                        faces.append(tri)
    verts, norms = np.asarray(verts), np.asarray(norms)
    return verts, orient(verts, faces, norms), norms


def board(dark):
    verts, faces = [], []
    for i in range(8):
        for k in range(8):
            if ((i + k) % 2 == 0) != dark:
                continue
            x0, z0 = i - 4.0, k - 4.0
            b = len(verts)
            verts += [(x0, 0.0, z0), (x0 + 1, 0.0, z0), (x0 + 1, 0.0, z0 + 1), (x0, 0.0, z0 + 1)]
            # counter-clockwise seen from +y: (x0,z0) -> (x0,z0+1) -> (x0+1,z0+1)
            faces += [(b, b + 3, b + 2), (b, b + 2, b + 1)]
    verts = np.asarray(verts)
    return verts, orient(verts, faces, np.tile([0.0, 1.0, 0.0], (len(verts), 1)))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("outdir", type=pathlib.Path, help="directory for the PLY files")
    a = ap.parse_args()
    a.outdir.mkdir(parents=True, exist_ok=True)
    out = []
    v, f, n = torus()
    out.append(("torus.ply", v, f, n, "ring torus R 1 r 0.3"))
    for name, prof in PROFILES.items():
        v, f, n = revolve(prof)
        out.append((f"chess-{name}.ply", v, f, n, f"chess {name}, surface of revolution"))
    for dark in (False, True):
        v, f = board(dark)
        out.append((f"chess-{'dark' if dark else 'light'}.ply", v, f, None,
                    f"chess board, {'dark' if dark else 'light'} squares"))
    for name, v, f, n, comment in out:
        p = a.outdir / name
        write_ply(p, v, f, n, comment)
        lo, hi = v.min(axis=0), v.max(axis=0)
        print(f"{p}: {len(v)} vertices, {len(f)} triangles, bounds {np.round(lo, 3)} .. {np.round(hi, 3)}, "
              f"{p.stat().st_size} bytes")


if __name__ == "__main__":
    main()
