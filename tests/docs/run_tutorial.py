#!/usr/bin/env python3
"""Runs every shell command of docs/tutorial.md (the test `docs.tutorial`).

Usage: run_tutorial.py KELVIN_CLI SOURCE_DIR [WORK_DIR]

What it does:
- Extracts every fenced code block whose language is `sh` from SOURCE_DIR/docs/tutorial.md, in order.
- Creates a scratch directory (WORK_DIR, emptied first, or a fresh temporary directory) holding symbolic links
  `scenes` and `tools` to SOURCE_DIR's, so that the tutorial's relative paths (`scenes/render/...`) work as they do
  from the source tree, and every output the tutorial writes lands in the scratch directory.
- Runs each block there with `bash -e -o pipefail`, with `kelvin` defined as a shell function calling KELVIN_CLI
  (so `kelvin` at the start of a command, after `&&` or in a loop is the build's binary).
- Fails (exit 1) when a block exits non-zero, or when a file named by the `<!-- expect: FILE ... -->` comment that
  follows a block (paths relative to the scratch directory) is missing or empty after it.
- Skips a block, printing a note, when it needs a tool that is missing: ffmpeg (blocks with `video=true`,
  `--video` or `.mp4`) or matplotlib for the Python that `kelvin converge --plot` uses ($KELVIN_PYTHON, else
  /usr/bin/python3, else python3; blocks with `--plot` or `plot_`). The files it would have written are not checked.
Prints each block, its exit status and its time, and the total time.
"""
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

BLOCK = re.compile(r"^```sh[ \t]*\n(.*?)^```[ \t]*\n(?:[ \t]*\n)*(?:<!--\s*expect:(.*?)-->)?", re.S | re.M)


def have_ffmpeg():
    return shutil.which("ffmpeg") is not None or os.path.exists("/usr/bin/ffmpeg")


def have_matplotlib():
    python = os.environ.get("KELVIN_PYTHON") or ("/usr/bin/python3" if os.path.exists("/usr/bin/python3")
                                                 else shutil.which("python3"))
    if not python:
        return False
    return subprocess.run([python, "-c", "import matplotlib"], stdout=subprocess.DEVNULL,
                          stderr=subprocess.DEVNULL).returncode == 0


def needs(block):
    out = []
    if re.search(r"video=true|--video|\.mp4", block):
        out.append("ffmpeg")
    if re.search(r"--plot|plot_", block):
        out.append("matplotlib")
    return out


def main():
    if len(sys.argv) not in (3, 4):
        print(__doc__)
        return 2
    cli = os.path.abspath(sys.argv[1])
    source = os.path.abspath(sys.argv[2])
    tutorial = os.path.join(source, "docs", "tutorial.md")
    if not os.access(cli, os.X_OK):
        print(f"run_tutorial: {cli} is not an executable")
        return 2
    text = open(tutorial, encoding="utf-8").read()
    blocks = [(m.group(1), (m.group(2) or "").split()) for m in BLOCK.finditer(text)]
    if not blocks:
        print(f"run_tutorial: no ```sh block in {tutorial}")
        return 1
    if len(sys.argv) == 4:
        work = os.path.abspath(sys.argv[3])
        shutil.rmtree(work, ignore_errors=True)
        os.makedirs(work)
    else:
        work = tempfile.mkdtemp(prefix="kelvin-tutorial-")
    for name in ("scenes", "tools"):
        os.symlink(os.path.join(source, name), os.path.join(work, name))
    available = {"ffmpeg": have_ffmpeg(), "matplotlib": have_matplotlib()}
    prelude = f'kelvin() {{ "{cli}" "$@"; }}\n'
    failures = 0
    start = time.monotonic()
    for i, (block, expect) in enumerate(blocks, 1):
        print(f"--- block {i} of {len(blocks)} (in {work}):\n{block.rstrip()}", flush=True)
        missing = [n for n in needs(block) if not available[n]]
        if missing:
            print(f"run_tutorial: block {i} SKIPPED: {', '.join(missing)} not installed", flush=True)
            continue
        t0 = time.monotonic()
        rc = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", prelude + block], cwd=work).returncode
        dt = time.monotonic() - t0
        if rc != 0:
            print(f"run_tutorial: FAILED: block {i} exited with {rc} ({dt:.1f} s)", flush=True)
            failures += 1
            continue
        absent = [f for f in expect if not os.path.isfile(os.path.join(work, f))
                  or os.path.getsize(os.path.join(work, f)) == 0]
        if absent:
            print(f"run_tutorial: FAILED: block {i} did not write {', '.join(absent)}", flush=True)
            failures += 1
            continue
        print(f"run_tutorial: block {i} ok ({dt:.1f} s; {len(expect)} expected files present)", flush=True)
    total = time.monotonic() - start
    if failures:
        print(f"run_tutorial: {failures} of {len(blocks)} blocks FAILED ({total:.1f} s)")
        return 1
    print(f"run_tutorial: all {len(blocks)} blocks passed ({total:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
