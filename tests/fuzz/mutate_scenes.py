#!/usr/bin/python3
"""A seeded mutation fuzzer of Kelvin scenes: mutants of the shipped scenes, run by `kelvin`.

    tests/fuzz/mutate_scenes.py --kelvin build/bin/kelvin --scenes scenes --work /tmp/mutants [--count 300]
                                [--seed 1] [--jobs 2] [--extremes] [--keep]

Each mutant is one shipped scene with one to three mutations: a number made extreme (0, -1, 1e308, NaN, Inf,
1e-308, 2^63), scaled or made negative; a string emptied, misspelt or pointed at /dev/zero or a missing file; an
element deleted, duplicated, moved into another or renamed; a plugin type swapped or misspelt; the text truncated or
bytes flipped. With --extremes most mutations are of magnitude instead: a coordinate, radius, circulation or any
other number scaled to the edges of float and double (1e18 to 1e308 and 1e-38 to 1e-308, both signs), and a
translation or scale of 1e19 to 1e300 added to a transform (the camera, a light, a mesh: the sizes that once
crashed Embree). It runs with small budgets (--time-limit, -D res=8 spp=2 end=0.05 every=0 with --allow-unused,
the image written as PFM) and is classified by exit code and output:

    0  a run, whose image must hold only finite values;
    2  bad input, which must be one line "kelvin: error: ..." on stderr; 130 never (no signal is sent)
    anything else (1, a signal, a crash, a timeout, 2 with more or less than one error line, exit 0 with a
    non-finite or unreadable image): a FAILURE

Exit status 0 when every mutant passed, 1 otherwise (the failures are listed, and kept in --work as
mutant_NNNN.xml with their stderr). Reproducible: the same seed gives the same mutants.
"""
import argparse
import concurrent.futures
import os
import random
import math
import re
import struct
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

EXTREME_NUMBERS = ["0", "-1", "1e308", "-1e308", "nan", "inf", "-inf", "1e-308", "9223372036854775807",
                   "-9223372036854775808", "4294967296", "1e12", "0.0000001"]
# Magnitudes at the edges of what float (geometry, images) and double (accumulators) hold, and just past them.
EXTREME_MAGNITUDES = ["1.8e18", "1e19", "3.4e38", "3.5e38", "1e39", "1e100", "1e150", "1e154", "1e155", "1e300",
                      "1e-38", "1e-39", "1e-300"]
NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")
SMALL = ["-D", "res=8", "-D", "spp=2", "-D", "end=0.05", "-D", "every=0", "--allow-unused"]


def mutate_value(rng, value):
    parts = [p.strip() for p in value.split(",")]
    if all(NUMBER.match(p) for p in parts if p):
        i = rng.randrange(len(parts))
        kind = rng.random()
        if kind < 0.6:
            parts[i] = rng.choice(EXTREME_NUMBERS)
        elif kind < 0.8:
            parts[i] = repr(float(parts[i] or 0) * 10 ** rng.randint(-6, 9))
        else:
            parts[i] = repr(-float(parts[i] or 0))
        return ", ".join(parts)
    choice = rng.random()
    if choice < 0.25:
        return ""
    if choice < 0.5:
        return value[::-1] if value else "x"
    if choice < 0.65:
        return "/dev/zero"
    if choice < 0.8:
        return "no_such_file_" + str(rng.randint(0, 999)) + os.path.splitext(value)[1]
    return value + rng.choice(["x", "_", "1", " ", "$undefined"])


def extreme_value(rng, value):
    """A number of the value scaled to an extreme magnitude, sign kept or flipped."""
    parts = [p.strip() for p in value.split(",")]
    if not all(NUMBER.match(p) for p in parts if p):
        return mutate_value(rng, value)
    i = rng.randrange(len(parts))
    m = rng.choice(EXTREME_MAGNITUDES)
    parts[i] = ("-" if rng.random() < 0.3 else "") + m
    return ", ".join(parts)


def extreme_mutation(rng, root):
    """A magnitude mutation: a number made extreme, or a huge translation or scale added to a transform."""
    elements = list(root.iter())
    transforms = [e for e in elements if e.tag == "transform"]
    if transforms and rng.random() < 0.4:
        t = rng.choice(transforms)
        m = rng.choice(["1e19", "1e20", "1e38", "1e39", "1e150", "1e300", "1e-30", "1e-300"])
        if rng.random() < 0.5:
            op = ET.Element("translate", {rng.choice("xyz"): ("-" if rng.random() < 0.3 else "") + m})
        else:
            op = ET.Element("scale", {"value": m})
        t.append(op)
        return
    numeric = [(e, k) for e in elements for k, v in sorted(e.attrib.items())
               if k in ("value", "x", "y", "z", "origin", "target", "up") and any(c.isdigit() for c in v)]
    if numeric:
        e, k = rng.choice(numeric)
        e.attrib[k] = extreme_value(rng, e.attrib[k])


def tree_mutation(rng, root):
    elements = list(root.iter())
    parents = {c: p for p in root.iter() for c in p}
    e = rng.choice(elements)
    op = rng.random()
    if op < 0.45 and e.attrib:
        key = rng.choice(sorted(e.attrib))
        if key in ("value", "x", "y", "z", "angle", "origin", "target", "up"):
            e.attrib[key] = mutate_value(rng, e.attrib[key])
        elif key == "type":
            others = sorted({x.attrib["type"] for x in elements if "type" in x.attrib and x.tag == e.tag})
            e.attrib[key] = rng.choice(others + [e.attrib[key] + "x", ""])
        elif key == "name":
            e.attrib[key] = rng.choice([e.attrib[key] + "s", "", e.attrib[key][:-1]])
        else:
            e.attrib[key] = mutate_value(rng, e.attrib[key])
    elif op < 0.6 and e in parents:
        parents[e].remove(e)
    elif op < 0.72 and e in parents:
        p = parents[e]
        p.insert(list(p).index(e), ET.fromstring(ET.tostring(e)))
    elif op < 0.82 and e in parents:
        target = rng.choice(elements)
        if target is not e and e not in list(target.iter()):
            parents[e].remove(e)
            target.append(e)
    elif op < 0.92:
        e.tag = rng.choice(["float", "integer", "string", "rgb", "boolean", "point", "transform", "shape", "bsdf",
                            "emitter", "default", "ref", e.tag + "x"])
    else:
        e.attrib[rng.choice(["value", "name", "type", "id"])] = mutate_value(rng, "1")


def mutant(rng, text, extremes=False):
    if not extremes and rng.random() < 0.15:  # byte level
        data = bytearray(text.encode())
        if rng.random() < 0.5:
            return bytes(data[: rng.randrange(len(data))])
        for _ in range(rng.randint(1, 8)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        return bytes(data)
    try:
        root = ET.fromstring(text)
    except ET.ParseError:
        return text.encode()
    for _ in range(rng.randint(1, 3)):
        if extremes and rng.random() < 0.8:
            extreme_mutation(rng, root)
        else:
            tree_mutation(rng, root)
    return ET.tostring(root)


def pfm_problem(path):
    """Why the PFM image at `path` is not a complete image of finite values; None when it is."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        return f"cannot read the output: {e}"
    parts = data.split(b"\n", 3)
    if len(parts) < 4 or parts[0] not in (b"PF", b"Pf"):
        return "the output is not a PFM image"
    try:
        w, h = (int(x) for x in parts[1].split())
        scale = float(parts[2])
    except ValueError:
        return "the output's PFM header is malformed"
    channels = 3 if parts[0] == b"PF" else 1
    n = w * h * channels
    if len(parts[3]) != 4 * n:
        return f"the output holds {len(parts[3])} bytes of pixels, {4 * n} expected (a cut file)"
    values = struct.unpack(("<" if scale < 0 else ">") + f"{n}f", parts[3])
    bad = sum(1 for v in values if not math.isfinite(v))
    return f"the output holds {bad} non-finite values" if bad else None


def run(kelvin, path, timeout, time_limit):
    out = os.path.splitext(path)[0] + "_out.pfm"
    cmd = [kelvin, path, "-q", "-t", "1", "--time-limit", str(time_limit), "-o", out] + SMALL
    start = time.monotonic()
    try:
        p = subprocess.run(cmd, capture_output=True, timeout=timeout, text=True, errors="replace")
    except subprocess.TimeoutExpired:
        return "timeout", f"still running after {timeout} s", time.monotonic() - start
    seconds = time.monotonic() - start
    if p.returncode == 0:
        # A simulation writes its fields beside the image (and no PFM when its fields are not RGB): the image is
        # checked when there is one; the writers themselves refuse non-finite values (exit 1, a failure here).
        if os.path.exists(out):
            why = pfm_problem(out)
            if why:
                return "FAIL", f"exit 0 but {why}", seconds
        return "ok", "", seconds
    errors = [l for l in p.stderr.splitlines() if l.startswith("kelvin: error:")]
    if p.returncode == 2 and len(errors) == 1:
        return "input", errors[0], seconds
    what = f"signal {-p.returncode}" if p.returncode < 0 else f"exit {p.returncode}"
    if p.returncode == 2:
        what += f" with {len(errors)} error lines"
    return "FAIL", f"{what}: {p.stderr.strip()[-600:]}", seconds


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kelvin", required=True)
    ap.add_argument("--scenes", required=True, help="folder of the shipped scenes (searched recursively)")
    ap.add_argument("--work", required=True)
    ap.add_argument("--count", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds before a mutant counts as hung")
    ap.add_argument("--time-limit", type=float, default=0.5, help="kelvin's --time-limit for each mutant")
    ap.add_argument("--keep", action="store_true", help="keep passing mutants too")
    ap.add_argument("--extremes", action="store_true",
                    help="mostly magnitude mutations: numbers and transforms at the edges of float and double")
    a = ap.parse_args()

    sources = []
    for d, _, files in os.walk(a.scenes):
        for f in sorted(files):
            if f.endswith(".xml"):
                sources.append(os.path.join(d, f))
    sources.sort()
    if not sources:
        print(f"mutate_scenes: no scenes under {a.scenes}", file=sys.stderr)
        return 2
    os.makedirs(a.work, exist_ok=True)
    rng = random.Random(a.seed)
    jobs = []
    for i in range(a.count):
        src = rng.choice(sources)
        with open(src, encoding="utf-8") as f:
            text = f.read()
        # Scenes name their assets relative to themselves: keep the mutant beside... a copy of the folder's
        # relative paths would be heavier; rewrite them absolute instead.
        base = os.path.dirname(os.path.abspath(src))
        text = re.sub(r'(name="(?:filename|path)" value=")([^"/$][^"]*)"',
                      lambda m: m.group(1) + os.path.join(base, m.group(2)) + '"', text)
        text = re.sub(r'(<include filename=")([^"/$][^"]*)"', lambda m: m.group(1) + os.path.join(base, m.group(2)) + '"',
                      text)
        path = os.path.join(a.work, f"mutant_{i:04d}.xml")
        with open(path, "wb") as f:
            f.write(mutant(rng, text, a.extremes))
        jobs.append((path, os.path.relpath(src, a.scenes)))

    counts = {"ok": 0, "input": 0, "FAIL": 0, "timeout": 0}
    failures = []
    slowest = (0.0, "")
    start = time.monotonic()
    with concurrent.futures.ThreadPoolExecutor(max_workers=a.jobs) as pool:
        results = list(pool.map(lambda j: run(a.kelvin, j[0], a.timeout, a.time_limit), jobs))
    for (path, src), (cls, msg, seconds) in zip(jobs, results):
        counts[cls] += 1
        slowest = max(slowest, (seconds, path))
        if cls in ("FAIL", "timeout"):
            failures.append((path, src, cls, msg))
            with open(path + ".stderr", "w") as f:
                f.write(msg + "\n")
        elif not a.keep:
            os.remove(path)
            stem = os.path.basename(os.path.splitext(path)[0]) + "_out"
            for f in os.listdir(a.work):  # the image and what a run writes beside it (MLT's stage map)
                if f.startswith(stem) and os.path.isfile(os.path.join(a.work, f)):
                    os.remove(os.path.join(a.work, f))
            folder = os.path.splitext(path)[0] + "_out"
            if os.path.isdir(folder):
                for root, dirs, files in os.walk(folder, topdown=False):
                    for f in files:
                        os.remove(os.path.join(root, f))
                    for d in dirs:
                        os.rmdir(os.path.join(root, d))
                os.rmdir(folder)
    kind = "magnitude mutants" if a.extremes else "mutants"
    print(f"mutate_scenes: {a.count} {kind} of {len(sources)} scenes (seed {a.seed}) in {time.monotonic() - start:.1f} s: "
          f"{counts['ok']} ran, {counts['input']} refused in one line, {counts['FAIL']} failed, "
          f"{counts['timeout']} hung; slowest {slowest[0]:.1f} s ({os.path.basename(slowest[1])})")
    for path, src, cls, msg in failures:
        print(f"  {cls}: {path} (from {src}): {msg}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
