"""Results a user can open, and large runs that stay safe.

* The ``.vtu`` series against an analytic solution: a bar stretched uniaxially (SVK, ν = 0) has a homogeneous state,
  ``F = diag(λ, 1, 1)``, so every cell's Cauchy stress, von Mises stress, strain and det F are known exactly; the
  files are read back with meshio and pyvista, and their displacement is cross-checked with ``solution.npz``.
* ``probes.csv`` carries σ columns after ``--uncertainty`` (the same numbers as ``summary.json``'s ``probes_std``).
* A run that would not fit in memory is refused before assembly (exit 2, the estimate in the message, the folder
  untouched); a SIGINT during a Newton solve stops the run within seconds (exit 130, the folder consistent).
* A main thread stuck in one long compiled call is ended ``FORCE_S`` after a signal, its last-resort action run.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import meshio
import numpy as np
import pytest

from fenicsfoam.cli import main as fenicsfoam_main
from fenicsfoam.io import read_solution
from fenicsfoam.scene import run_scene

L = 0.06
STRETCH = (1.01, 1.1)  # λ at the end of each step
E = 1e6

BAR = f"""name = "bar"
probes = ["displacement:tip"]
[geometry]
builder = "beam"
length = {L}
width = 0.01
height = 0.01
h = 0.005
[fem]
model = "svk"
degree = 1
[regions.beam]
tags = "beam"
material = "isotropic"
E = {E}
nu = 0.0
rho = 1000.0
[loads]
clamp = "clamped"
[loads.motion.pull]
group = "tip"
[[steps]]
label = "small"
motions = {{pull = {{translation = [{(STRETCH[0] - 1) * L}, 0.0, 0.0]}}}}
[[steps]]
label = "large"
increments = 2
motions = {{pull = {{translation = [{(STRETCH[1] - 1) * L}, 0.0, 0.0]}}}}
[outputs]
png = false
"""


@pytest.fixture(scope="module")
def bar(tmp_path_factory):
    out = tmp_path_factory.mktemp("bar") / "out"
    scene = out.parent / "bar.toml"
    scene.write_text(BAR)
    return run_scene(scene, out), out


def test_the_series_holds_the_analytic_state_of_a_stretched_bar(bar):
    """meshio reads every step's file: the homogeneous uniaxial state of SVK, exactly (P1 represents it)."""
    result, out = bar
    solution = read_solution(out)
    for index, (label, stretch) in enumerate(zip(("small", "large"), STRETCH)):
        mesh = meshio.read(out / f"solution_{index:03d}_{label}.vtu")
        assert mesh.cells[0].type == "tetra" and len(mesh.cells[0].data) == result.n_cells
        assert np.array_equal(mesh.points, solution.points) and np.array_equal(mesh.cells[0].data, solution.cells)
        u = mesh.point_data["displacement"]
        assert np.allclose(u, solution.displacement(label), rtol=0, atol=1e-15)  # the npz says the same
        assert np.allclose(u[:, 0], (stretch - 1) * mesh.points[:, 0], rtol=0, atol=1e-9 * L)
        cells = {name: values[0] for name, values in mesh.cell_data.items()}
        green = (stretch**2 - 1) / 2
        sigma = np.zeros((len(u), 9))
        sigma = cells["cauchy_stress"]
        expected = np.zeros(9)
        expected[0] = stretch * E * green  # σ = P Fᵀ / J with P = F S, S = E E (ν = 0)
        assert np.allclose(sigma, expected, rtol=0, atol=1e-6 * E * green)
        assert np.allclose(cells["von_mises"], expected[0], rtol=1e-6)
        assert np.allclose(cells["equivalent_strain"], 2 / 3 * green, rtol=1e-6)
        assert np.allclose(cells["det_F"], stretch, rtol=1e-9)
        assert np.all(cells["region"] == 1) and np.all(np.isnan(cells["density"]))
        assert np.all(cells["ellipticity_margin"] > 0)
        assert bytes(mesh.field_data["step_label"].ravel()).decode() == label
        assert int(mesh.field_data["step_index"].ravel()[0]) == index
        assert np.allclose(mesh.field_data["translation_m:pull"].ravel(), [(stretch - 1) * L, 0, 0])


def test_pyvista_reads_the_collection_one_time_per_step(bar):
    pyvista = pytest.importorskip("pyvista")
    result, out = bar
    reader = pyvista.PVDReader(out / "solution.pvd")
    assert reader.time_values == [0.0, 1.0]
    assert [Path(d.path).name for d in reader.datasets] == ["solution_000_small.vtu", "solution_001_large.vtu"]
    reader.set_active_time_value(1.0)
    grid = reader.read()[0]
    assert grid.n_cells == result.n_cells
    assert np.allclose(grid.cell_data["det_F"], STRETCH[1])
    assert bytes(np.asarray(grid.field_data["step_label"]).ravel()).decode() == "large"
    single = pyvista.read(out / "solution_001_large.vtu")  # one step's file on its own
    assert np.array_equal(single.cell_data["cauchy_stress"], grid.cell_data["cauchy_stress"])
    assert np.array_equal(single.point_data["displacement"], read_solution(out).displacement("large"))
    summary = json.loads((out / "summary.json").read_text())
    assert {"solution.pvd", "solution_000_small.vtu", "solution_001_large.vtu", "run.log"} <= set(summary["files"])
    log = (out / "run.log").read_text()
    assert "Newton iteration" in log and f"{result.n_dofs} dofs" in log


def test_a_foam_scene_writes_its_density_gamma_and_l_axis(tmp_path):
    """A graded TI foam: per-cell density and γ (the scene's functions), the l axis, written in input order."""
    scene = {
        "name": "graded", "probes": ["tip_deflection"],
        "geometry": {"builder": "beam", "length": 0.06, "width": 0.01, "height": 0.01, "h": 0.006},
        "fem": {"model": "linear", "degree": 1},
        "regions": {"beam": {"tags": "beam", "material": "foam", "density": 0.15, "gamma": 0.2,
                             "E_solid": 12e6, "nu_solid": 0.3, "rho_solid": 1190.0, "fit": "transverse"}},
        "orientation": {"kind": "uniform", "direction": [0.0, 1.0, 0.0]},
        "loads": {"gravity": [0.0, 0.0, -9.81], "clamp": "clamped"},
        "steps": [{"label": "g", "gravity": 1.0}], "outputs": {"png": False},
    }
    run_scene(scene, tmp_path / "out")
    mesh = meshio.read(tmp_path / "out" / "solution_000_g.vtu")
    cells = {name: values[0] for name, values in mesh.cell_data.items()}
    assert np.allclose(cells["density"], 0.15) and np.allclose(cells["gamma"], 0.2)
    assert np.allclose(cells["l_axis"], [0.0, 1.0, 0.0])


def test_uncertainty_writes_sigma_columns_into_probes_csv(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text(textwrap.dedent("""\
        name = "u"
        probes = ["tip_deflection", "displacement:tip"]
        [geometry]
        builder = "beam"
        length = 0.06
        width = 0.01
        height = 0.01
        h = 0.008
        [fem]
        model = "linear"
        degree = 1
        [regions.beam]
        tags = "beam"
        material = "foam"
        density = 0.15
        gamma = 0.2
        E_solid = 12e6
        nu_solid = 0.3
        rho_solid = 1190.0
        fit = "transverse"
        [orientation]
        kind = "uniform"
        direction = [1.0, 0.0, 0.0]
        [loads]
        gravity = [0.0, 0.0, -9.81]
        clamp = "clamped"
        [[steps]]
        label = "g"
        gravity = 1.0
        [outputs]
        png = false
        xdmf = false
        """))
    assert fenicsfoam_main(["run", str(scene), "--out", str(tmp_path / "out"), "--uncertainty"]) == 0
    lines = (tmp_path / "out" / "probes.csv").read_text().splitlines()
    header, row = lines[0].split(","), lines[1].split(",")
    assert header[:3] == ["step", "tip_deflection_m", "tip_deflection_std_m"]
    assert "displacement:tip_z_std_m" in header
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    std = summary["steps"][0]["probes_std"]
    assert float(row[2]) == std["tip_deflection"] > 0
    assert float(row[header.index("displacement:tip_z_std_m")]) == std["displacement:tip"][2]


def test_an_oversized_run_is_refused_before_assembly(tmp_path, monkeypatch, capsys):
    """With 100 MB available the estimate does not fit: exit 2, the estimate in the message, nothing written."""
    scene = tmp_path / "bar.toml"
    scene.write_text(BAR)
    monkeypatch.setenv("FENICSFOAM_AVAILABLE_MEMORY", str(100 * 2**20))
    status = fenicsfoam_main(["run", str(scene), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert status == 2
    # neither solver fits: auto falls back to the iterative one, which does not fit either
    assert re.search(r"\d+ cells, \d+ dofs on 1 rank\(s\), iterative solver .*estimated \d+ MB of memory "
                     r"\(100 MB available\)", err), err
    assert "--force" in err and not (tmp_path / "out").exists()
    # forced, it runs (the estimate is only an estimate)
    assert fenicsfoam_main(["run", str(scene), "--out", str(tmp_path / "out"), "--force"]) == 0


SLOW_BEAM = """name = "slow"
probes = ["tip_deflection"]
[geometry]
builder = "beam"
length = 0.25
width = 0.015
height = 0.015
h = 0.006
[fem]
model = "corotational"
degree = 2
[regions.beam]
tags = "beam"
material = "isotropic"
E = 2e5
nu = 0.3
rho = 200.0
[loads]
gravity = [0.0, 0.0, -9.81]
clamp = "clamped"
""" + "".join(f'[[steps]]\nlabel = "s{i}"\ngravity = {(i + 1) / 20}\nincrements = 2\n' for i in range(20))


def test_sigint_during_a_newton_solve_stops_within_seconds(tmp_path):
    """SIGINT once the log shows Newton iterations: exit 130 within a few seconds, the folder consistent."""
    (tmp_path / "slow.toml").write_text(SLOW_BEAM)
    out = tmp_path / "out"
    process = subprocess.Popen([sys.executable, "-m", "fenicsfoam.cli", "run", "slow.toml", "--out", "out"],
                               cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True)
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and process.poll() is None:
            if (out / "run.log").exists() and "Newton iteration 1," in (out / "run.log").read_text():
                break
            time.sleep(0.05)
        assert process.poll() is None, process.communicate()
        sent = time.monotonic()
        process.send_signal(signal.SIGINT)
        stdout, stderr = process.communicate(timeout=60)
        stopped = time.monotonic() - sent
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
    assert process.returncode == 130, stderr
    assert stopped < 8.0  # seconds, on a loaded machine; typically under 2
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and "SIGINT" in summary["error"]
    assert "compiled call" not in summary["error"]  # stopped by the solver's monitors, not by the watcher's deadline
    names = {p.name for p in out.iterdir()}
    assert not [n for n in names if n.startswith(".")]  # no temporary left
    assert names <= {"summary.json", "probes.csv", "run.log", "solution.pvd", *(
        f"solution_{i:03d}_s{i}.vtu" for i in range(len(summary["steps"])))}
    assert set(summary["files"]) == names
    assert "steps done" in summary["error"] and "INTERRUPTED" in stdout  # the table of the steps done


def test_a_main_thread_stuck_in_compiled_code_is_ended_after_force_s(tmp_path):
    script = tmp_path / "stuck.py"
    marker = tmp_path / "marker"
    script.write_text(textwrap.dedent(f"""
        import hashlib
        from pathlib import Path
        from foambase.signals import interruptible, register_last_resort
        with interruptible():
            register_last_resort(lambda name: Path({str(marker)!r}).write_text(name))
            print("ready", flush=True)
            hashlib.pbkdf2_hmac("sha256", b"x", b"y", 10**9)  # minutes in C without running Python
        """))
    process = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True,
                               start_new_session=True)
    try:
        assert process.stdout.readline().strip() == "ready"
        time.sleep(0.2)
        sent = time.monotonic()
        process.send_signal(signal.SIGTERM)
        process.communicate(timeout=60)
        stopped = time.monotonic() - sent
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
    from foambase.signals import FORCE_S
    assert process.returncode == 143 and FORCE_S - 0.5 < stopped < FORCE_S + 3
    assert marker.read_text() == "SIGTERM"


def test_the_solver_by_size():
    from fenicsfoam.sizing import ITERATIVE_ABOVE_DOFS, choose_solver, estimate
    from foambase.errors import InputError

    assert choose_solver("auto", 10_000) == "direct"
    assert choose_solver("auto", 10_000, direct_fits=False) == "iterative"
    assert choose_solver("auto", ITERATIVE_ABOVE_DOFS + 1) == "iterative"
    assert choose_solver("direct", 10**8) == "direct"
    with pytest.raises(InputError, match="solver must be one of auto, direct, iterative"):
        choose_solver("lu", 10)
    # the model against two measurements of the benchmark page (P2 beam, 83 166 and 37 770 dofs)
    assert estimate(16595, 83166, "direct", available=1e12).memory_bytes == pytest.approx(866 * 2**20, rel=0.05)
    assert estimate(6974, 37770, "iterative", available=1e12).memory_bytes == pytest.approx(264 * 2**20, rel=0.05)
    assert not estimate(0, 10**6, "direct", available=4e9).fits


def test_the_iterative_solver_reaches_the_same_state(tmp_path):
    """Krylov + GAMG (forced): the stretched bar's analytic state again, and the summary says which solver ran."""
    scene = tmp_path / "bar.toml"
    scene.write_text(BAR.replace("png = false", "png = false\nxdmf = false"))
    result = run_scene(scene, tmp_path / "out", solver="iterative")
    assert result.estimate["solver"] == "iterative"
    u = result.displacement
    x = u.function_space.tabulate_dof_coordinates()
    values = u.x.array.reshape(-1, 3)
    assert np.allclose(values[:, 0], (STRETCH[1] - 1) * x[:, 0], rtol=0, atol=1e-7 * L)  # every node, not only
    assert np.allclose(values[:, 1:], 0.0, rtol=0, atol=1e-7 * L)                      # the prescribed ones


def test_progress_shows_on_a_terminal(tmp_path):
    """stderr a terminal (a pseudo-terminal here): a status line rewritten in place with the Newton iterations."""
    import pty

    scene = tmp_path / "bar.toml"
    scene.write_text(BAR.replace("png = false", "png = false\nxdmf = false"))
    leader, follower = pty.openpty()
    process = subprocess.Popen([sys.executable, "-m", "fenicsfoam.cli", "run", str(scene), "--out",
                                str(tmp_path / "out")], stdout=subprocess.DEVNULL, stderr=follower)
    os.close(follower)
    shown = b""
    while True:
        try:
            chunk = os.read(leader, 4096)
        except OSError:  # the terminal closed with the process
            break
        if not chunk:
            break
        shown += chunk
    os.close(leader)
    assert process.wait(timeout=60) == 0
    text = shown.decode(errors="replace")
    assert re.search(r"\rstep large, load factor 1: Newton iteration \d, residual", text), text[-500:]
    assert "step 2/2 large: done" in text
