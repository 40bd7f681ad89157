"""Kelvin: Monte Carlo light transport and Monte Carlo fluid simulation, from Python.

    import kelvin
    scene = kelvin.load_file("scenes/render/cornell-box.xml", res=128)   # keyword arguments: the scene's -D parameters
    image = kelvin.render(scene, spp=16, seed=0)                         # numpy float32 (height, width, channels)
    kelvin.write("cornell.exr", image)

    sim = kelvin.Simulation(kelvin.load_file("scenes/fluid/lamb_oseen.xml", res=32), spp=64)
    sim.step()
    omega = sim.vorticity()                                              # numpy (ny, nx)

Errors in scenes and parameters raise kelvin.Error (a ValueError with file, line and column); a run that fails
raises kelvin.RunError. Ctrl-C stops a render or a step within a fraction of a second and raises KeyboardInterrupt,
with what was computed in its `result` attribute. See docs/python.md.
"""
from . import _kelvin
from ._kelvin import (  # noqa: F401
    Error,
    Result,
    RunError,
    Scene,
    Simulation,
    Transform,
    __version__,
    data_directory,
    load_dict,
    load_file,
    load_string,
    point,
    read,
    read_channels,
    render,
    rgb,
    run,
    vector,
    write,
)

__all__ = [
    "Error", "Result", "RunError", "Scene", "Simulation", "Transform", "converge", "data_directory", "load_dict", "load_file", "load_string",
    "point", "read", "read_channels", "render", "rgb", "run", "vector", "write",
]


def _params(d):
    """Scene parameters as the -D strings the scene parser reads."""
    return {str(k): ("true" if v is True else "false" if v is False else str(v)) for k, v in (d or {}).items()}


def converge(scene, configs, *, reference=None, checkpoints=None, spp=None, steps=None, times=None, runs=1, seed=0,
             fields=None, window=None, disk=None, pixels=None, epsilon=0.01, output=None, images="first",
             allow_unused=False, threads=None, **params):
    """A convergence study, as `kelvin converge` runs it (docs/convergence.md): every configuration, `runs` runs
    each, measured at the checkpoints (exactly one of `checkpoints` (compute seconds), `spp`, `steps`, `times`)
    against `reference` (renders; simulations default to the exact solution). `configs` maps a configuration's name
    to its scene parameters ({"path": {"integrator": "path"}}); keyword arguments are parameters of every
    configuration. The CSV goes to `output` (default: <scene>_converge) and an existing study there is resumed.
    Returns the CSV's rows as a list of dicts (numbers as floats). Ctrl-C stops it, dropping the run in progress."""
    import csv as _csv
    import os as _os

    scene = _os.fspath(scene)
    if output is None:
        output = _os.path.splitext(_os.path.basename(scene))[0] + "_converge"
    if isinstance(configs, dict):
        configs = list(configs.items())
    configs = [(str(name), _params(p)) for name, p in configs]
    csv_path, _stats, interrupted, _done, _skipped = _kelvin._converge(
        scene, configs, _params(params), None if reference is None else _os.fspath(reference),
        list(checkpoints or []), list(spp or []), list(steps or []), list(times or []), runs, seed,
        list(fields or []), window, disk, pixels, epsilon, _os.fspath(output), images, allow_unused, threads)
    rows = []
    with open(csv_path, newline="") as f:
        for row in _csv.DictReader(f):
            for k, v in row.items():
                try:
                    row[k] = float(v)
                except (TypeError, ValueError):
                    pass
            rows.append(row)
    return rows
