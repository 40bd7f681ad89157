#!/usr/bin/env python3
"""Write a small procedural sky as a Radiance RGBE (.hdr) latitude-longitude map, using the standard library only.

The map follows the envmap emitter's axes (Mitsuba's): +y is up, row 0 is the zenith, the left edge looks along
-z. Above the horizon, a blue sky brightening towards a pale horizon; below it, a dim brown ground; and a sun, a
disk of angular radius `--sun-radius` degrees, at the given elevation and azimuth (azimuth 0 = -z, 90 = +x).
Rows without the sun are constant, so the run-length encoding of the file keeps it a few kilobytes.

    python3 tools/make_sky.py scenes/render/textures/sky.hdr
    python3 tools/make_sky.py sky.hdr --width 512 --height 256 --sun-elevation 20 --sun-azimuth 120

Radiance's format (Ward, "Real Pixels", Graphics Gems II, 1991; the 'new' run-length encoding of Radiance 2.0):
a text header, a blank line, the resolution line, then one scanline after the other, each as the bytes 2, 2,
width (big endian 16 bits), followed by the four components (R, G, B mantissas, shared exponent) encoded one
after the other as runs (count + 128, byte) and literal dumps (count, bytes).
"""
import argparse
import math
import sys


def rgbe(r, g, b):
    """Shared-exponent encoding of one linear RGB triple."""
    v = max(r, g, b)
    if v < 1e-32:
        return (0, 0, 0, 0)
    m, e = math.frexp(v)  # v = m * 2^e, m in [0.5, 1)
    scale = m * 256.0 / v
    return (min(255, int(r * scale)), min(255, int(g * scale)), min(255, int(b * scale)), e + 128)


def rle_component(data):
    """Radiance run-length encoding of one component of a scanline."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        # Length of the run starting at i.
        run = 1
        while i + run < n and run < 127 and data[i + run] == data[i]:
            run += 1
        if run >= 4:
            out += bytes((128 + run, data[i]))
            i += run
            continue
        # A literal dump up to the next run of at least 4 (or 128 bytes).
        j = i
        while j < n and j - i < 128:
            k = 1
            while j + k < n and k < 4 and data[j + k] == data[j]:
                k += 1
            if k >= 4:
                break
            j += 1
        out += bytes((j - i,)) + bytes(data[i:j])
        i = j
    return out


def sky_radiance(d, sun_dir, sun_cos, args):
    """Linear RGB radiance arriving from unit direction d (y up)."""
    if math.acos(max(-1.0, min(1.0, sum(a * b for a, b in zip(d, sun_dir))))) <= math.radians(args.sun_radius):
        return tuple(args.sun_radiance * c for c in (1.0, 0.93, 0.80))
    y = d[1]
    if y >= 0:
        t = (1.0 - y) ** 3  # 0 at the zenith, 1 at the horizon
        zenith, horizon = (0.18, 0.35, 0.85), (0.85, 0.90, 1.00)
        return tuple(args.sky * (z + (h - z) * t) for z, h in zip(zenith, horizon))
    return tuple(args.sky * c for c in (0.22, 0.18, 0.14))


def main(argv):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("output")
    p.add_argument("--width", type=int, default=256)
    p.add_argument("--height", type=int, default=128)
    p.add_argument("--sky", type=float, default=1.0, help="sky brightness scale")
    p.add_argument("--sun-radiance", type=float, default=400.0)
    p.add_argument("--sun-radius", type=float, default=2.5, help="degrees")
    p.add_argument("--sun-elevation", type=float, default=35.0, help="degrees above the horizon")
    p.add_argument("--sun-azimuth", type=float, default=110.0, help="degrees from -z towards +x")
    args = p.parse_args(argv)
    if not (8 <= args.width <= 32767) or args.height < 1:
        sys.exit("width must lie in [8, 32767] (run-length encoded scanlines) and height be positive")

    el, az = math.radians(args.sun_elevation), math.radians(args.sun_azimuth)
    sun_dir = (math.sin(az) * math.cos(el), math.sin(el), -math.cos(az) * math.cos(el))
    out = bytearray(b"#?RADIANCE\n# procedural sky, tools/make_sky.py\nFORMAT=32-bit_rle_rgbe\n\n")
    out += f"-Y {args.height} +X {args.width}\n".encode()
    for j in range(args.height):
        theta = math.pi * (j + 0.5) / args.height
        comps = [bytearray(), bytearray(), bytearray(), bytearray()]
        for i in range(args.width):
            phi = 2 * math.pi * (i + 0.5) / args.width
            d = (math.sin(phi) * math.sin(theta), math.cos(theta), -math.cos(phi) * math.sin(theta))
            for c, v in zip(comps, rgbe(*sky_radiance(d, sun_dir, None, args))):
                c.append(v)
        out += bytes((2, 2, args.width >> 8, args.width & 255))
        for c in comps:
            out += rle_component(c)
    with open(args.output, "wb") as f:
        f.write(out)
    print(f"wrote {args.output}: {args.width} x {args.height}, {len(out)} bytes")


if __name__ == "__main__":
    main(sys.argv[1:])
