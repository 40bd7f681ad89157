#!/usr/bin/python3
"""tools/run_spread.py against a known answer (ctest: converge.run_spread).

    test_run_spread.py SCRIPT OUTDIR

Synthetic `kelvin converge` studies with a known true image T (smooth, with a band 50x brighter and a band of
exact black), a noisy reference R = T + noise, and two configurations of 5 runs and 2 checkpoints each: "a",
unbiased with per-pixel standard deviation s (s / sqrt 2 at the second checkpoint), and "b", with 0.7 s and a
fixed bias of 0.05 T, which the spread must not see. Over 6 independent studies (fixed seed) the tool must give:

- the spread of "a" and "b": the exact variance part of a run's relative MSE, mean of s^2 / (R^2 + eps) over pixels
  and channels (R the study's own reference, as the tool weighs), within 5 standard errors of the per-study
  spread (the estimator is unbiased given R: no allowance beyond the scatter);
- the ratio b / a: 0.49 within 5 standard errors, and the jackknife standard error the tool prints within
  a factor 2.5 of the spread of the ratio across studies (it is what the docs quote).

The images are PFM files named in the CSV (the tool reads a PNG's EXR sibling, or the named file). A spread
without the 1/2 (the variance of a difference taken for a run's variance) fails by far, and so does one weighted by
the runs' own pixels instead of the reference's. Bad input (not a study, one run per configuration) must be one line
and exit 2. Skipped (exit 0, "SKIPPED") without OpenImageIO's Python module, which the tool reads images with.
"""
import csv
import os
import re
import shutil
import subprocess
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from synthetic_images import test_arguments, true_image, write_pfm  # noqa: E402

EPS = 0.01
COLUMNS = ["config", "run", "seed", "trigger", "target", "seconds", "work", "unit", "sim_time", "mse", "rmse",
           "rel_mse", "l1", "rel_l1", "max_abs", "ssim", "image"]


def make_study(d, rng, t, s):
    """One study in d; returns the reference (float32-rounded, as float64)."""
    shutil.rmtree(d, ignore_errors=True)
    os.makedirs(d)
    r = (t + 0.5 * s * rng.standard_normal(t.shape)).astype(np.float32)
    write_pfm(os.path.join(d, "ref.pfm"), r)
    r = r.astype(float)
    w = 1.0 / (r * r + EPS)
    with open(os.path.join(d, "convergence.settings"), "w") as f:
        f.write("# synthetic\nkind: render\ncheckpoints: seconds 1,2\n")
        f.write(f"reference: {os.path.join(d, 'ref.pfm')}\nepsilon: {EPS:g}\n")
    rows = []
    for config, sd, bias in (("a", 1.0, 0.0), ("b", 0.7, 0.05)):
        os.makedirs(os.path.join(d, "images", config))
        for run in range(5):
            for target, scale in (("1", 1.0), ("2", 1 / np.sqrt(2))):
                x = (t * (1 + bias) + sd * scale * s * rng.standard_normal(t.shape)).astype(np.float32)
                rel = f"images/{config}/run{run}_seconds{target}.pfm"
                write_pfm(os.path.join(d, rel), x)
                rel_mse = float(np.mean((x.astype(float) - r) ** 2 * w))
                rows.append([config, run, run, "seconds", target, target, 0, "mutations/px", "", 0, 0, rel_mse, 0, 0,
                             0, 0, rel])
    with open(os.path.join(d, "convergence.csv"), "w", newline="") as f:
        c = csv.writer(f)
        c.writerow(COLUMNS)
        c.writerows(rows)
    return r


def parse(stdout):
    """config -> list of the cells of its table row."""
    rows = {}
    for line in stdout.splitlines():
        if line.startswith("| ") and not line.startswith("| variant"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            rows[cells[0]] = cells[1:]
    return rows


def value(cell):
    return float(re.split(r"\s*\+-\s*", cell)[0])


def se(cell):
    return float(re.split(r"\s*\+-\s*", cell)[1])


def main():
    script, out = test_arguments("test_run_spread")
    rng = np.random.default_rng(7)
    t = true_image(40, 48, 20, 12, 50.0)
    s = np.where(t > 0, 0.02 + 0.1 * t, 0.0)
    failures = []

    # Bad input: a directory that is not a study; then a study with a single run.
    r = subprocess.run([sys.executable, script, out], capture_output=True, text=True)
    if r.returncode != 2 or len(r.stderr.strip().splitlines()) != 1:
        failures.append(f"not a study: exit {r.returncode}, '{r.stderr.strip()}'")

    got = {k: [] for k in ("a1", "a2", "b2", "ratio", "ratio_se")}
    want = {k: [] for k in ("a1", "a2", "b2")}
    draws = 6
    for draw in range(draws):
        d = os.path.join(out, f"study{draw}")
        ref = make_study(d, rng, t, s)
        wgt = 1.0 / (ref * ref + EPS)
        r = subprocess.run([sys.executable, script, d], capture_output=True, text=True)
        if r.returncode != 0:
            sys.exit(f"run_spread.py failed: {r.stderr}")
        rows = parse(r.stdout)
        # cells: runs, spread at 1, x a at 1, spread at 2, x a at 2
        got["a1"].append(value(rows["a"][1]))
        got["a2"].append(value(rows["a"][3]))
        got["b2"].append(value(rows["b"][3]))
        got["ratio"].append(value(rows["b"][4]))
        got["ratio_se"].append(se(rows["b"][4]))
        want["a1"].append(float(np.mean(s * s * wgt)))
        want["a2"].append(float(np.mean(s * s * wgt)) / 2)
        want["b2"].append(0.49 * float(np.mean(s * s * wgt)) / 2)

    def check(name, est, tru):
        d = np.array(est) - np.array(tru)
        tol = 5 * d.std(ddof=1) / np.sqrt(len(d))
        print(f"{name}: estimate {np.mean(est):.6g}, exact {np.mean(tru):.6g}, difference {d.mean():.3g} "
              f"(tolerance {tol:.3g})")
        if abs(d.mean()) > tol:
            failures.append(name)

    check("spread a at 1", got["a1"], want["a1"])
    check("spread a at 2", got["a2"], want["a2"])
    check("spread b at 2", got["b2"], want["b2"])
    check("ratio b / a at 2", got["ratio"], [0.49] * draws)
    spread_sd = float(np.std(got["ratio"], ddof=1))
    quoted = float(np.mean(got["ratio_se"]))
    print(f"ratio's standard error: quoted {quoted:.3g}, seen across studies {spread_sd:.3g}")
    if not (spread_sd / 2.5 < quoted < spread_sd * 2.5):
        failures.append("ratio's standard error")

    # A study with one run per configuration cannot give a spread.
    d = os.path.join(out, "study0")
    rows = list(csv.DictReader(open(os.path.join(d, "convergence.csv"))))
    with open(os.path.join(d, "convergence.csv"), "w", newline="") as f:
        c = csv.DictWriter(f, fieldnames=COLUMNS)
        c.writeheader()
        c.writerows([row for row in rows if row["run"] == "0"])
    r = subprocess.run([sys.executable, script, d], capture_output=True, text=True)
    if r.returncode != 2 or len(r.stderr.strip().splitlines()) != 1:
        failures.append(f"one run: exit {r.returncode}, '{r.stderr.strip()}'")

    if failures:
        sys.exit(f"test_run_spread: wrong: {', '.join(failures)}")
    print("test_run_spread: passed")


if __name__ == "__main__":
    main()
