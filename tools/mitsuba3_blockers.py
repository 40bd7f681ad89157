#!/usr/bin/env python3
"""Which Mitsuba 3 features block which scenes: for every scene of a Mitsuba 3 scene folder (default
../shared/mitsuba3-tests/tests/scenes), the plugins (<kind type=...>) and the parameters of supported plugins
(including textures given for a parameter that takes none) that Kelvin does not have, counted over the scenes
they appear in. Reads Kelvin's plugin list from `kelvin --list-plugins`.

    tools/mitsuba3_blockers.py [--kelvin build/bin/kelvin] [SCENE_DIR]
"""
import argparse
import collections
import os
import re
import subprocess
import xml.etree.ElementTree as ET

KINDS = {"integrator", "sensor", "film", "sampler", "rfilter", "shape", "bsdf", "emitter", "texture", "medium",
         "phase", "volume", "spectrum"}
VALUE_TAGS = {"float", "integer", "boolean", "string", "rgb", "spectrum", "point", "vector", "transform"}


def kelvin_plugins(kelvin):
    out = subprocess.run([kelvin, "--list-plugins"], capture_output=True, text=True, check=True).stdout
    plugins, kind, name = {}, None, None
    for line in out.splitlines():
        if not line.strip():
            continue
        indent = len(line) - len(line.lstrip(" "))
        if indent == 0:
            kind = line.strip()
        elif indent == 2:
            name = line.split()[0]
            plugins[(kind, name)] = {}
        elif indent == 6 and name:
            parts = line.split()
            plugins[(kind, name)][parts[0]] = parts[1] if len(parts) > 1 else ""
    return plugins


def elements(path, search, seen):
    """The scene's elements, includes expanded (relative to the including file, then the <path> folders)."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError):
        return []
    out = []
    for child in root:
        if child.tag == "path":
            search.append(os.path.normpath(os.path.join(os.path.dirname(path), child.get("value", ""))))
        elif child.tag == "include":
            fn = child.get("filename", "")
            cands = [os.path.join(os.path.dirname(path), fn)] + [os.path.join(d, fn) for d in reversed(search)]
            for c in cands:
                if os.path.exists(c) and c not in seen:
                    seen.add(c)
                    out += elements(c, search, seen)
                    break
        else:
            out.append(child)
    return out


def blockers(el, plugins, found):
    for c in el.iter():
        kind, typ = c.tag, c.get("type")
        if kind in KINDS and typ and not typ.startswith("$"):
            if kind == "spectrum":
                found.add("<spectrum type=...> plugins")
                continue
            params = plugins.get((kind, typ))
            if params is None:
                found.add(f"{kind} {typ}")
                continue
            for p in c:
                name = p.get("name")
                if not name:
                    continue
                if p.tag in VALUE_TAGS and name not in params:
                    found.add(f"{kind} {typ}: parameter {name}")
                elif p.tag == "texture" and name in params and "texture" not in params[name]:
                    found.add(f"{kind} {typ}: texture for {name}")
        elif kind in ("medium", "phase", "volume") and not typ:
            found.add(f"<{kind}>")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene_dir", nargs="?",
                    default=os.path.join(os.path.dirname(__file__), "..", "..", "shared", "mitsuba3-tests", "tests",
                                         "scenes"))
    ap.add_argument("--kelvin", default=os.path.join(os.path.dirname(__file__), "..", "build", "bin", "kelvin"))
    a = ap.parse_args()
    plugins = kelvin_plugins(a.kelvin)
    counts, per_scene = collections.Counter(), {}
    for group in sorted(os.listdir(a.scene_dir)):
        gdir = os.path.join(a.scene_dir, group)
        if not os.path.isdir(gdir):
            continue
        for f in sorted(os.listdir(gdir)):
            if not f.endswith(".xml"):
                continue
            path = os.path.join(gdir, f)
            found = set()
            for el in elements(path, [], {path}):
                if el.tag == "integrator" and el.get("type", "").startswith("$"):
                    suffix = f[:-4].rsplit("_", 1)[-1]
                    el = ET.fromstring(ET.tostring(el).decode().replace(el.get("type"), suffix, 1))
                for inner in el.iter("integrator"):
                    if inner.get("type", "").startswith("$"):
                        inner.set("type", f[:-4].rsplit("_", 1)[-1])
                blockers(el, plugins, found)
            per_scene[f"{group}/{f}"] = sorted(found)
            counts.update(found)
    print(f"{len(per_scene)} scenes; {sum(1 for v in per_scene.values() if not v)} use only supported plugins and "
          "parameters\n")
    print("blocked scenes  feature")
    for feat, n in counts.most_common():
        print(f"{n:14d}  {feat}")
    print()
    for s, f in per_scene.items():
        print(f"{s}: {', '.join(f) if f else 'supported'}")


if __name__ == "__main__":
    main()
