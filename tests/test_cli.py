"""One command line, one exit-code table (0 ok, 1 other failure, 2 bad input, 3 did not converge), quiet output.

``fenicsfoam homogenize`` and the ``homogenize`` program are the same command; ``fenicsfoam run`` under
``mpirun -n 2`` exits like the serial run. The ``mpirun`` case spawns its own ``mpirun`` (not marked ``mpi``).
"""

import io
import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fenicsfoam.cli import main
from foambase.logs import setup_logging

BIN = Path(sys.executable).parent
MPI_ENV = {"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
           "OMPI_MCA_btl_vader_single_copy_mechanism": "none", "OMPI_MCA_rmaps_base_oversubscribe": "1"}
BEAM = """name = "quiet_beam"
probes = ["tip_deflection"]
[geometry]
builder = "beam"
h = 0.0075
[regions.beam]
tags = "beam"
material = "isotropic"
E = 1e6
nu = 0.3
rho = 1000.0
[loads]
gravity = [0.0, 0.0, -9.81]
clamp = "clamped"
[[steps]]
label = "gravity"
gravity = 1.0
[outputs]
xdmf = false
png = false
"""


def command(name: str) -> list[str]:
    script = BIN / name
    module = "fenicsfoam.cli" if name == "fenicsfoam" else "homogenization.cli"
    return [str(script)] if script.exists() else [sys.executable, "-m", module]


def run(argv: list[str], env: dict | None = None, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(argv, capture_output=True, text=True, env={**os.environ, **(env or {})}, cwd=cwd,
                          timeout=600)


@pytest.fixture
def image(tmp_path):
    """A solid with a spherical pore and a channel along x (8³): CG needs several iterations."""
    x = (np.arange(8) + 0.5) / 8 - 0.5
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    path = tmp_path / "porous.npy"
    np.save(path, ~((X**2 + Y**2 + Z**2 < 0.3**2) | (Y**2 + Z**2 < 0.15**2)))
    return path


@pytest.fixture
def bar(tmp_path):
    """A solid bar along x in void: its stiffness is singular across the bar (not positive definite)."""
    phases = np.zeros((8, 8, 8), dtype=bool)
    phases[:, 2:6, 2:6] = True
    path = tmp_path / "bar.npy"
    np.save(path, phases)
    return path


@pytest.fixture
def bad_scene(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('[geometry]\nbuilder = "beam"\nh = "fine"\n')
    return path


@pytest.mark.parametrize("program", [["fenicsfoam", "homogenize"], ["homogenize"]], ids=["fenicsfoam", "alias"])
def test_homogenize_exit_codes_under_both_names(program, image, bar, tmp_path):
    base = command(program[0]) + program[1:]
    ok = run([*base, "--image", str(image), "--threads", "1", "--out", str(tmp_path / "r.json")])
    assert ok.returncode == 0, ok.stderr
    assert np.array(json.loads((tmp_path / "r.json").read_text())["C"]).shape == (6, 6)
    bad = run([*base, "--image", str(image), "--tol", "2"])
    assert bad.returncode == 2 and "--tol must be in (0, 1), got 2.0" in bad.stderr
    unreachable = run([*base, "--density", "0.9999", "--cells", "4", "--resolution", "8"])
    assert unreachable.returncode == 2 and "density" in unreachable.stderr  # FoamParameterError: bad input
    stuck = run([*base, "--image", str(image), "--maxiter", "1", "--threads", "1", "--out", str(tmp_path / "s.json")])
    assert stuck.returncode == 3 and "did not reach tol in maxiter = 1" in stuck.stderr
    assert not (tmp_path / "s.json").exists()
    singular = run([*base, "--image", str(bar), "--threads", "1", "--out", str(tmp_path / "b.json")])
    assert singular.returncode == 1 and "not positive definite" in singular.stderr
    assert not (tmp_path / "b.json").exists()


def test_run_exit_codes(bad_scene, tmp_path):
    assert main(["run", str(bad_scene), "--out", str(tmp_path / "out")]) == 2
    assert main(["run", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "out")]) == 2
    scene = tmp_path / "beam.toml"
    scene.write_text(BEAM.replace('[outputs]', '[fem]\nmodel = "svk"\n[fem.petsc]\nsnes_max_it = 1\n[outputs]'))
    # one Newton iteration per increment: no increment of the nonlinear model reaches snes_rtol, even cut back
    assert main(["run", str(scene), "--out", str(tmp_path / "stuck")]) == 3
    summary = json.loads((tmp_path / "stuck" / "summary.json").read_text())
    assert "failed" in summary["error"] and summary["failure"]["step"] == "gravity"


def test_usage_errors_exit_2_and_help_lists_the_exit_codes(capsys):
    with pytest.raises(SystemExit) as info:
        main(["frobnicate"])
    assert info.value.code == 2
    with pytest.raises(SystemExit) as info:
        main(["table", "--out", "x", "--densities", "1.5"])
    assert info.value.code == 2 and "--densities must lie in (0, 1), got [1.5]" in capsys.readouterr().err
    assert main(["table", "--out", "x", "--box", "equiaxed", "--gammas", "1", "0.3", "--resolution", "16"]) == 2
    assert "--resolution 16 with --gammas 0.3 gives 4.8" in capsys.readouterr().err  # before any sample is run
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert all(name in out for name in ("info", "run", "calibrate", "homogenize", "table"))
    assert "2 bad input" in out and "3 a solver" in out


def test_table_writes_the_three_files(tmp_path):
    """A table made with the defaults is a hex8 table: its name, rows and provenance say so, and its recorded
    settings read back are the run's; --discretization rotated writes the shipped tables' names."""
    from homogenization import tables

    out = tmp_path / "table"
    args = ["table", "--densities", "0.3", "--gammas", "1", "--seeds", "0", "--cells", "3", "--resolution", "16",
            "--threads", "1"]
    assert main([*args, "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["cache", "foam_table_cube_hex8.csv",
                                                     "foam_table_cube_hex8_provenance.json",
                                                     "foam_table_cube_hex8_samples.csv"]
    provenance = json.loads((out / "foam_table_cube_hex8_provenance.json").read_text())
    assert provenance["n_samples"] == 1 and provenance["settings"]["resolution"] == 16
    assert provenance["settings"]["discretization"] == "hex8"
    assert tables.read_samples(out / "foam_table_cube_hex8_samples.csv")[0]["discretization"] == "hex8"
    assert tables.recorded_settings("cube_hex8", out) == {
        1.0: tables.SweepSettings(n_cells=3, resolution=16, tol=1e-4, discretization="hex8")}
    rotated = tmp_path / "rotated"
    assert main([*args, "--discretization", "rotated", "--out", str(rotated)]) == 0
    assert sorted(p.name for p in rotated.iterdir()) == ["cache", "foam_table.csv", "foam_table_provenance.json",
                                                         "foam_table_samples.csv"]
    assert tables.recorded_settings("cube", rotated)[1.0].discretization == "rotated"


@pytest.mark.parametrize("command", ["table", "homogenize"])
def test_help_states_the_default_discretization(command, capsys):
    with pytest.raises(SystemExit) as info:
        main([command, "--help"])
    assert info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--discretization" in text and "default hex8" in text


def test_run_with_a_bad_scene_exits_2_under_mpirun(bad_scene, tmp_path):
    result = run(["mpirun", "-n", "2", *command("fenicsfoam"), "run", str(bad_scene), "--out", str(tmp_path / "o")],
                 env=MPI_ENV)
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("geometry.h: expected a finite number") == 1  # reported once, by rank 0


def test_logging_setup_filters_the_compilers_info_lines(capsys):
    """The C compiler run by FFCx raises the root logger to INFO while it compiles; the handler still filters."""
    root = logging.getLogger()
    saved = root.level, root.handlers[:]
    try:
        setup_logging(0, rank=0)
        root.setLevel(logging.INFO)  # what cffi's distutils does during a JIT compilation
        root.info("running build_ext")
        logging.getLogger("fenicsfoam.solver").warning("a warning")
        setup_logging(1, rank=0)
        root.info("gcc -c form.c")
        setup_logging(2, rank=1)
        logging.getLogger("fenicsfoam.solver").warning("rank 1 is quiet below ERROR")
    finally:
        root.handlers[:] = saved[1]
        root.setLevel(saved[0])
    err = capsys.readouterr().err
    assert "running build_ext" not in err and "WARNING fenicsfoam.solver: a warning" in err
    assert "INFO root: gcc -c form.c" in err and "rank 1 is quiet" not in err


def test_logging_writes_to_the_current_stderr(monkeypatch):
    """A record goes to the ``sys.stderr`` of the moment it is emitted, not to a stream closed since set-up."""
    root = logging.getLogger()
    saved = root.level, root.handlers[:]
    first, second = io.StringIO(), io.StringIO()
    try:
        monkeypatch.setattr(sys, "stderr", first)
        setup_logging(0, rank=0)
        first.close()
        monkeypatch.setattr(sys, "stderr", second)
        logging.getLogger("fenicsfoam.solver").warning("after the stream changed")
    finally:
        root.handlers[:] = saved[1]
        root.setLevel(saved[0])
    assert second.getvalue() == "WARNING fenicsfoam.solver: after the stream changed\n"


def test_fresh_form_compilation_prints_no_info_line_unless_verbose(tmp_path):
    """A scene run with an empty FFCx cache (forms compiled afresh) prints no INFO line; with -v it does."""
    scene = tmp_path / "beam.toml"
    scene.write_text(BEAM)
    quiet = run([*command("fenicsfoam"), "run", str(scene), "--out", str(tmp_path / "q")],
                env={"XDG_CACHE_HOME": str(tmp_path / "cache-quiet")})
    assert quiet.returncode == 0, quiet.stderr
    assert not [line for line in (quiet.stdout + quiet.stderr).splitlines() if "INFO" in line]
    assert "tip_deflection" in quiet.stdout
    verbose = run([*command("fenicsfoam"), "run", "-v", str(scene), "--out", str(tmp_path / "v")],
                  env={"XDG_CACHE_HOME": str(tmp_path / "cache-verbose")})
    assert verbose.returncode == 0, verbose.stderr
    assert "INFO root: running build_ext" in verbose.stderr
