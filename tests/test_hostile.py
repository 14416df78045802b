"""Hostile but realistic use: every bad input is refused before any work, naming it; nothing outside ``--out`` changes.

Each case asserts the exit status, that the message names the offending key or argument and its value, that no
Python traceback is shown, and that nothing outside the output location changed (a snapshot of the working
directory: every file's size, modification time and mode). Interruptions (SIGINT, SIGTERM, SIGINT through
``mpirun -n 2``) leave a run folder that says so and no temporary files. The ``mpirun`` cases spawn their own
``mpirun`` (they are not marked ``mpi``) and every subprocess has a timeout, so a hang fails instead of blocking.
"""

from __future__ import annotations

import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fenicsfoam.cli import main as fenicsfoam_main
from fenicsfoam.scene import SceneError, parse_scene
from fenicsfoam.scene.outputs import FIXED_OUTPUTS, output_path
from foambase.errors import InputError
from foambase.files import check_output_dir, check_output_file
from homogenization.cli import main as homogenize_main

BIN = Path(sys.executable).parent
MPI_ENV = {"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
           "OMPI_MCA_btl_vader_single_copy_mechanism": "none", "OMPI_MCA_rmaps_base_oversubscribe": "1"}
TIMEOUT = 300

BEAM = """name = "hostile"
probes = ["tip_deflection"]
[geometry]
builder = "beam"
h = 0.0075
[fem]
model = "linear"
[regions.beam]
tags = "beam"
material = "isotropic"
E = 1e6
nu = 0.3
rho = 1000.0
[loads]
gravity = [0.0, 0.0, -9.81]
clamp = "clamped"
"""


def steps(*labels: str, increments: int = 1) -> str:
    return "".join(f'[[steps]]\nlabel = "{label}"\ngravity = {(i + 1) / len(labels)}\nincrements = {increments}\n'
                   for i, label in enumerate(labels))


def scene_text(*labels: str, extra: str = "", outputs: str = "") -> str:
    return BEAM.replace("[loads]", extra + "[loads]") + steps(*(labels or ("gravity",))) + outputs


def snapshot(root: Path, exclude: Path | None = None) -> dict[str, tuple]:
    """Every file and directory under ``root`` (except ``exclude``'s tree): size, mtime and mode."""
    state = {}
    for path in sorted(root.rglob("*")):
        if exclude is not None and (path == exclude or exclude in path.parents):
            continue
        info = path.lstat()
        state[str(path.relative_to(root))] = (info.st_size if path.is_file() else None, info.st_mtime_ns,
                                              info.st_mode)
    return state


def command(name: str) -> list[str]:
    script = BIN / name
    module = "fenicsfoam.cli" if name == "fenicsfoam" else "homogenization.cli"
    return [str(script)] if script.exists() else [sys.executable, "-m", module]


def spawn(argv: list[str], cwd: Path, env: dict | None = None) -> subprocess.Popen:
    return subprocess.Popen(argv, cwd=cwd, env={**os.environ, **(env or {})}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


def run(argv: list[str], cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(argv, cwd=cwd, env={**os.environ, **(env or {})}, capture_output=True, text=True,
                          timeout=TIMEOUT)


def status_of(argv, capsys) -> tuple[int, str]:
    """Exit status and stderr of an in-process command line (argparse's usage errors exit, the others return)."""
    try:
        status = argv[0](argv[1:])
    except SystemExit as info:
        status = info.code
    return status, capsys.readouterr().err


@pytest.fixture
def work(tmp_path):
    """A working directory with a file that must survive every case."""
    work = tmp_path / "work"
    work.mkdir()
    (work / "victim.txt").write_text("precious\n")
    return work


# --------------------------------------------------------------------------------------------------
# Names: step labels are safe file names, validated with the scene
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("labels, index, message", [
    (["../victim"], 0, r"'\.\./victim' is not a valid step label"),
    (["a/b"], 0, r"'a/b' is not a valid step label"),
    ([""], 0, r"'' is not a valid step label"),
    ([".hidden"], 0, r"'\.hidden' is not a valid step label"),
    (["x" * 65], 0, r"'x{65}' is not a valid step label"),
    (["tab\there"], 0, r"'tab\\there' is not a valid step label"),
    (["orientation"], 0, r"'orientation' is the name of a fixed output"),
    (["Summary"], 0, r"'Summary' is the name of a fixed output"),
    (["top", "Top"], 1, r"'Top' differs from 'top' only in case"),
    (["top", "top"], 1, r"'top' is repeated"),
])
def test_unsafe_step_labels_are_refused_naming_the_key(labels, index, message):
    scene = {"geometry": {"builder": "beam"}, "regions": {"beam": {"tags": "beam", "material": "isotropic",
                                                                   "E": 1e6, "nu": 0.3}},
             "loads": {"clamp": "clamped"}, "steps": [{"label": label} for label in labels]}
    with pytest.raises(SceneError, match=rf"^steps\[{index}\]\.label: {message}"):
        parse_scene(scene)


def test_safe_labels_are_accepted():
    scene = {"geometry": {"builder": "beam"}, "regions": {"beam": {"tags": "beam", "material": "isotropic",
                                                                   "E": 1e6, "nu": 0.3}},
             "loads": {"clamp": "clamped"}, "steps": [{"label": s} for s in ("rest", "step-2", "top_19.5deg")]}
    assert [s.label for s in parse_scene(scene).steps] == ["rest", "step-2", "top_19.5deg"]


@pytest.mark.parametrize("name", ["../x.png", "a/b.png", ".x.png", "", "..", "/etc/passwd"])
def test_output_path_refuses_anything_but_a_plain_file_name(tmp_path, name):
    with pytest.raises(InputError, match="not a plain file name"):
        output_path(tmp_path, name)


def test_a_path_traversal_label_writes_nothing_anywhere(work, capsys):
    (work / "scene.toml").write_text(scene_text("../victim"))
    before = snapshot(work)
    status, err = status_of([fenicsfoam_main, "run", str(work / "scene.toml"), "--out", str(work / "out")], capsys)
    assert status == 2 and "steps[0].label: '../victim' is not a valid step label" in err
    assert snapshot(work) == before and (work / "victim.txt").read_text() == "precious\n"


# --------------------------------------------------------------------------------------------------
# Scenes the library refuses: exit 2 with a message naming the key, no traceback, nothing written
# --------------------------------------------------------------------------------------------------
FOAM = 'material = "foam"\ndensity = 0.18\ngamma = 1.0\nE_solid = 1e6\nnu_solid = 0.3\nrho_solid = 1000.0\n'
TI_BAD = ('material = "transverse_isotropic"\nE_t = 1e6\nE_l = 2e6\nnu_t = 0.3\nnu_tl = 0.9\nG_l = 3e5\n'
          'rho = 1000.0\n')
ISO = 'material = "isotropic"\nE = 1e6\nnu = 0.3\nrho = 1000.0\n'


@pytest.mark.parametrize("edit, message", [
    (lambda s: s.replace("h = 0.0075", "h = 10"), "geometry.h (with width, height): beam element size h = 10.0 m"),
    (lambda s: s.replace(ISO, TI_BAD).replace("[loads]", '[orientation]\nkind = "callable"\nfunction = '
                                              '"os:getcwd"\n[loads]'),
     "regions.beam.nu_t (with nu_tl, E_l, E_t): transverse isotropy requires"),
    (lambda s: s.replace(ISO, TI_BAD.replace("nu_tl = 0.9", "nu_tl = 0.3")).replace(
        "[loads]", '[orientation]\nkind = "callable"\nfunction = "os:getcwd"\n[loads]'),
     "orientation.function: os:getcwd(x) raised TypeError"),
    (lambda s: s.replace(ISO, TI_BAD.replace("nu_tl = 0.9", "nu_tl = 0.3")).replace(
        "[loads]", '[orientation]\nkind = "callable"\nfunction = "math:pi"\n[loads]'),
     "orientation.function: 'math:pi' is a float, not a function"),
    (lambda s: s.replace("[loads]", '[fem.petsc]\nsnes_rtol = "abc"\n[loads]'),
     "fem.petsc.snes_rtol: PETSc refuses the value 'abc'"),
    (lambda s: s.replace("[loads]", "[fem.petsc]\nsnes_rtoll = 1e-8\n[loads]"),
     "fem.petsc.snes_rtoll: PETSc does not use this option"),
    (lambda s: s.replace("[loads]", "[fem.petsc]\nsnes_monitor = true\n[loads]"),
     'fem.petsc.snes_monitor: PETSc refuses the value True'),
    (lambda s: s.replace(ISO, FOAM.replace("rho_solid = 1000.0", "rho_solid = -5")),
     "regions.beam.rho_solid: -5 is out of range"),
    (lambda s: s.replace(ISO, FOAM.replace("gamma = 1.0", "gamma = 0.01")),
     "regions.beam.gamma: gamma = 0.01 is outside the tabulated range"),
    (lambda s: s.replace(ISO, FOAM.replace("E_solid = 1e6", "E_solid = 1e6\nfit = \"diagonal\"")),
     "regions.beam.fit: 'diagonal' is not valid"),
])
def test_bad_scenes_exit_2_naming_the_key(work, capsys, edit, message):
    (work / "scene.toml").write_text(edit(scene_text()))
    before = snapshot(work)
    status, err = status_of([fenicsfoam_main, "run", str(work / "scene.toml"), "--out", str(work / "out")], capsys)
    assert status == 2, err
    assert message in err and "Traceback" not in err
    assert snapshot(work) == before  # not even --out is created


def test_a_binary_scene_file_exits_2(work, capsys):
    (work / "scene.toml").write_bytes(bytes(range(256)))
    status, err = status_of([fenicsfoam_main, "run", str(work / "scene.toml"), "--out", str(work / "out")], capsys)
    assert status == 2 and "not a TOML text file (not UTF-8 at byte 128)" in err and "Traceback" not in err


def test_a_foam_with_a_negative_solid_density_names_rho_solid():
    from fenicsfoam.materials import foam_material

    with pytest.raises(InputError, match=r"^rho_solid must be finite and >= 0 kg/m³, got -5"):
        foam_material(0.18, 1.0, 12e6, 0.3, rho_solid=-5)


# --------------------------------------------------------------------------------------------------
# Output locations, checked before any work
# --------------------------------------------------------------------------------------------------
def test_output_checks(tmp_path):
    (tmp_path / "file").write_text("x")
    for bad, message in [("", "an empty path"), (tmp_path / "file", "is a file"),
                         (tmp_path / "file" / "sub", "is a file, not a directory"),
                         ("/proc/fenicsfoam-out", "cannot create files in /proc")]:
        with pytest.raises(InputError, match=message):
            check_output_dir(bad, "--out")
    for bad, message in [("", "an empty path"), (tmp_path, "is a directory"),
                         (tmp_path / "missing" / "r.json", "does not exist"),
                         (tmp_path / "file" / "r.json", "is a file, not a directory"),
                         ("/proc/r.json", "cannot create files in /proc")]:
        with pytest.raises(InputError, match=message):
            check_output_file(bad, "--out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]  # the write probes leave nothing


@pytest.mark.parametrize("out, message", [
    ("", "argument --out: an empty path"),
    ("scene.toml", "--out scene.toml: is a file, not a directory"),
    ("victim.txt/out", "victim.txt is a file, not a directory"),
    ("/proc/out", "--out /proc/out: cannot create files in /proc"),
    (".", "--out .: the directory is not empty and not a run's output folder"),
])
def test_run_checks_its_output_directory_first(work, capsys, monkeypatch, out, message):
    monkeypatch.chdir(work)
    (work / "scene.toml").write_text(scene_text())
    before = snapshot(work)
    status, err = status_of([fenicsfoam_main, "run", "scene.toml", "--out", out], capsys)
    assert status == 2 and message in err, err
    assert snapshot(work) == before


# --------------------------------------------------------------------------------------------------
# Run folders: one run per folder, stale files removed, status in summary.json, normal permissions
# --------------------------------------------------------------------------------------------------
def outputs_of(out: Path) -> list[str]:
    return sorted(p.name for p in out.iterdir())


def test_a_rerun_replaces_the_previous_run_and_keeps_other_files(work, capsys):
    out = work / "out"
    (work / "one.toml").write_text(scene_text("first", "second"))
    assert fenicsfoam_main(["run", str(work / "one.toml"), "--out", str(out)]) == 0
    assert outputs_of(out) == ["first.png", "probes.csv", "run.log", "second.png", "solution.h5", "solution.npz",
                               "solution.pvd", "solution.xdmf", "solution_000_first.vtu", "solution_001_second.vtu",
                               "summary.json"]
    assert sorted(json.loads((out / "summary.json").read_text())["files"]) == outputs_of(out)
    (out / "notes.txt").write_text("mine")
    (out / ".solution.stale").mkdir()  # as a killed run leaves them
    (out / ".summary.123.0123abcd.tmp.json").write_text("{")
    (work / "two.toml").write_text(scene_text("third", outputs="[outputs]\nxdmf = false\n"))
    before = snapshot(work, exclude=out)
    assert fenicsfoam_main(["run", str(work / "two.toml"), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert outputs_of(out) == ["notes.txt", "probes.csv", "run.log", "summary.json", "third.png"]
    assert summary["status"] == "complete" and sorted(summary["files"]) == ["probes.csv", "run.log", "summary.json",
                                                                             "third.png"]
    assert [s["label"] for s in summary["steps"]] == ["third"] and summary["error"] is None
    assert snapshot(work, exclude=out) == before
    mask = os.umask(0)
    os.umask(mask)
    for name in outputs_of(out):
        assert stat.S_IMODE((out / name).stat().st_mode) == 0o666 & ~mask, name
    capsys.readouterr()


def test_fixed_outputs_are_the_reserved_names():
    from fenicsfoam.scene.schema import RESERVED_NAMES

    assert {name.split(".")[0] for name in FIXED_OUTPUTS} == set(RESERVED_NAMES)


def test_an_option_read_only_at_setup_is_checked_after_the_first_step(work, capsys):
    out = work / "out"
    (work / "scene.toml").write_text(scene_text("a", "b", extra="[fem.petsc]\nmat_mumps_icntl_144 = 1\n"))
    status, err = status_of([fenicsfoam_main, "run", str(work / "scene.toml"), "--out", str(out)], capsys)
    assert status == 2 and "fem.petsc.mat_mumps_icntl_144: PETSc did not use this option" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and "mat_mumps_icntl_144" in summary["error"] and summary["steps"] == []
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_a_used_setup_option_passes_and_unknown_command_line_options_warn(work, capsys):
    (work / "scene.toml").write_text(scene_text(extra="[fem.petsc]\nmat_mumps_icntl_14 = 40\n",
                                                outputs="[outputs]\nxdmf = false\npng = false\n"))
    status, err = status_of([fenicsfoam_main, "run", str(work / "scene.toml"), "--out", str(work / "out"), "--",
                             "-scene_snes_rtoll", "1e-8", "-scene_snes_rtol", "1e-9", "-snes_max_it", "3"], capsys)
    assert status == 0, err
    assert "WARNING" in err and "-scene_snes_rtoll -snes_max_it" in err and "-scene_snes_rtol " not in err
    from petsc4py import PETSc
    assert not [k for k in PETSc.Options().getAll() if "snes" in k]  # the run's options are gone with it


# --------------------------------------------------------------------------------------------------
# Interruptions
# --------------------------------------------------------------------------------------------------
SLOW = BEAM.replace('model = "linear"', 'model = "corotational"').replace("E = 1e6", "E = 2e5") + "".join(
    f'[[steps]]\nlabel = "s{i}"\ngravity = {(i + 1) / 40}\nincrements = 2\n' for i in range(40)) + \
    "[outputs]\npng = false\n"


def interrupt(argv: list[str], work: Path, out: Path, sig: int, env: dict | None = None) -> tuple[int, str]:
    """Start a run, wait until its folder says it has started, send ``sig`` to the launcher; exit status, stderr."""
    process = spawn(argv, work, env)
    deadline = time.monotonic() + TIMEOUT
    try:
        while time.monotonic() < deadline and process.poll() is None:
            try:
                if json.loads((out / "summary.json").read_text())["status"] == "incomplete":
                    break
            except (OSError, ValueError, KeyError):
                pass
            time.sleep(0.05)
        assert process.poll() is None, process.communicate()
        time.sleep(0.5)
        process.send_signal(sig)
        _, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
    return process.returncode, err


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["SIGINT", "SIGTERM"])
def test_an_interrupted_run_says_so_and_leaves_no_temporary_files(work, sig, code):
    out = work / "out"
    (work / "slow.toml").write_text(SLOW)
    before = snapshot(work)
    status, err = interrupt([*command("fenicsfoam"), "run", "slow.toml", "--out", "out"], work, out, sig)
    assert status == code, err
    assert f"interrupted by {signal.Signals(sig).name}" in err and "Traceback" not in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and f"interrupted by {signal.Signals(sig).name}" in summary["error"]
    assert len(summary["steps"]) < 40
    done = {"solution.pvd", *(f"solution_{i:03d}_s{i}.vtu" for i in range(len(summary["steps"])))}
    assert set(outputs_of(out)) <= {"summary.json", "probes.csv", "run.log", *done}  # no .solution.* nor *.tmp
    after = snapshot(work, exclude=out)
    assert after == {k: v for k, v in before.items() if not k.startswith("out")}


def test_sigint_through_mpirun_stops_every_rank_and_removes_the_temporaries(work):
    out = work / "out"
    (work / "slow.toml").write_text(SLOW)
    status, err = interrupt(["mpirun", "-n", "2", *command("fenicsfoam"), "run", "slow.toml", "--out", "out"],
                            work, out, signal.SIGINT, MPI_ENV)
    assert status != 0
    summary = json.loads((out / "summary.json").read_text())
    # rank 0 writes "interrupted" when it regains control; if it was waiting in MPI it is killed: "incomplete"
    assert summary["status"] in ("interrupted", "incomplete") and len(summary["steps"]) < 40
    done = {"solution.pvd", *(f"solution_{i:03d}_s{i}.vtu" for i in range(len(summary["steps"]) + 1))}
    assert set(outputs_of(out)) <= {"summary.json", "probes.csv", "run.log", *done}


def test_a_rank_waiting_in_mpi_removes_its_temporaries_on_a_signal(tmp_path):
    """The watcher thread cleans up for a main thread that cannot run Python (here: stuck in a barrier)."""
    script = tmp_path / "stuck.py"
    script.write_text(f"""
import time
from pathlib import Path
from mpi4py import MPI
from foambase.signals import interruptible, register_temporary
comm = MPI.COMM_WORLD
mine = Path({str(tmp_path)!r}) / f"tmp{{comm.rank}}"
mine.mkdir()
(mine / "part.h5").write_text("x")
with interruptible():
    register_temporary(mine)
    print("ready", flush=True)
    if comm.rank == 0:
        comm.Barrier()   # rank 1 never comes: rank 0 cannot run Python
    else:
        time.sleep(120)
""")
    process = spawn(["mpirun", "-n", "2", sys.executable, str(script)], tmp_path, MPI_ENV)
    try:
        deadline = time.monotonic() + 60
        lines = 0
        while lines < 2 and time.monotonic() < deadline:
            lines += process.stdout.readline().startswith("ready")
        time.sleep(0.5)
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
    assert not (tmp_path / "tmp0").exists() and not (tmp_path / "tmp1").exists()


# --------------------------------------------------------------------------------------------------
# Under mpirun every rank agrees on the error and exits
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("scene, out, message", [
    (lambda: scene_text(extra="[fem.petsc]\nsnes_rtoll = 1\n"), "out", "fem.petsc.snes_rtoll"),
    (lambda: scene_text("../victim"), "out", "steps[0].label"),
    (scene_text, "/proc/out", "--out /proc/out: cannot create files"),
], ids=["petsc-option", "label", "unwritable-out"])
def test_errors_under_mpirun_exit_2_on_every_rank(work, scene, out, message):
    (work / "scene.toml").write_text(scene())
    before = snapshot(work)
    result = run(["mpirun", "-n", "2", *command("fenicsfoam"), "run", "scene.toml", "--out", out], work, MPI_ENV)
    assert result.returncode == 2, result.stderr
    assert result.stderr.count(message) == 1 and "Traceback" not in result.stderr  # once, by rank 0
    assert snapshot(work) == before


# --------------------------------------------------------------------------------------------------
# homogenize: the command line applies the library's checks, before any work, under both names
# --------------------------------------------------------------------------------------------------
def _homogenize(argv):
    return homogenize_main(argv)


def _fenicsfoam_homogenize(argv):
    return fenicsfoam_main(["homogenize", *argv])


@pytest.fixture
def images(work):
    np.savez(work / "archive.npz", phases=np.ones((8, 8, 8), dtype=bool))
    np.save(work / "empty.npy", np.zeros((0, 8, 8), dtype=bool))
    np.save(work / "void.npy", np.zeros((8, 8, 8), dtype=bool))
    x = (np.arange(8) + 0.5) / 8 - 0.5
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    np.save(work / "porous.npy", ~((X**2 + Y**2 + Z**2 < 0.3**2) | (Y**2 + Z**2 < 0.15**2)))
    return work


FOAM_ARGS = ["--density", "0.3", "--cells", "8", "--resolution", "16", "--threads", "1"]


@pytest.mark.parametrize("main", [_homogenize, _fenicsfoam_homogenize], ids=["homogenize", "fenicsfoam"])
@pytest.mark.parametrize("argv, message", [
    ([*FOAM_ARGS, "--cells", "1"], "--cells must be an integer >= 2, got 1"),
    ([*FOAM_ARGS, "--resolution", "2"], "--resolution must be an integer >= 8, got 2"),
    ([*FOAM_ARGS, "--seed", "-1"], "--seed must be an integer >= 0, got -1"),
    ([*FOAM_ARGS, "--gamma", "1e-300"], "--gamma 1e-300 --cells 8 --seed 0 --box cube --distance euclidean: "
                                        "gamma=1e-300 is too flat for n_cells=8"),
    ([*FOAM_ARGS, "--gamma", "nan"], "--gamma must be in (0, 1], got nan"),
    ([*FOAM_ARGS, "--density", "0.9999"], "--density 0.9999 --gamma 1 --cells 8 --seed 0 --box cube "
                                          "--distance euclidean: density 0.9999 is outside the valid range"),
    ([*FOAM_ARGS, "--E-solid", "1.5e308"], "--E-solid 1.5e+308: the solid's largest stiffness entry inf overflows"),
    ([*FOAM_ARGS, "--E-solid", "1e-310"], "--E-solid 1e-310: the solid's largest stiffness entry 1.35e-310 is a "
                                          "subnormal number"),
    ([*FOAM_ARGS, "--E-solid", "inf"], "--E-solid must be > 0 and finite, got inf"),
    (["--image", "archive.npz"], "--image archive.npz: an .npz archive, not an .npy array"),
    (["--image", "empty.npy"], "--image empty.npy: expected a non-empty 3-D array"),
    (["--image", "void.npy"], "--image void.npy: every voxel is void"),
    (["--image", "victim.txt"], "--image victim.txt: cannot read a .npy array"),
    (["--image", ""], "argument --image: an empty path"),
    (["--image", "porous.npy", "--stl", "foam.stl"], "--stl writes a foam's surface: it needs --density"),
    (["--image", "porous.npy", "--out", ""], "argument --out: an empty path"),
    (["--image", "porous.npy", "--out", "."], "--out .: is a directory"),
    (["--image", "porous.npy", "--out", "missing/r.json"], "--out missing/r.json: directory missing does not exist"),
    (["--image", "porous.npy", "--out", "victim.txt/r.json"], "victim.txt is a file, not a directory"),
    (["--image", "porous.npy", "--out", "/proc/r.json"], "--out /proc/r.json: cannot create files in /proc"),
    ([*FOAM_ARGS, "--stl", "/proc/f.stl"], "--stl /proc/f.stl: cannot create files in /proc"),
    ([*FOAM_ARGS, "--stl", "r.json", "--out", "r.json"], "--stl and --out name the same file"),
])
def test_homogenize_refuses_bad_arguments_naming_them(images, capsys, monkeypatch, main, argv, message):
    monkeypatch.chdir(images)
    before = snapshot(images)
    status, err = status_of([main, *argv], capsys)
    assert status == 2 and message in err, err
    assert "Traceback" not in err
    assert snapshot(images) == before


@pytest.mark.parametrize(("threads", "ranks", "warned"), [(1, 2, False), (2, 1, True), (1, 3, True), (None, 4, False)])
def test_thread_warning_counts_a_bound_rank_and_the_machine(threads, ranks, warned, monkeypatch, caplog):
    """Under mpirun each rank is bound to one of the 2 CPUs: one thread per rank is fine, more is not."""
    import os

    from foambase import threads as foam_threads
    from homogenization.cli import _warn_threads

    monkeypatch.setattr(foam_threads, "cpu_count", lambda: 1)
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    with caplog.at_level("WARNING", logger="homogenization.cli"):
        _warn_threads(threads, ranks)
    assert bool(caplog.records) == warned, caplog.text


def test_homogenize_defaults_prints_the_constants_and_warns_about_threads(images, capsys, monkeypatch):
    from foambase import threads

    monkeypatch.setattr(threads, "cpu_count", lambda: 2)
    monkeypatch.chdir(images)
    assert homogenize_main(["--image", "porous.npy", "--threads", "64", "--out", "r.json"]) == 0
    captured = capsys.readouterr()
    assert "--threads 64 is more than the 2 CPU(s) this process may use" in captured.err
    assert "engineering constants: E1 = " in captured.out and "TI fit (l = x):" in captured.out
    data = json.loads((images / "r.json").read_text())
    assert data["inputs"]["tol"] == 1e-4 and data["info"]["threads"] == 64
    assert homogenize_main(["--image", "porous.npy"]) == 0
    assert "WARNING" not in capsys.readouterr().err  # one thread by default


def test_homogenize_writes_the_foam_surface(images, monkeypatch):
    import meshio

    monkeypatch.chdir(images)
    assert homogenize_main([*FOAM_ARGS, "--stl", "foam.stl", "--out", "foam.json"]) == 0
    surface = meshio.read(images / "foam.stl")
    triangles = surface.cells_dict["triangle"]
    # a closed, consistently oriented surface: every edge is shared by exactly two triangles, in opposite directions
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    assert len({tuple(e) for e in edges.tolist()}) == len(edges)
    assert {tuple(e) for e in edges.tolist()} == {tuple(e) for e in edges[:, ::-1].tolist()}
    assert json.loads((images / "foam.json").read_text())["inputs"]["stl"] == "foam.stl"
    assert stat.S_IMODE((images / "foam.stl").stat().st_mode) & 0o044  # readable by others, not 0600


# --------------------------------------------------------------------------------------------------
# table: outputs and settings checked before the sweep
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, message", [
    (["--out", "victim.txt"], "--out victim.txt: is a file, not a directory"),
    (["--out", "/proc/table"], "--out /proc/table: cannot create files in /proc"),
    (["--out", "t", "--cache", "victim.txt"], "--cache victim.txt: is a file, not a directory"),
    (["--out", ""], "argument --out: an empty path"),
    (["--out", "t", "--cells", "1"], "--cells: n_cells must be an integer >= 2, got 1"),
    (["--out", "t", "--resolution", "4"], "--resolution: resolution must be an integer >= 8 (cubic voxels"),
    (["--out", "t", "--densities", "nan"], "--densities must lie in (0, 1)"),
])
def test_table_refuses_bad_arguments_naming_them(work, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(work)
    before = snapshot(work)
    status, err = status_of([fenicsfoam_main, "table", *argv], capsys)
    assert status == 2 and message in err, err
    assert snapshot(work) == before
