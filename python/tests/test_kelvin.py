"""The kelvin Python module against the command line and against itself (ctest python.pytest; docs/python.md).

Run by ctest with PYTHONPATH pointing at the build's python/ folder, KELVIN_CLI at the build's kelvin and
KELVIN_SOURCE_DIR at the source tree.
"""
import os
import signal
import subprocess
import threading
import time

import numpy as np
import pytest

import kelvin

SRC = os.environ.get("KELVIN_SOURCE_DIR", os.path.join(os.path.dirname(__file__), "..", ".."))
CLI = os.environ.get("KELVIN_CLI", os.path.join(SRC, "build", "bin", "kelvin"))
CORNELL = os.path.join(SRC, "scenes", "render", "cornell-box.xml")
LAMB_OSEEN = os.path.join(SRC, "scenes", "fluid", "lamb_oseen.xml")


def cli(*args, cwd=None):
    p = subprocess.run([CLI, *args, "-q"], capture_output=True, text=True, cwd=cwd)
    assert p.returncode == 0, p.stderr
    return p


# ----------------------------------------------------------------------------------------------------- rendering

def test_render_equals_the_cli_bit_for_bit(tmp_path):
    out = tmp_path / "cli.exr"
    cli(CORNELL, "-D", "res=24", "--spp", "8", "--seed", "7", "-o", str(out))
    image = kelvin.render(kelvin.load_file(CORNELL, res=24), spp=8, seed=7)
    assert image.dtype == np.float32 and image.shape == (24, 24, 3)
    assert np.array_equal(image, kelvin.read(out))
    # Another seed is another image: the comparison can fail.
    assert not np.array_equal(image, kelvin.render(kelvin.load_file(CORNELL, res=24), spp=8, seed=8))


def test_keyword_parameters_are_the_clis_defines(tmp_path):
    out = tmp_path / "bdpt.exr"
    cli(CORNELL, "-D", "res=16", "-D", "integrator=bdpt", "-D", "max_depth=3", "--spp", "4", "-o", str(out))
    image = kelvin.render(kelvin.load_file(CORNELL, res=16, integrator="bdpt", max_depth=3), spp=4)
    assert np.array_equal(image, kelvin.read(out))


def test_run_gives_channels_statistics_and_the_work():
    r = kelvin.run(kelvin.load_file(CORNELL, res=16), spp=4, seed=1)
    assert r.channels == ["R", "G", "B"] and r.image.shape == (16, 16, 3)
    assert r.work == 4 and r.work_unit == "spp" and not r.interrupted
    assert r.stats["render.spp"] == 4 and r.stats["render.rays"] > 0
    assert np.array_equal(r.image, kelvin.render(kelvin.load_file(CORNELL, res=16), spp=4, seed=1))


def test_aov_channel_names():
    scene = kelvin.load_string("""<scene version="3.0.0">
        <integrator type="aov"><string name="aovs" value="nn:sh_normal,d:depth"/></integrator>
        <sensor type="perspective"><transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/>
            </transform><film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/></film>
            <sampler type="independent"><integer name="sample_count" value="2"/></sampler></sensor>
        <shape type="sphere"/></scene>""")
    r = kelvin.run(scene)
    assert r.image.shape == (6, 8, len(r.channels))
    assert "d.T" in r.channels or any(c.startswith("d") for c in r.channels)
    assert any(c.startswith("nn") for c in r.channels)


def test_load_dict_equals_its_xml_twin():
    xml = kelvin.load_string("""<scene version="3.0.0">
        <integrator type="path"><integer name="max_depth" value="4"/></integrator>
        <sensor type="perspective"><float name="fov" value="40"/>
            <transform name="to_world"><lookat origin="0, 1, 6" target="0, 0, 0" up="0, 1, 0"/></transform>
            <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
            <film type="hdrfilm"><integer name="width" value="20"/><integer name="height" value="16"/></film>
        </sensor>
        <bsdf type="diffuse" id="red"><rgb name="reflectance" value="0.8, 0.15, 0.1"/></bsdf>
        <shape type="sphere"><ref id="red"/></shape>
        <shape type="sphere"><point name="center" x="0" y="-101" z="0"/><float name="radius" value="100"/>
            <bsdf type="diffuse"><rgb name="reflectance" value="0.6"/></bsdf></shape>
        <emitter type="point"><point name="position" x="2" y="4" z="3"/><rgb name="intensity" value="40"/></emitter>
    </scene>""")
    d = kelvin.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 4},
        "sensor": {"type": "perspective", "fov": 40.0,
                   "to_world": kelvin.Transform.look_at(origin=[0, 1, 6], target=[0, 0, 0], up=[0, 1, 0]),
                   "sampler": {"type": "independent", "sample_count": 4},
                   "film": {"type": "hdrfilm", "width": 20, "height": 16}},
        "red": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.15, 0.1]}},
        "ball": {"type": "sphere", "bsdf": {"type": "ref", "id": "red"}},
        "floor": {"type": "sphere", "center": kelvin.point(0, -101, 0), "radius": 100.0,
                  "bsdf": {"type": "diffuse", "reflectance": kelvin.rgb(0.6)}},
        "lamp": {"type": "point", "position": [2, 4, 3], "intensity": kelvin.rgb(40)},
    })
    a, b = kelvin.render(xml, seed=3), kelvin.render(d, seed=3)
    assert a.mean() > 0 and np.array_equal(a, b)


def test_transform_matrices_are_row_major():
    t = kelvin.Transform.translate([1, 2, 3])
    assert np.array_equal(t.matrix[:3, 3], [1, 2, 3])
    assert np.array_equal(kelvin.Transform(t.matrix).matrix, t.matrix)
    s = kelvin.Transform.scale(2) @ t  # t first, then the scale
    assert np.array_equal(s.matrix[:3, 3], [2, 4, 6])


def test_write_and_read_round_trip(tmp_path):
    a = np.random.default_rng(1).random((5, 7, 3), dtype=np.float32)
    kelvin.write(tmp_path / "a.exr", a)
    assert np.array_equal(kelvin.read(tmp_path / "a.exr"), a)
    kelvin.write(tmp_path / "b.exr", a[:, :, :2], channels=["u", "v"])
    assert kelvin.read_channels(tmp_path / "b.exr") == ["u", "v"]
    kelvin.write(tmp_path / "c.png", a)
    assert kelvin.read(tmp_path / "c.png").shape[:2] == (5, 7)
    a[1, 2, 0] = np.nan
    with pytest.raises(kelvin.RunError, match="pixel \\(2, 1\\)"):
        kelvin.write(tmp_path / "a.exr", a)  # numerical trouble is never written
    assert np.isfinite(kelvin.read(tmp_path / "a.exr")).all()


# -------------------------------------------------------------------------------------------------------- errors

def test_a_typo_in_a_keyword_parameter_names_it():
    with pytest.raises(kelvin.Error, match="'rez'.*did you mean 'res'") as e:
        kelvin.load_file(CORNELL, rez=16)
    assert isinstance(e.value, ValueError)
    kelvin.load_file(CORNELL, rez=16, allow_unused=True)  # a warning only


def test_a_typo_in_the_scene_names_file_line_and_column(tmp_path):
    path = tmp_path / "typo.xml"
    path.write_text('<scene version="3.0.0">\n  <integrator type="path">\n'
                    '    <integer name="max_dpth" value="3"/>\n  </integrator>\n</scene>\n')
    with pytest.raises(kelvin.Error) as e:
        kelvin.load_file(path)
    assert e.value.file == str(path) and e.value.line == 3 and e.value.column == 5
    assert "max_dpth" in str(e.value) and "max_depth" in e.value.message


def test_a_bad_value_in_a_dict_names_its_key():
    with pytest.raises(kelvin.Error, match="dict:integrator.max_depth"):
        kelvin.load_dict({"type": "scene", "integrator": {"type": "path", "max_depth": "deep"}})
    with pytest.raises(kelvin.Error, match="dict:sensor.film.width"):
        kelvin.load_dict({"type": "scene", "sensor": {"type": "perspective", "film": {"type": "hdrfilm",
                                                                                      "width": [1, 2]}}})
    with pytest.raises(kelvin.Error, match="dict:integrator.max_depth.*cannot be a scene parameter"):
        kelvin.load_dict({"type": "scene", "integrator": {"type": "path", "max_depth": object()}})


def test_bad_run_settings_are_errors():
    scene = kelvin.load_file(CORNELL, res=8)
    for kwargs in ({"seed": -1}, {"seed": 2 ** 64}, {"spp": 0}, {"time_limit": float("nan")}, {"threads": -2}):
        with pytest.raises(kelvin.Error):
            kelvin.render(scene, **kwargs)


# --------------------------------------------------------------------------------------- progress and threads

def test_progress_reaches_the_callback():
    reports = []
    kelvin.render(kelvin.load_file(CORNELL, res=16), spp=8, progress=reports.append)
    assert reports and reports[-1]["final"] and reports[-1]["done"] == 8 and reports[-1]["unit"] == "spp"
    assert all(0 <= r["fraction"] <= 1 for r in reports)


def test_an_exception_in_the_callback_stops_the_render():
    def boom(report):
        raise ZeroDivisionError("from the callback")
    with pytest.raises(ZeroDivisionError):
        kelvin.render(kelvin.load_file(CORNELL, res=16), spp=100000, progress=boom)


def test_two_threads_render_at_once():
    scenes = [kelvin.load_file(CORNELL, res=20), kelvin.load_file(CORNELL, res=20, integrator="bdpt")]
    alone = [kelvin.render(s, spp=4, seed=2) for s in scenes]
    together = [None, None]

    def work(i):
        together[i] = kelvin.render(scenes[i], spp=4, seed=2)
    threads = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(np.array_equal(a, b) for a, b in zip(alone, together))


def test_ctrl_c_stops_a_render_promptly_and_keeps_the_image():
    scene = kelvin.load_file(CORNELL, res=256)
    started = threading.Event()
    sent = {}

    def progress(report):
        if report["done"] >= 1 and not started.is_set():
            started.set()

    def interrupt():
        started.wait(30)
        time.sleep(0.2)
        sent["cpu"] = time.process_time()
        os.kill(os.getpid(), signal.SIGINT)

    t = threading.Thread(target=interrupt)
    t.start()
    with pytest.raises(KeyboardInterrupt) as e:
        kelvin.render(scene, spp=1000000, threads=1, progress=progress)
    cpu_after = time.process_time() - sent["cpu"]
    t.join()
    assert cpu_after < 0.5, f"{cpu_after:.2f} s of CPU between SIGINT and KeyboardInterrupt"
    partial = e.value.result
    assert partial.interrupted and 1 <= partial.work < 1000000
    assert partial.image.shape == (256, 256, 3) and np.isfinite(partial.image).all() and partial.image.mean() > 0


# --------------------------------------------------------------------------------------------------- simulations

def test_a_simulation_stepped_from_python_equals_the_cli_run(tmp_path):
    out = tmp_path / "lo.exr"
    cli(LAMB_OSEEN, "-D", "res=16", "-D", "end=0.3", "-D", "every=0", "--spp", "32", "--seed", "4", "-o", str(out))
    sim = kelvin.Simulation(kelvin.load_file(LAMB_OSEEN, res=16, end=0.3, every=0), spp=32, seed=4)
    assert sim.dimension == 2 and sim.time == 0
    taken = sim.run()
    assert taken == sim.steps == sim.step_index and abs(sim.time - 0.3) < 1e-12
    fields = kelvin.read(out)
    names = kelvin.read_channels(out)
    omega = fields[:, :, names.index("vorticity")]
    # The EXR holds float32, top row first (an image); the solver's grid holds doubles, row j = 0 at y = min.
    assert np.array_equal(np.flipud(sim.vorticity()).astype(np.float32), omega)
    u = fields[:, :, names.index("u")]
    assert np.array_equal(np.flipud(sim.velocity()[:, :, 0]).astype(np.float32), u)


def test_pointwise_queries_agree_with_the_grid():
    sim = kelvin.Simulation(kelvin.load_file(LAMB_OSEEN, res=12), spp=16, seed=1)
    sim.step()
    centres = sim.cell_centers().reshape(-1, 2)
    assert np.allclose(sim.vorticity_at(centres), sim.vorticity().reshape(-1), rtol=1e-12, atol=1e-12)
    v = sim.velocity_at(centres[:5])
    assert v.shape == (5, 2) and np.isfinite(v).all()
    assert np.array_equal(v, sim.velocity_at(centres[:5]))  # a fixed stream per (seed, step, x)
    d = sim.diagnostics()
    assert d["step"] == 1 and d["kinetic_energy"] > 0
    with pytest.raises(kelvin.Error, match="shape \\(N, 2\\)"):
        sim.velocity_at(np.zeros((3, 3)))


def test_a_3d_simulation():
    sim = kelvin.Simulation(kelvin.load_file(os.path.join(SRC, "scenes", "fluid", "taylor_green_3d.xml"), res=8),
                            spp=16, seed=2)
    assert sim.dimension == 3
    sim.step()
    w = sim.vorticity()
    assert w.shape == (8, 8, 8, 3) and np.isfinite(w).all() and np.abs(w).max() > 0
    assert sim.velocity().shape == (8, 8, 8, 3)
    assert np.allclose(sim.vorticity_at(sim.cell_centers().reshape(-1, 3)[:10]), w.reshape(-1, 3)[:10])


# ------------------------------------------------------------------------------------------- studies and MLT

def test_converge_rows_equal_the_clis(tmp_path):
    ref = tmp_path / "ref.exr"
    kelvin.write(ref, kelvin.render(kelvin.load_file(CORNELL, res=12), spp=64, seed=99))
    cli("converge", CORNELL, "-D", "res=12", "--reference", str(ref), "--config", "path:integrator=path",
        "--config", "bdpt:integrator=bdpt", "--spp", "1,4", "--runs", "2", "-o", str(tmp_path / "cli"))
    rows = kelvin.converge(CORNELL, {"path": {"integrator": "path"}, "bdpt": {"integrator": "bdpt"}}, reference=ref,
                           spp=[1, 4], runs=2, output=tmp_path / "py", res=12)
    import csv
    with open(tmp_path / "cli" / "convergence.csv", newline="") as f:
        expected = list(csv.DictReader(f))
    assert len(rows) == len(expected) == 8
    for got, want in zip(rows, expected):
        for key in ("config", "run", "seed", "target", "work", "mse", "rel_mse"):
            assert str(got[key]) == want[key] or float(got[key]) == float(want[key]), key


def test_metropolis_runs_and_writes_its_stage_map_beside_the_output(tmp_path):
    scene = kelvin.load_file(os.path.join(SRC, "scenes", "render", "mlt-study.xml"), res=16)
    r = kelvin.run(scene, spp=4, seed=1, output=tmp_path / "mlt.exr")
    assert r.work_unit == "mutations/px" and r.image.shape[:2] == (16, 16) and np.isfinite(r.image).all()
    assert "mlt.chains" in r.stats or any(k.startswith("mlt.") for k in r.stats)
    assert any(p.name.startswith("mlt") and p.name != "mlt.exr" for p in tmp_path.iterdir())
