#!/usr/bin/env python3
"""Writes the boundary assets of the fluid boundary scenes (pure Python, no dependencies):

  scenes/fluid/meshes/bunny_outline.obj   a closed bunny-shaped outline ('v'/'l' polyline, 2D) for
                                          scenes/fluid/bunny.xml: the zero contour (marching squares on a
                                          400^2 lattice) of the union of ellipses (body, head, ears, tail, feet)
  scenes/fluid/meshes/soup.obj            a triangle soup for scenes/fluid/soup_obstacle.xml: a ring of
                                          triangles with two triangles missing (holes into a pocket), every
                                          fourth triangle duplicated, and a stray sliver triangle
  scenes/fluid/meshes/bunny3d.obj         a closed, consistently oriented bunny-shaped surface for
                                          scenes/fluid/bunny3d.xml: the zero level set of a union of ellipsoids
                                          (body, head, ears, tail, feet) by marching tetrahedra on a 40^3
                                          lattice (Freudenthal split of each cube: conforming, so the surface is
                                          a closed 2-manifold)
  scenes/fluid/meshes/bunny3d_soup.obj    the same triangles as a soup for scenes/fluid/bunny3d_soup.xml: 12
                                          triangles removed (holes), every 9th duplicated, in shuffled order

    python3 tools/make_fluid_boundaries.py
"""
import math
import os

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "..", "scenes", "fluid", "meshes")

# (centre x, centre y, radius x, radius y, rotation) in a [-1, 1]^2 frame
BUNNY = [
    (-0.05, -0.30, 0.55, 0.40, 0.15),   # body
    (0.38, 0.12, 0.27, 0.25, 0.0),      # head
    (0.27, 0.55, 0.08, 0.30, 0.25),     # back ear
    (0.48, 0.52, 0.08, 0.28, -0.30),    # front ear
    (-0.60, -0.20, 0.13, 0.13, 0.0),    # tail
    (0.28, -0.66, 0.26, 0.08, 0.0),     # front foot
]


def bunny(x, y):
    """Approximate signed distance (negative inside) of the union of ellipses."""
    best = 1e9
    for cx, cy, rx, ry, a in BUNNY:
        dx, dy = x - cx, y - cy
        c, s = math.cos(a), math.sin(a)
        u, v = c * dx + s * dy, -s * dx + c * dy
        k = math.hypot(u / rx, v / ry)
        best = min(best, (k - 1) * min(rx, ry))
    return best


def contour(f, lo, hi, n):
    h = (hi - lo) / n
    vals = [[f(lo + i * h, lo + j * h) for i in range(n + 1)] for j in range(n + 1)]
    segs = []
    for j in range(n):
        for i in range(n):
            corners = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)]
            fv = [vals[b][a] for a, b in corners]
            pts = []
            for k in range(4):
                l = (k + 1) % 4
                if (fv[k] < 0) != (fv[l] < 0):
                    t = fv[k] / (fv[k] - fv[l])
                    (ax, ay), (bx, by) = corners[k], corners[l]
                    pts.append((lo + (ax + t * (bx - ax)) * h, lo + (ay + t * (by - ay)) * h))
            if len(pts) == 2:
                segs.append((pts[0], pts[1]))
            elif len(pts) == 4:
                segs.append((pts[0], pts[1]))
                segs.append((pts[2], pts[3]))
    # Chain the segments into loops by their (rounded) end points.
    key = lambda p: (round(p[0], 9), round(p[1], 9))
    adj = {}
    for a, b in segs:
        adj.setdefault(key(a), []).append(b)
        adj.setdefault(key(b), []).append(a)
    seen, loops = set(), []
    for a, b in segs:
        if key(a) in seen:
            continue
        loop, prev, cur = [a], None, a
        while True:
            seen.add(key(cur))
            nxt = [p for p in adj[key(cur)] if prev is None or key(p) != key(prev)]
            nxt = [p for p in nxt if key(p) not in seen] or nxt
            if not nxt or key(nxt[0]) == key(loop[0]) or key(nxt[0]) in seen:
                break
            prev, cur = cur, nxt[0]
            loop.append(cur)
        loops.append(loop)
    return max(loops, key=len)


def write_bunny():
    loop = contour(bunny, -1.0, 1.0, 400)
    with open(os.path.join(OUT, "bunny_outline.obj"), "w") as f:
        f.write("# Bunny-shaped closed outline (tools/make_fluid_boundaries.py), %d points\n" % len(loop))
        for x, y in loop:
            f.write("v %.6f %.6f 0\n" % (x, y))
        f.write("l " + " ".join(str(i + 1) for i in range(len(loop))) + "\n")


def write_soup():
    n, r0, r1 = 24, 0.12, 0.22
    verts, faces = [], []
    for i in range(n):
        a = 2 * math.pi * i / n
        verts.append((r0 * math.cos(a), r0 * math.sin(a)))
        verts.append((r1 * math.cos(a), r1 * math.sin(a)))
    for i in range(n):
        a0, b0 = 2 * i, 2 * i + 1
        a1, b1 = 2 * ((i + 1) % n), 2 * ((i + 1) % n) + 1
        tris = [(a0, b0, b1), (a0, b1, a1)]
        if i in (5, 17):  # holes: one triangle of the quad missing opens the ring into the pocket
            tris = tris[:1]
        faces += tris
        if i % 4 == 0:
            faces += tris  # duplicated faces
    verts.append((0.30, -0.02))
    verts.append((0.45, 0.0))
    verts.append((0.30, 0.02))
    faces.append((len(verts) - 3, len(verts) - 2, len(verts) - 1))  # a thin sliver
    with open(os.path.join(OUT, "soup.obj"), "w") as f:
        f.write("# Triangle soup (tools/make_fluid_boundaries.py): a ring with two holes, duplicated faces, a sliver\n")
        for x, y in verts:
            f.write("v %.6f %.6f 0\n" % (x, y))
        for a, b, c in faces:
            f.write("f %d %d %d\n" % (a + 1, b + 1, c + 1))


# (centre, radii, rotation about z) in a [-1, 1]^3 frame; the bunny faces +x, up is +y.
BUNNY3D = [
    ((-0.10, -0.28, 0.00), (0.50, 0.40, 0.38), 0.15),   # body
    ((0.38, 0.12, 0.00), (0.26, 0.24, 0.22), 0.0),      # head
    ((0.27, 0.52, -0.09), (0.07, 0.30, 0.06), 0.25),    # back ear
    ((0.45, 0.50, 0.09), (0.07, 0.28, 0.06), -0.30),    # front ear
    ((-0.62, -0.18, 0.00), (0.13, 0.13, 0.13), 0.0),    # tail
    ((0.25, -0.64, -0.16), (0.24, 0.08, 0.10), 0.0),    # front feet
    ((0.25, -0.64, 0.16), (0.24, 0.08, 0.10), 0.0),
]


def bunny3d(x, y, z):
    best = 1e9
    for (cx, cy, cz), (rx, ry, rz), a in BUNNY3D:
        dx, dy, dz = x - cx, y - cy, z - cz
        c, s = math.cos(a), math.sin(a)
        u, v = c * dx + s * dy, -s * dx + c * dy
        k = math.sqrt((u / rx) ** 2 + (v / ry) ** 2 + (dz / rz) ** 2)
        best = min(best, (k - 1) * min(rx, ry, rz))
    return best


def marching_tetrahedra(f, lo, hi, n):
    """Closed triangle mesh of the zero level set of f (negative inside) on an n^3 lattice of [lo, hi]^3."""
    h = (hi - lo) / n
    vals = {}
    for k in range(n + 1):
        for j in range(n + 1):
            for i in range(n + 1):
                v = f(lo + i * h, lo + j * h, lo + k * h)
                vals[(i, j, k)] = v if v != 0 else 1e-12  # no vertex exactly on the surface
    verts, index = [], {}

    def vertex(a, b):
        key = (min(a, b), max(a, b))
        if key not in index:
            fa, fb = vals[a], vals[b]
            t = min(max(fa / (fa - fb), 0.02), 0.98)  # keep vertices of different edges apart
            index[key] = len(verts)
            verts.append(tuple(lo + (a[d] + t * (b[d] - a[d])) * h for d in range(3)))
        return index[key]

    # Freudenthal: the 6 tetrahedra of a cube along its main diagonal, one per permutation of the axes.
    perms = [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]
    faces = []
    for k in range(n):
        for j in range(n):
            for i in range(n):
                for p in perms:
                    c = [i, j, k]
                    tet = [tuple(c)]
                    for axis in p:
                        c[axis] += 1
                        tet.append(tuple(c))
                    inside = [q for q in tet if vals[q] < 0]
                    outside = [q for q in tet if vals[q] >= 0]
                    if not inside or not outside:
                        continue
                    if len(inside) == 1 or len(outside) == 1:
                        lone, rest = (inside[0], outside) if len(inside) == 1 else (outside[0], inside)
                        tris = [[vertex(lone, r) for r in rest]]
                    else:
                        a, b = inside
                        c2, d = outside
                        tris = [[vertex(a, c2), vertex(a, d), vertex(b, d)], [vertex(a, c2), vertex(b, d), vertex(b, c2)]]
                    # Orient outwards: the normal points from the inside corners to the outside ones.
                    cin = [sum(q[d] for q in inside) / len(inside) for d in range(3)]
                    cout = [sum(q[d] for q in outside) / len(outside) for d in range(3)]
                    g = [cout[d] - cin[d] for d in range(3)]
                    for t in tris:
                        p0, p1, p2 = (verts[t[0]], verts[t[1]], verts[t[2]])
                        e1 = [p1[d] - p0[d] for d in range(3)]
                        e2 = [p2[d] - p0[d] for d in range(3)]
                        nrm = (e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0])
                        if sum(nrm[d] * g[d] for d in range(3)) < 0:
                            t = [t[0], t[2], t[1]]
                        faces.append(tuple(t))
    return verts, faces


def write_mesh(name, comment, verts, faces):
    with open(os.path.join(OUT, name), "w") as f:
        f.write("# %s (tools/make_fluid_boundaries.py): %d vertices, %d triangles\n" % (comment, len(verts), len(faces)))
        for x, y, z in verts:
            f.write("v %.7f %.7f %.7f\n" % (x, y, z))
        for a, b, c in faces:
            f.write("f %d %d %d\n" % (a + 1, b + 1, c + 1))


def write_bunny3d():
    verts, faces = marching_tetrahedra(bunny3d, -1.0, 1.0, 40)
    write_mesh("bunny3d.obj", "closed bunny surface", verts, faces)
    soup = [t for i, t in enumerate(faces) if i % (len(faces) // 12) != 7]  # 12 holes
    soup += [t for i, t in enumerate(faces) if i % 9 == 0]  # duplicated faces
    rng = __import__("random").Random(3)
    rng.shuffle(soup)
    write_mesh("bunny3d_soup.obj", "bunny triangle soup: holes, duplicates, shuffled", verts, soup)


if __name__ == "__main__":
    os.makedirs(OUT, exist_ok=True)
    write_bunny()
    write_soup()
    write_bunny3d()
