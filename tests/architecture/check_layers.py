#!/usr/bin/env python3
"""Checks every #include of Kelvin's sources against the layering table of docs/architecture.md (the test
`architecture.layers`).

Usage: check_layers.py SOURCE_DIR        check the tree (after a self-test of the checker itself)
       check_layers.py --self-test       only the self-test

The rules come from the table under "### Allowed includes" in SOURCE_DIR/docs/architecture.md, so the page and the
check cannot drift apart. Each row names a layer, the folders that hold its files, and what it may include:

  * a layer name (`core`, `render`, ...): that layer's public headers (include/kelvin/<layer>/);
  * `private core` (any layer name): that layer's private headers too (src/<layer>/*.h);
  * `public`: every public header (include/kelvin/...);
  * `beside`: headers in the including file's own folder (a plugin folder's shared header);
  * `everything`: anything (not checked).

A layer may always include its own headers, public and private. Besides the table, two rules hold for every public
header (include/kelvin/...), since an installed tree has nothing else: it includes only public headers, and never a
header of a dependency that libkelvin keeps private (Embree, OpenVDB, OpenImageIO, OpenEXR, oneTBB, pugixml, Eigen,
MPI). An include that resolves to no file of the tree (a quoted include that is neither beside the file nor under
src/ or include/; a <kelvin/...> that names no public header) is an error too, so that nothing escapes the check by
a spelling the checker does not understand.

Every problem is printed as `file:line: rule broken: the include`, and the exit status is 1. KNOWN lists the breaks
that are tolerated while their fix is under way; each must still be present (a stale entry fails, so the list only
shrinks).
"""
import os
import re
import sys
import tempfile

# (file, included header): why it is tolerated for now. Remove the entry with the include. Empty: no break is known.
KNOWN = {}

# Dependencies libkelvin links privately: their headers never appear in a public header.
PRIVATE_DEPENDENCIES = ("embree3/", "embree4/", "openvdb/", "OpenImageIO/", "OpenEXR/", "Imath/", "tbb/", "oneapi/",
                        "pugixml", "Eigen/", "eigen3/", "mpi.h")

SOURCE_SUFFIXES = (".h", ".hpp", ".cpp", ".cc", ".h.in")
INCLUDE = re.compile(r'^\s*#\s*include\s*([<"])([^>"]+)[>"]')
TOKENS_OK = re.compile(r"^(everything|public|beside|private [a-z]+|[a-z]+)$")


class Table:
    """The rows of the "Allowed includes" table: layer -> (folders, tokens)."""

    def __init__(self, text, where):
        self.rows = {}
        lines = text.splitlines()
        try:
            start = next(i for i, l in enumerate(lines) if l.strip().lower() == "### allowed includes")
        except StopIteration:
            raise SystemExit(f"{where}: no '### Allowed includes' section")
        # The first table after the heading: a header row, a separator, then rows until the first non-table line.
        rows = []
        for l in lines[start + 1:]:
            if l.startswith("|"):
                rows.append(l)
            elif rows:
                break
        if len(rows) < 3:
            raise SystemExit(f"{where}: the 'Allowed includes' table has no rows")
        for l in rows[2:]:
            cells = [c.strip() for c in l.strip().strip("|").split("|")]
            if len(cells) != 3:
                raise SystemExit(f"{where}: table row '{l}' does not have three cells (layer, files, may include)")
            names = [n.strip() for n in cells[0].split(",")]
            folders = re.findall(r"`([^`]+)`", cells[1])
            tokens = [t.strip() for t in cells[2].split(",") if t.strip()]
            if not folders or not tokens or not all(TOKENS_OK.match(t) for t in tokens):
                raise SystemExit(f"{where}: cannot read table row '{l}'")
            for name in names:
                self.rows[name] = ([f.rstrip("/") + "/" for f in folders], tokens)
        for name, (_, tokens) in self.rows.items():
            for t in tokens:
                target = t.split(" ", 1)[1] if t.startswith("private ") else t
                if target not in ("everything", "public", "beside") and target not in self.rows:
                    raise SystemExit(f"{where}: layer '{name}' may include '{t}', which is not a layer of the table")

    def layer_of(self, path):
        """The layer whose folder is the longest prefix of path (relative, '/'-separated), or None."""
        best, best_len = None, -1
        for name, (folders, _) in self.rows.items():
            for f in folders:
                if path.startswith(f) and len(f) > best_len:
                    best, best_len = name, len(f)
        return best


def resolve(root, path, kind, name):
    """(resolved relative path or None, where): where is 'beside', 'private' (src/) or 'public' (include/)."""
    here = os.path.dirname(path)
    if kind == '"':
        beside = os.path.normpath(os.path.join(here, name))
        if os.path.isfile(os.path.join(root, beside)):
            return beside, "beside"
        for base, where in (("src", "private"), ("include", "public")):
            p = os.path.normpath(os.path.join(base, name))
            if os.path.isfile(os.path.join(root, p)):
                return p, where
        return None, None
    p = os.path.join("include", name)
    if os.path.isfile(os.path.join(root, p)) or os.path.isfile(os.path.join(root, p + ".in")):
        return p, "public"
    return None, None


def check_tree(root, known):
    """Returns (problems, known breaks seen): problems as 'file:line: message' strings; `known` as KNOWN."""
    doc = os.path.join(root, "docs", "architecture.md")
    with open(doc, encoding="utf-8") as f:
        table = Table(f.read(), doc)
    problems, seen = [], set()
    files = []
    for name, (folders, tokens) in table.rows.items():
        if "everything" in tokens:
            continue
        for folder in folders:
            top = os.path.join(root, folder)
            for d, dirs, names in os.walk(top):
                dirs.sort()
                for n in sorted(names):
                    if n.endswith(SOURCE_SUFFIXES):
                        files.append(os.path.relpath(os.path.join(d, n), root).replace(os.sep, "/"))
    for path in sorted(set(files)):
        layer = table.layer_of(path)
        tokens = table.rows[layer][1]
        if "everything" in tokens:
            continue
        public_file = path.startswith("include/")
        with open(os.path.join(root, path), encoding="utf-8", errors="replace") as f:
            lines = f.readlines()
        for number, line in enumerate(lines, 1):
            m = INCLUDE.match(line)
            if not m:
                continue
            kind, name = m.group(1), m.group(2).strip()
            where_text = f"{path}:{number}"
            if kind == "<" and not name.startswith("kelvin/"):
                if public_file and name.startswith(PRIVATE_DEPENDENCIES):
                    problems.append(f"{where_text}: a public header includes <{name}>, a header of a dependency "
                                    "libkelvin keeps private (no Embree, OpenVDB, ... type in a public header)")
                continue
            target, where = resolve(root, path, kind, name)
            if target is None:
                problems.append(f"{where_text}: {kind}{name}{'>' if kind == '<' else kind} is no header of the "
                                "tree (neither beside the file nor under src/ or include/)")
                continue
            target_layer = table.layer_of(target)
            key = (path, name)
            if public_file and where == "private":
                message = (f"{where_text}: a public header includes the private header \"{name}\" ({target}); public "
                           "headers include only include/kelvin/...")
            elif where == "beside" and ("beside" in tokens or target_layer == layer):
                continue
            elif target_layer == layer:
                continue
            elif where == "public" and ("public" in tokens or target_layer in tokens):
                continue
            elif where in ("private", "beside") and f"private {target_layer}" in tokens:
                continue
            else:
                kind_text = "the public" if where == "public" else "the private"
                message = (f"{where_text}: {layer} may include only {', '.join(tokens)} (docs/architecture.md), not "
                           f"{kind_text} {target_layer or 'unlayered'} header {kind}{name}"
                           f"{'>' if kind == '<' else kind}")
            if key in known:
                seen.add(key)
                continue
            problems.append(message)
    for key, why in known.items():
        if key not in seen:
            problems.append(f"{key[0]}: the known break 'includes {key[1]}' ({why}) is gone: remove it from KNOWN in "
                            "tests/architecture/check_layers.py")
    return problems, seen


SELF_TEST_TABLE = """# Architecture

### Allowed includes

| layer | files | may include |
|---|---|---|
| core | `include/kelvin/core/`, `src/core/` | core |
| render | `include/kelvin/render/`, `src/render/` | core, render |
| wos | `include/kelvin/wos/`, `src/wos/` | core, wos |
| fluid | `include/kelvin/fluid/`, `src/fluid/` | core, wos, fluid |
| plugins | `src/plugins/` | public, beside |
| modules | `src/modules/` | core, private core |
| examples | `examples/` | public |
| cli | `src/cli/` | everything |
| tests | `tests/` | everything |

Text after the table.
"""


def self_test():
    """Builds a small tree with one break of each kind (under a table of its own, like the page's) and checks that
    each is reported, and nothing else."""
    table_text = SELF_TEST_TABLE
    files = {
        "include/kelvin/core/a.h": '#include <kelvin/core/b.h>\n#include <vector>\n#include <kelvin/fluid/f.h>\n',
        "include/kelvin/core/b.h": '#include "core/private.h"\n#include <embree3/rtcore.h>\n',
        "include/kelvin/fluid/f.h": '#include <kelvin/core/a.h>\n#include <kelvin/wos/w.h>\n',
        "include/kelvin/wos/w.h": '#include <kelvin/core/a.h>\n#include <kelvin/fluid/f.h>\n',
        "include/kelvin/render/r.h": '#include <kelvin/core/a.h>\n',
        "src/core/private.h": '#pragma once\n',
        "src/core/a.cpp": '#include "private.h"\n#include "core/private.h"\n  #  include <kelvin/render/r.h>\n',
        "src/fluid/f.cpp": '#include <kelvin/fluid/f.h>\n#include <kelvin/render/r.h>\n#include "core/private.h"\n',
        "src/fluid/simulation.cpp": '#include <kelvin/render/scene.h>\n',
        "include/kelvin/render/scene.h": '#pragma once\n',
        "src/modules/m.cpp": '#include "core/private.h"\n#include <kelvin/render/r.h>\n',
        "src/plugins/boundaries/common.h": '#include <kelvin/wos/w.h>\n',
        "src/plugins/boundaries/p.cpp": ('#include "common.h"\n#include <kelvin/fluid/f.h>\n#include "core/private.h"\n'
                                         '#include <kelvin/core/missing.h>\n#include "nowhere.h"\n'),
        "src/cli/main.cpp": '#include "core/private.h"\n',
        "examples/e.cpp": '#include <kelvin/fluid/f.h>\n#include "core/private.h"\n',
        "tests/t.cpp": '#include "core/private.h"\n',
    }
    expected = [
        "include/kelvin/core/a.h:3: core may include only core",
        "include/kelvin/core/b.h:1: a public header includes the private header",
        "include/kelvin/core/b.h:2: a public header includes <embree3/rtcore.h>",
        "include/kelvin/wos/w.h:2: wos may include only core, wos",
        "src/core/a.cpp:3: core may include only core",
        "src/fluid/f.cpp:3: fluid may include only core, wos, fluid (docs/architecture.md), not the private core",
        "src/modules/m.cpp:2: modules may include only",
        "src/plugins/boundaries/p.cpp:3: plugins may include only public, beside",
        "src/plugins/boundaries/p.cpp:4: <kelvin/core/missing.h> is no header",
        "src/plugins/boundaries/p.cpp:5: \"nowhere.h\" is no header",
        "examples/e.cpp:2: examples may include only public",
        # src/fluid/f.cpp:2 (fluid -> render) is reported too; the known break in simulation.cpp is not.
        "src/fluid/f.cpp:2: fluid may include only",
    ]
    with tempfile.TemporaryDirectory() as root:
        os.makedirs(os.path.join(root, "docs"))
        with open(os.path.join(root, "docs", "architecture.md"), "w", encoding="utf-8") as f:
            f.write(table_text)
        for p, text in files.items():
            os.makedirs(os.path.join(root, os.path.dirname(p)), exist_ok=True)
            with open(os.path.join(root, p), "w", encoding="utf-8") as f:
                f.write(text)
        known = {("src/fluid/simulation.cpp", "kelvin/render/scene.h"): "a known break"}
        problems, seen = check_tree(root, known)
        failures = []
        for e in expected:
            if not any(p.startswith(e) for p in problems):
                failures.append(f"self-test: the checker missed '{e}...'")
        for p in problems:
            if not any(p.startswith(e) for e in expected):
                failures.append(f"self-test: the checker reported a problem that is none: {p}")
        if not seen:
            failures.append("self-test: the known break was not recognised")
        # The stale-entry rule: without the known include, its entry is reported.
        os.remove(os.path.join(root, "src/fluid/simulation.cpp"))
        problems, _ = check_tree(root, known)
        if not any("is gone: remove it from KNOWN" in p for p in problems):
            failures.append("self-test: a stale KNOWN entry was not reported")
    return failures


def main(argv):
    if len(argv) == 2 and argv[1] == "--self-test":
        root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
    elif len(argv) == 2:
        root = argv[1]
    else:
        print(__doc__.split("\n\n")[1], file=sys.stderr)
        return 2
    failures = self_test()
    for f in failures:
        print(f)
    if failures:
        return 1
    if argv[1] == "--self-test":
        print("check_layers: self-test passed")
        return 0
    problems, seen = check_tree(root, KNOWN)
    for key in sorted(seen):
        print(f"{key[0]}: known break: includes {key[1]} ({KNOWN[key]})")
    for p in problems:
        print(p)
    if problems:
        print(f"check_layers: {len(problems)} include(s) break docs/architecture.md's layering")
        return 1
    print("check_layers: every include follows docs/architecture.md's layering")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
