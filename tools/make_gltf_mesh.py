#!/usr/bin/env python3
"""Generate the procedural glTF asset of scenes/render/gltf-mesh.xml (no downloaded assets).

    python3 tools/make_gltf_mesh.py scenes/render/meshes     # writes knot-and-blob.gltf + knot-and-blob.bin

Two meshes under a small node hierarchy (so that node transforms are exercised):
  * a (2, 3) torus knot swept by a circle (smooth normals, uvs along and around the tube), lying on the floor;
  * a lumpy "bunny-like" blob: a subdivided icosahedron displaced by two ear-like bumps and low-frequency
    waves, without NORMAL (glTF then asks for flat shading).
Only the Python standard library is used; the output is deterministic (byte-identical on every run).
"""
import json
import math
import os
import struct
import sys


def normalize(v):
    n = math.sqrt(sum(c * c for c in v))
    return [c / n for c in v] if n > 0 else [0.0, 0.0, 0.0]


def cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def torus_knot(p=2, q=3, segments=192, sides=16, tube=0.35):
    """Vertices, normals, uvs, triangle indices. The knot lies on a torus (core radius 2, tube 1); the torus
    normal gives a periodic, twist-free frame for the swept circle."""
    def curve(t):
        phi, theta = p * t, q * t
        r = 2 + math.cos(theta)
        return [r * math.cos(phi), r * math.sin(phi), -math.sin(theta)], [
            math.cos(theta) * math.cos(phi), math.cos(theta) * math.sin(phi), -math.sin(theta)]

    pos, nrm, uv, idx = [], [], [], []
    for i in range(segments + 1):  # the last ring repeats the first (uv seam)
        t = 2 * math.pi * (i % segments) / segments
        c, up = curve(t)
        c2, _ = curve(t + 1e-4)
        tangent = normalize([c2[k] - c[k] for k in range(3)])
        b = normalize(cross(tangent, up))
        n = cross(b, tangent)
        for j in range(sides + 1):
            a = 2 * math.pi * (j % sides) / sides
            d = [math.cos(a) * n[k] + math.sin(a) * b[k] for k in range(3)]
            pos.append([c[k] + tube * d[k] for k in range(3)])
            nrm.append(d)
            uv.append([i / segments, j / sides])
    for i in range(segments):
        for j in range(sides):
            a = i * (sides + 1) + j
            b_, c_, d_ = a + sides + 1, a + 1, a + sides + 2
            idx += [a, b_, c_, c_, b_, d_]
    # Orientation check: normals must agree with the winding (outward).
    v0, v1, v2 = (pos[idx[k]] for k in range(3))
    face = cross([v1[k] - v0[k] for k in range(3)], [v2[k] - v0[k] for k in range(3)])
    if sum(face[k] * nrm[idx[0]][k] for k in range(3)) < 0:
        idx = [idx[k + o] for k in range(0, len(idx), 3) for o in (0, 2, 1)]
    return pos, nrm, uv, idx


def blob(levels=3):
    """Subdivided icosahedron, displaced: two 'ears' and gentle waves."""
    t = (1 + math.sqrt(5)) / 2
    verts = [normalize(v) for v in [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                                     [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]]
    faces = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
             [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
             [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    for _ in range(levels):
        cache, out = {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                verts.append(normalize([(verts[a][k] + verts[b][k]) / 2 for k in range(3)]))
                cache[key] = len(verts) - 1
            return cache[key]
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            out += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        faces = out
    ears = [normalize([0.35, 1, -0.2]), normalize([-0.35, 1, -0.2])]
    pos = []
    for d in verts:
        r = 1.0 + 0.06 * math.sin(5 * d[0]) * math.sin(4 * d[2])
        for e in ears:
            dd = sum((d[k] - e[k]) ** 2 for k in range(3))
            r += 0.55 * math.exp(-dd / 0.03)
        pos.append([r * d[0], 0.85 * r * d[1], r * d[2]])
    return pos, [i for f in faces for i in f]


class Buffer:
    def __init__(self):
        self.data = bytearray()
        self.views, self.accessors = [], []

    def add(self, fmt, values, count, kind, component, target, minmax=False):
        while len(self.data) % 4:
            self.data.append(0)
        offset = len(self.data)
        self.data += struct.pack("<%d%s" % (len(values), fmt), *values)
        self.views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(self.data) - offset, "target": target})
        acc = {"bufferView": len(self.views) - 1, "componentType": component, "count": count, "type": kind}
        if minmax:
            n = len(values) // count
            acc["min"] = [min(values[k::n]) for k in range(n)]
            acc["max"] = [max(values[k::n]) for k in range(n)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def f32(v):
    return struct.unpack("<f", struct.pack("<f", v))[0]


def main(out_dir):
    os.makedirs(out_dir, exist_ok=True)
    buf = Buffer()
    kpos, knrm, kuv, kidx = torus_knot()
    flat = lambda rows: [f32(c) for r in rows for c in r]
    knot = {"attributes": {
        "POSITION": buf.add("f", flat(kpos), len(kpos), "VEC3", 5126, 34962, True),
        "NORMAL": buf.add("f", flat(knrm), len(knrm), "VEC3", 5126, 34962),
        "TEXCOORD_0": buf.add("f", flat(kuv), len(kuv), "VEC2", 5126, 34962)},
        "indices": buf.add("H", kidx, len(kidx), "SCALAR", 5123, 34963), "mode": 4}
    bpos, bidx = blob()
    lump = {"attributes": {"POSITION": buf.add("f", flat(bpos), len(bpos), "VEC3", 5126, 34962, True)},
            "indices": buf.add("H", bidx, len(bidx), "SCALAR", 5123, 34963), "mode": 4}
    s = math.sqrt(0.5)
    gltf = {
        "asset": {"version": "2.0", "generator": "Kelvin tools/make_gltf_mesh.py"},
        "scene": 0,
        "scenes": [{"name": "knot-and-blob", "nodes": [0]}],
        "nodes": [
            {"name": "root", "children": [1, 2], "translation": [0, 0, 0]},
            # The knot lies in the xy plane: rotate -90 degrees about x to lay it on the floor (y up).
            {"name": "knot", "mesh": 0, "rotation": [-s, 0, 0, s], "scale": [0.4, 0.4, 0.4],
             "translation": [-0.6, 0.54, 0]},
            {"name": "blob", "mesh": 1, "scale": [0.55, 0.55, 0.55], "translation": [1.55, 0.47, 0.7]},
        ],
        "meshes": [{"name": "torus-knot", "primitives": [knot]}, {"name": "blob", "primitives": [lump]}],
        "buffers": [{"uri": "knot-and-blob.bin", "byteLength": len(buf.data)}],
        "bufferViews": buf.views,
        "accessors": buf.accessors,
    }
    with open(os.path.join(out_dir, "knot-and-blob.bin"), "wb") as f:
        f.write(buf.data)
    with open(os.path.join(out_dir, "knot-and-blob.gltf"), "w") as f:
        json.dump(gltf, f, indent=1)
        f.write("\n")
    print("wrote %s: %d + %d triangles, %d bytes of buffer" % (
        os.path.join(out_dir, "knot-and-blob.gltf"), len(kidx) // 3, len(bidx) // 3, len(buf.data)))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..", "scenes", "render", "meshes"))
