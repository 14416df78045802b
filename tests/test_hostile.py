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
import re
import signal
import stat
import subprocess
import sys
import textwrap
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


def _beam(**extra):
    return {"geometry": {"builder": "beam"}, "regions": {"beam": {"tags": "beam", "material": "isotropic",
                                                                  "E": 1e6, "nu": 0.3}},
            "loads": {"clamp": "clamped"}, "steps": [{"label": "a"}], **extra}


def _ti_beam(orientation):
    scene = _beam(orientation=orientation)
    scene["regions"]["beam"] = {"tags": "beam", "material": "transverse_isotropic", "E_t": 1e6, "E_l": 2e6,
                                "nu_t": 0.3, "nu_tl": 0.3, "G_l": 3e5}
    return scene


@pytest.mark.parametrize("scene, message", [
    (lambda: _beam(loads={"clamp": "clamped", "force": {"clamp": {"group": "tip", "force": [0, 0, -1.0]}}}),
     r"^loads\.force\.clamp: the name 'clamp' is reserved"),
    (lambda: _beam(loads={"clamp": "clamped", "pressure": {"servo1": {"group": "tip", "pressure": 1.0}}}),
     r"^loads\.pressure\.servo1: the name 'servo1' is reserved"),
    (lambda: _ti_beam({"kind": "per_tag", "directions": {"beam": [1.0, 0, 0]}, "default": [0, 0, 1.0]}),
     r"^orientation\.default: every cell tag of the mesh \(\[1\]\) has a direction"),
    (lambda: _ti_beam({"kind": "per_tag", "directions": {"\u00b2": [1.0, 0, 0]}}),
     r"^orientation\.directions\.\u00b2: unknown region name '\u00b2'"),
])
def test_reserved_names_unused_defaults_and_odd_tags_are_refused(scene, message):
    with pytest.raises(SceneError, match=message):
        parse_scene(scene())


@pytest.mark.parametrize("edit, message", [
    (lambda s: s["steps"][0].update(lable=s["steps"][0].pop("label")),
     r"^steps\[0\]\.lable: unknown key; did you mean 'label'\? \(steps\[0\]\.label is required\)"),
    (lambda s: s["regions"]["beam"].update(e=s["regions"]["beam"].pop("E")),
     r"^regions\.beam\.e: unknown key; did you mean 'E'\?"),
    (lambda s: s["geometry"].update(heigth=0.01),
     r"^geometry\.heigth: unknown key; did you mean 'height'\? valid keys here"),
    (lambda s: s["regions"]["beam"].update(material="foam", density=0.2, gama=1.0, E_solid=1e6, nu_solid=0.3,
                                           E=None) or s["regions"]["beam"].pop("E") and None,
     r"^regions\.beam\.gama: unknown key; did you mean 'gamma'\?"),
])
def test_a_misspelt_key_is_named_with_a_suggestion(edit, message):
    scene = _beam()
    scene["regions"]["beam"]["nu"] = 0.3
    edit(scene)
    with pytest.raises(SceneError, match=message):
        parse_scene(scene)


def test_a_key_of_the_schema_is_never_taken_for_a_misspelling():
    """nu_tl is a key of its own: a transversely isotropic region without nu_t is told nu_t is missing."""
    scene = _ti_beam({"kind": "uniform", "direction": [1.0, 0.0, 0.0]})
    del scene["regions"]["beam"]["nu_t"]
    with pytest.raises(SceneError, match=r"^regions\.beam\.nu_t: missing value \(required\)"):
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
    (lambda s: s.replace(ISO, TI_BAD.replace("nu_tl = 0.9", "nu_tl = 0.3")).replace(
        "[loads]", '[orientation]\nkind = "callable"\nfunction = "sys:exit"\n[loads]'),
     "orientation.function: sys:exit(x) raised SystemExit"),
    (lambda s: s.replace(ISO, TI_BAD.replace("nu_tl = 0.9", "nu_tl = 0.3")).replace(
        "[loads]", '[orientation]\nkind = "callable"\nfunction = "numpy.fft:fft"\n[loads]'),
     "orientation.function: numpy.fft:fft(x) returned complex values"),
    (lambda s: s.replace(ISO, FOAM.replace("density = 0.18", 'density = {function = "numpy.fft:fft"}')).replace(
        "[loads]", '[orientation]\nkind = "uniform"\ndirection = [1.0, 0.0, 0.0]\n[loads]'),
     "regions.beam.density: the function returned complex values"),
    (lambda s: s.replace(ISO, FOAM.replace("density = 0.18", 'density = {function = "sys:exit"}')).replace(
        "[loads]", '[orientation]\nkind = "uniform"\ndirection = [1.0, 0.0, 0.0]\n[loads]'),
     "regions.beam.density: sys:exit(x) raised SystemExit"),
    (lambda s: s.replace("E = 1e6", "E = 1e300"),
     "regions.beam.E: 1e+300 is out of range; valid: a modulus in (0, 1e+13] Pa"),
    (lambda s: s.replace(ISO, TI_BAD.replace("nu_tl = 0.9", "nu_tl = 0.3").replace("G_l = 3e5", "G_l = 2e13")),
     "regions.beam.G_l: 20000000000000.0 is out of range; valid: a modulus in (0, 1e+13] Pa"),
    (lambda s: s.replace(ISO, TI_BAD.replace("nu_tl = 0.9", "nu_tl = 1e300")),
     "regions.beam.nu_t (with nu_tl, E_l, E_t): transverse isotropy requires"),
    (lambda s: s.replace(ISO, FOAM.replace("E_solid = 1e6", "E_solid = 1e300")),
     "regions.beam.E_solid: 1e+300 is out of range; valid: a modulus in (0, 1e+13] Pa"),
    (lambda s: s.replace("increments = 1", "increments = 9223372036854775807"),
     "steps[0].increments: 9223372036854775807 is out of range; valid: an integer <= 10000"),
    (lambda s: s.replace('name = "hostile"', f'name = "{"n" * 10000}"'),
     "name: expected a printable name of at most 200 characters"),
    (lambda s: s.replace(ISO, FOAM.replace("E_solid = 1e6", 'E_solid = {calibration = "/dev/zero"}')).replace(
        "[loads]", '[orientation]\nkind = "uniform"\ndirection = [1.0, 0.0, 0.0]\n[loads]'),
     "regions.beam.E_solid.calibration: cannot read calibration file /dev/zero: is a character device"),
    (lambda s: s.replace("[loads]", '[fem.petsc]\nsnes_rtol = nan\n[loads]'),
     "fem.petsc.snes_rtol: nan is not a finite number"),
    (lambda s: s.replace("[loads]", '[fem.petsc]\nsnes_atol = -inf\n[loads]'),
     "fem.petsc.snes_atol: -inf is not a finite number"),
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


def test_sys_exit_inside_a_command_is_a_failure_not_a_success(capsys):
    """A ``sys.exit(0)`` reached inside a command's work (e.g. from a user's function) must not end with status 0."""
    from foambase import cli

    command = cli.Command("quits", "calls sys.exit(0) in its work", lambda parser: None, lambda args: sys.exit(0))
    status, err = status_of([lambda argv: cli.main_single(command, "quits", argv)], capsys)
    assert status == 1 and "quits: error: the command did not finish: sys.exit(0) was called" in err


@pytest.mark.parametrize("kind, message", [
    ("fifo", "is a named pipe (FIFO), not a regular file"),
    ("/dev/zero", "is a character device (such as /dev/zero), not a regular file"),
    ("directory", "is a directory, not a file"),
    ("missing", "does not exist"),
])
def test_a_scene_that_is_not_a_regular_file_is_named_as_what_it_is(work, capsys, kind, message):
    """Only os.stat is called: a FIFO would block a reader forever, /dev/zero would fill the memory."""
    scene = {"fifo": work / "scene.toml", "/dev/zero": Path("/dev/zero"), "directory": work / "scenes",
             "missing": work / "missing.toml"}[kind]
    if kind == "fifo":
        os.mkfifo(scene)
    elif kind == "directory":
        scene.mkdir()
    status, err = status_of([fenicsfoam_main, "run", str(scene), "--out", str(work / "out")], capsys)
    assert status == 2 and f"error: scene {scene}: {message}" in err, err


def test_an_output_name_longer_than_the_file_system_allows_is_refused_first(work, capsys):
    (work / "scene.toml").write_text(scene_text())
    before = snapshot(work)
    status, err = status_of([fenicsfoam_main, "run", str(work / "scene.toml"), "--out", str(work / ("o" * 300))],
                            capsys)
    assert status == 2 and "has 300 bytes, more than the 255 a file name may have here" in err, err
    assert snapshot(work) == before


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


@pytest.mark.parametrize("options, message", [
    (["-scene_snes_rtol", "nan"], "command-line option -scene_snes_rtol: 'nan' is not a finite number"),
    (["-scene_snes_atol", "inf"], "command-line option -scene_snes_atol: 'inf' is not a finite number"),
    (["scene_snes_rtol", "1e-8"], "PETSc options after '--': 'scene_snes_rtol' is not an option (options start "
                                  "with '-') (did you mean -scene_snes_rtol?)"),
    (["-scene_snes_rtol", "1e-8", "1e-9"], "PETSc options after '--': '1e-9' is not an option"),
    (["-scene_ksp_type"], "command-line option -scene_ksp_type: PETSc refuses no value"),
    (["-scene_ksp_type", "nosuchtype"], "command-line option -scene_ksp_type: PETSc refuses the value 'nosuchtype'"),
])
def test_bad_command_line_petsc_options_exit_2_naming_them(work, capsys, options, message):
    (work / "scene.toml").write_text(scene_text())
    before = snapshot(work)
    status, err = status_of([fenicsfoam_main, "run", str(work / "scene.toml"), "--out", str(work / "out"), "--",
                             *options], capsys)
    assert status == 2 and message in err and "Traceback" not in err, err
    assert snapshot(work) == before
    from petsc4py import PETSc
    assert not [k for k in PETSc.Options().getAll() if k.startswith("scene_")]


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
    header = (work / "void.npy").read_bytes().replace(b"(8, 8, 8)", b"(4096, 4096, 4096)")
    (work / "huge.npy").write_bytes(header)  # a header announcing 4096³ voxels over 512 bytes of data
    os.mkfifo(work / "fifo.npy")
    (work / "folder.npy").mkdir()
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
    (["--image", "huge.npy"], "--image huge.npy: its header announces an array of shape (4096, 4096, 4096)"),
    (["--image", "fifo.npy"], "--image fifo.npy: is a named pipe (FIFO), not a regular file"),
    (["--image", "folder.npy"], "--image folder.npy: is a directory, not a file"),
    (["--image", "/dev/zero"], "--image /dev/zero: is a character device"),
    (["--image", "missing.npy"], "--image missing.npy: no such file"),
    ([*FOAM_ARGS, "--resolution", "100000"], "--resolution 100000: 1e+15 voxels need at least"),
    ([*FOAM_ARGS, "--cells", "100000000"], "--cells 100000000 --resolution 16: 100000000 Voronoi cells in 16³ "
                                           "voxels leave less than 2 voxels across a cell; valid at this "
                                           "resolution: at most 512 cells"),
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
    (["--out", "t", "--densities", "0.25", "0.25", "--seeds", "0"], "--densities: 0.25 given more than once"),
    (["--out", "t", "--seeds", "0", "1", "0"], "--seeds: 0 given more than once"),
    (["--out", "t", "--resolution", "100000"], "--resolution 100000: 1e+15 voxels need at least"),
    (["--out", "t", "--cells", "100000000"], "--cells 100000000 --resolution 48: 100000000 Voronoi cells"),
])
def test_table_refuses_bad_arguments_naming_them(work, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(work)
    before = snapshot(work)
    status, err = status_of([fenicsfoam_main, "table", *argv], capsys)
    assert status == 2 and message in err, err
    assert snapshot(work) == before


# --------------------------------------------------------------------------------------------------
# One run per output folder: a lock, refused or waited for
# --------------------------------------------------------------------------------------------------
def hold_lock(out: Path) -> int:
    """Lock ``out`` as a running ``fenicsfoam run`` does (flock on the directory); the descriptor to close."""
    import fcntl

    fd = os.open(out, os.O_RDONLY | os.O_DIRECTORY)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return fd


def another_run_in(out: Path) -> dict[str, tuple]:
    """``out`` as a run that is writing leaves it: an incomplete summary and its temporary XDMF folder."""
    out.mkdir()
    (out / "summary.json").write_text(json.dumps({"status": "incomplete", "scene": {}, "steps": [],
                                                  "files": ["summary.json"]}))
    (out / ".solution.running").mkdir()
    (out / ".solution.running" / "solution.h5").write_text("the other run's data")
    return snapshot(out)


def test_a_second_run_into_a_locked_folder_is_refused_and_touches_nothing(work, capsys):
    out = work / "out"
    before = another_run_in(out)
    (work / "scene.toml").write_text(scene_text())
    fd = hold_lock(out)
    try:
        status, err = status_of([fenicsfoam_main, "run", str(work / "scene.toml"), "--out", str(out)], capsys)
    finally:
        os.close(fd)
    assert status == 2 and f"--out {out}: another run is writing into this folder" in err, err
    assert snapshot(out) == before  # the other run's temporary folder survives


def test_a_run_with_wait_waits_for_the_lock_then_runs(work):
    out = work / "out"
    another_run_in(out)
    (work / "scene.toml").write_text(scene_text(outputs="[outputs]\nxdmf = false\npng = false\n"))
    fd = hold_lock(out)
    process = spawn([*command("fenicsfoam"), "run", "scene.toml", "--out", "out", "--wait"], work)
    try:
        time.sleep(4.0)  # long enough to build the scene and reach the lock
        assert process.poll() is None and (out / ".solution.running").exists()
        assert json.loads((out / "summary.json").read_text())["status"] == "incomplete"
        os.close(fd)
        fd = None
        _, err = process.communicate(timeout=TIMEOUT)
    finally:
        if fd is not None:
            os.close(fd)
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
    assert process.returncode == 0, err
    assert json.loads((out / "summary.json").read_text())["status"] == "complete"


# --------------------------------------------------------------------------------------------------
# Write faults: the file and the system's error named, status "failed", no half-written file
# --------------------------------------------------------------------------------------------------
LIMITED = """import resource, sys
from mpi4py import MPI  # MPI starts before the limit (it writes its own session files)
limit = int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
from fenicsfoam.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.parametrize("limit, victim, status", [
    (20_000, "solution.h5", "failed"),
    pytest.param(60_000, "first.png", "failed", marks=pytest.mark.slow),
    pytest.param(1_000, "summary.json", None, marks=pytest.mark.slow),
], ids=["hdf5", "png", "summary"])
def test_a_write_fault_fails_the_run_naming_the_file_and_leaves_no_partial_file(work, limit, victim, status):
    (work / "limited.py").write_text(LIMITED)
    (work / "scene.toml").write_text(scene_text("first", "second"))
    result = run([sys.executable, "limited.py", str(limit), "run", "scene.toml", "--out", "out"], work)
    out = work / "out"
    assert result.returncode == 1, result.stderr
    assert f"fenicsfoam run: error: cannot write out/{victim}: " in result.stderr
    assert "File too large (EFBIG)" in result.stderr and "Traceback" not in result.stderr
    assert not (out / victim).exists() or victim == "summary.json"
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]  # no temporaries
    if status is not None:
        summary = json.loads((out / "summary.json").read_text())
        assert summary["status"] == status and f"cannot write out/{victim}" in summary["error"]
        assert sorted(summary["files"]) == outputs_of(out)
    else:
        assert not (out / "summary.json").exists()


def test_an_atomic_write_that_fails_names_the_file_and_keeps_the_previous_version(tmp_path):
    import errno

    from foambase.errors import WriteError
    from foambase.files import atomic_open, write_json_atomic

    target = tmp_path / "calibration.json"
    write_json_atomic(target, {"E_solid": 1.0})
    with pytest.raises(WriteError, match=rf"^cannot write {target}: File too large \(EFBIG\)"):
        with atomic_open(target) as f:
            f.write('{"E_solid": 2.0')
            raise OSError(errno.EFBIG, "File too large")  # as a write beyond the file-size limit fails
    assert json.loads(target.read_text()) == {"E_solid": 1.0}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["calibration.json"]


LIMITED_HOMOGENIZE = LIMITED.replace("from fenicsfoam.cli import main", "from homogenization.cli import main")


def test_homogenize_reports_a_write_fault_on_its_json(images):
    """The JSON written beyond a 64-byte file-size limit (set in the subprocess, after MPI has started)."""
    (images / "limited.py").write_text(LIMITED_HOMOGENIZE)
    result = run([sys.executable, "limited.py", "64", "--image", "porous.npy", "--out", "r.json"], images)
    assert result.returncode == 1, result.stderr
    assert "homogenize: error: cannot write r.json: File too large (EFBIG)" in result.stderr
    assert "Traceback" not in result.stderr and not (images / "r.json").exists()
    assert not [p.name for p in images.iterdir() if p.name.startswith(".")]


def test_a_grid_counts_a_repeated_value_once():
    from homogenization import tables

    assert tables.grid((0.25, 0.25), (1.0,), (0, 0)) == [tables.Sample(0.25, 1.0, 0)]


@pytest.fixture
def cached_row(tmp_path):
    """A cache entry as the sweep writes one, for a sample whose C is a (slightly anisotropic) known stiffness."""
    from homogenization import tables
    from homogenization.tensors import (
        closest_isotropic,
        closest_transverse_isotropic,
        engineering_constants,
        isotropic_voigt,
    )

    settings = tables.SweepSettings(n_cells=3, resolution=16, tol=1e-5, discretization="rotated")  # no such column
    sample = tables.Sample(0.3, 1.0, 1)
    C = isotropic_voigt(0.02, 0.3)
    C[0, 0] *= 1.1
    row = {"density": sample.density, "gamma": sample.gamma, "seed": sample.seed, "distance": settings.distance,
           "box": settings.box, "n_cells": settings.n_cells, "resolution": settings.resolution, "tol": settings.tol,
           "measured_density": 0.3, "radius": 0.05, **engineering_constants(C)}
    row.update({name: float(C[int(name[1]) - 1, int(name[2]) - 1]) for name in tables.C_ENTRIES})
    ti = closest_transverse_isotropic(C, axis=(1.0, 0.0, 0.0))
    row.update(ti_E_t=ti.E_t, ti_E_l=ti.E_l, ti_nu_t=ti.nu_t, ti_nu_tl=ti.nu_tl, ti_G_l=ti.G_l, ti_error=ti.error)
    iso = closest_isotropic(C)
    row.update(iso_E=iso.E, iso_nu=iso.nu, iso_error=iso.error, iterations=10, wall_s=1.0, version="test")
    entry = tmp_path / tables.cache_name(sample, settings)
    entry.write_text(json.dumps(row))
    return entry, sample, settings


@pytest.mark.parametrize("edit, message", [
    (lambda row: row.update(E1=2 * row["E1"]), "column 'E1' = .* is not the value of its C"),
    (lambda row: row.update(E1=float("nan")), "column 'E1' is nan, not a finite number"),
    (lambda row: row.update(E1="abc"), "column 'E1' is 'abc', not a finite number"),
    (lambda row: row.update(C11=-row["C11"]), "its C is not positive definite"),
])
def test_a_hand_edited_cache_entry_is_named_and_not_used(cached_row, tmp_path, caplog, edit, message):
    import logging
    import re

    from homogenization import tables

    entry, sample, settings = cached_row
    row = json.loads(entry.read_text())
    assert tables.read_cache_entry(entry, sample, settings) == row  # the entry as the sweep wrote it is used
    edit(row)
    edited = tmp_path / entry.name
    edited.write_text(json.dumps(row))
    with caplog.at_level(logging.WARNING, logger="homogenization.tables"):
        assert tables.read_cache_entry(edited, sample, settings) is None
    assert re.search(message, caplog.text) and "recomputed" in caplog.text, caplog.text


def test_a_mesh_in_millimetres_is_refused_naming_metres_not_a_material_instability():
    from fenicsfoam.scene import run_scene

    scene = {"name": "mm", "geometry": {"builder": "finger", "h": 3.0, "length": 120.0, "width": 20.0,
                                        "height": 6.0, "chamber": False},
             "fem": {"model": "linear", "degree": 1},
             "regions": {"finger": {"tags": "finger", "material": "isotropic", "E": 1e6, "nu": 0.3, "rho": 1000.0}},
             "loads": {"gravity": [0.0, 0.0, -9.81], "clamp": "base"}, "steps": [{"label": "g"}]}
    with pytest.raises(SceneError, match=r"^geometry: the mesh is 120 m across, more than the 10 m a robot may be: "
                                         r"fenicsfoam works in metres .* scaled by 0\.001"):
        run_scene(parse_scene(scene))


@pytest.mark.parametrize("scene, message", [
    (lambda: _beam(loads={"clamp": "clamped", "pressure": {"p": {"group": "beam", "pressure": 1.0}}}),
     r"^loads\.pressure\.p\.group: unknown facet group 'beam': it is a volume group \(a cell region\) of the "
     r"mesh, and a surface is needed here; facet groups: clamped, tip"),
    (lambda: _ti_beam({"kind": "uniform", "direction": [0.0, 0.0, 0.0]}),
     r"^orientation\.direction: a direction must be a non-zero vector, got \[0\.0, 0\.0, 0\.0\]"),
    (lambda: _ti_beam({"kind": "per_tag", "directions": {"beam": [0, 0, 0]}}),
     r"^orientation\.directions\.beam: a direction must be a non-zero vector"),
])
def test_a_volume_group_for_a_pressure_and_a_zero_direction_are_named(scene, message):
    with pytest.raises(SceneError, match=message):
        parse_scene(scene())


def test_a_gmsh_volume_left_out_of_the_physical_groups_is_refused_before_meshing(tmp_path):
    """Two boxes, one in a physical volume, a face of the other in a physical surface: gmsh writes that face's
    triangles but not its box's tetrahedra; reading such a file crashed PETSc (SEGV)."""
    import gmsh

    from meshes.msh import physical_groups

    path = tmp_path / "robot.msh"
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        kept = gmsh.model.occ.addBox(0, 0, 0, 0.02, 0.02, 0.02)
        left_out = gmsh.model.occ.addBox(0.02, 0, 0, 0.02, 0.02, 0.02)
        gmsh.model.occ.fragment([(3, kept)], [(3, left_out)])
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [kept], 1)
        far = max(gmsh.model.getBoundary([(3, left_out)], oriented=False),
                  key=lambda face: gmsh.model.occ.getCenterOfMass(*face)[0])  # the face at x = 0.04
        gmsh.model.addPhysicalGroup(2, [far[1]], 10)
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.01)
        gmsh.model.mesh.generate(3)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    with pytest.raises(InputError, match=r"triangle\(s\) of the physical surface groups are faces of no "
                                         r"tetrahedron: a volume is missing from the physical volume groups"):
        physical_groups(path)
    scene = {"geometry": {"builder": "file", "path": str(path)},
             "regions": {"kept": {"tags": 1, "material": "isotropic", "E": 1e6, "nu": 0.3}},
             "loads": {"clamp": 10}, "steps": [{"label": "a"}]}
    with pytest.raises(SceneError, match=r"^geometry\.path: mesh file .*faces of no tetrahedron"):
        parse_scene(scene)


def _api_calls(tmp_path):
    from fenicsfoam.io import read_solution
    from fenicsfoam.material import foam_material
    from fenicsfoam.scene import load_scene
    from homogenization.fft import homogenize_fft
    from homogenization.tensors import engineering_constants, isotropic_voigt
    from meshes.foam import VoronoiFoam

    solid = np.ones((8, 8, 8), dtype=np.int8)
    materials = [np.zeros((6, 6)), isotropic_voigt(1.0, 0.3)]
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "solution.npz").write_bytes(b"not an archive" * 8)
    return {
        "homogenize_fft tol": (lambda: homogenize_fft(solid, materials, tol="1e-4"), "tol must be a number"),
        "homogenize_fft materials": (lambda: homogenize_fft(solid, "ab"), "materials[1] must be a 6×6 Voigt"),
        "foam_material": (lambda: foam_material("0.18", 1.0, 12e6, 0.3), "density must be a number, got str"),
        "to_stl": (lambda: VoronoiFoam(4, 0.3, seed=0).to_stl(".", 16), "to_stl path .: is a directory"),
        "load_scene": (lambda: load_scene(42), "scene: expected a TOML file's path or a dict, got int 42"),
        "parse_scene": (lambda: parse_scene([1, 2]), "scene: expected a table (a dict, as tomllib reads one)"),
        "read_solution": (lambda: read_solution(tmp_path / "run"), "not a solution archive written by a scene run"),
        "engineering_constants": (lambda: engineering_constants("abc"), "C must be a 6×6 matrix of numbers"),
    }


@pytest.mark.parametrize("call", ["homogenize_fft tol", "homogenize_fft materials", "foam_material", "to_stl",
                                  "load_scene", "parse_scene", "read_solution", "engineering_constants"])
def test_public_api_calls_with_bad_arguments_raise_the_family(tmp_path, call):
    from foambase.errors import FenicsfoamError

    function, message = _api_calls(tmp_path)[call]
    with pytest.raises(FenicsfoamError, match=re.escape(message)) as info:
        function()
    assert isinstance(info.value, ValueError)  # an InputError: still the builtin a caller may catch


def test_a_huge_value_is_not_echoed_back_whole(work, capsys):
    (work / "scene.toml").write_text(scene_text().replace('[loads]', f'[fem.petsc]\nsnes_type = "{"x" * 5_000_000}"\n'
                                                                     '[loads]'))
    status, err = status_of([fenicsfoam_main, "run", str(work / "scene.toml"), "--out", str(work / "out")], capsys)
    assert status == 2 and "fem.petsc.snes_type" in err and "characters left out" in err and len(err) < 3000


# --------------------------------------------------------------------------------------------------
# A homogenized stiffness that is singular: the solid does not percolate
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("discretization", ["rotated", "spectral", "hex8"])
def test_homogenize_fft_refuses_a_singular_stiffness_unless_allowed(discretization):
    """Isolated solid blocks in void carry no load: C = 0 within the tolerance, refused; a laminate passes."""
    from foambase.errors import FenicsfoamError
    from homogenization.fft import SingularStiffnessError, homogenize_fft
    from homogenization.tensors import isotropic_voigt

    materials = [np.zeros((6, 6)), isotropic_voigt(1.0, 0.3)]
    blocks = np.zeros((8, 8, 8), np.int8)
    blocks[1:5, 1:5, 1:5] = 1
    # (spectral at tol = 1e-4 leaves a positive definite junk C at 3e-3 tol: checked at 1e-6, see the docs)
    kwargs = dict(discretization=discretization, tol=1e-6 if discretization == "spectral" else 1e-4, threads=1)
    with pytest.raises(SingularStiffnessError, match=r"smallest eigenvalue.*does not percolate.*allow_singular") \
            as info:
        homogenize_fft(blocks, materials, **kwargs)
    assert isinstance(info.value, FenicsfoamError) and info.value.exit_code == 1
    # returned on request: C is zero within the tolerance (the stiffest phase's largest eigenvalue is 2.5)
    r = homogenize_fft(blocks, materials, allow_singular=True, **kwargs)
    assert np.abs(r.C).max() < 1e-4 * 2.5
    # the same solid fraction connected along x only (rods): still singular (no transverse stiffness)
    rods = np.zeros((8, 8, 8), np.int8)
    rods[:, 1:5, 1:5] = 1
    with pytest.raises(SingularStiffnessError):
        homogenize_fft(rods, materials, **kwargs)
    # a percolating porous solid (a cubic void inclusion) is positive definite and passes
    porous = 1 - blocks
    r = homogenize_fft(porous, materials, **kwargs)
    assert np.linalg.eigvalsh(r.C).min() > 1e-2


@pytest.mark.parametrize("text, message", [
    ("", r"samples\.csv: empty file, no header; expected the columns of a foam samples CSV \(density, gamma, seed"),
    ("gamma,seed,E1\n1.0,0,0.1\n", r"samples\.csv: no column 'density' \(nor 'measured_density'"),
    (None, r"samples\.csv: line 3, column 'E1': 'abc' is not a finite number"),
])
def test_uncertainty_samples_without_a_column_or_empty_are_named_before_any_run(work, capsys, text, message):
    from homogenization.tables import table_paths

    if text is None:  # the shipped samples with one value spoilt
        lines = table_paths("cube")["samples"].read_text().splitlines()[:3]
        header = lines[0].split(",")
        row = lines[2].split(",")
        row[header.index("E1")] = "abc"
        text = "\n".join([lines[0], lines[1], ",".join(row)]) + "\n"
    (work / "samples.csv").write_text(text)
    (work / "scene.toml").write_text(scene_text().replace(ISO, FOAM).replace(
        "[loads]", '[orientation]\nkind = "uniform"\ndirection = [1.0, 0.0, 0.0]\n[loads]'))
    status, err = status_of([fenicsfoam_main, "run", str(work / "scene.toml"), "--out", str(work / "out"),
                             "--uncertainty", "--samples", str(work / "samples.csv")], capsys)
    assert status == 2, err
    assert re.search(message, err) and "Traceback" not in err
    assert not (work / "out" / "summary.json").exists()  # refused before the nominal run


def test_material_classes_refuse_a_modulus_above_the_bound_naming_it():
    """The API refuses what the scene refuses: a modulus above 1e13 Pa, named, before any stiffness is formed."""
    from fenicsfoam.material import MAX_MODULUS, InadmissibleMaterialError, Isotropic, TransverseIsotropic
    from fenicsfoam.materials import foam_material

    Isotropic(E=MAX_MODULUS, nu=0.3)  # the bound itself is a modulus
    with pytest.raises(InadmissibleMaterialError, match=r"E must be a modulus in \(0, 1e\+13\] Pa, got E = 1e\+300"):
        Isotropic(E=1e300, nu=0.3)
    with pytest.raises(InadmissibleMaterialError, match=r"G_l must be a modulus .* got G_l = 1e\+14"):
        TransverseIsotropic(E_t=1e6, E_l=2e6, nu_t=0.3, nu_tl=0.3, G_l=1e14)
    with pytest.raises(InadmissibleMaterialError, match=r"transverse isotropy requires .* nu_tl = 1e\+200"):
        TransverseIsotropic(E_t=1e6, E_l=2e6, nu_t=0.3, nu_tl=1e200, G_l=3e5)  # no OverflowError
    with pytest.raises(InadmissibleMaterialError, match=r"E_solid must be a modulus .* got E_solid = 1e\+300"):
        foam_material(0.18, 1.0, 1e300, 0.3)


@pytest.mark.parametrize("extra, message", [
    (["--E-range", "1e6", "1e14"], r"E_solid = 1e\+14 Pa, the E_range's upper end, is refused by scene 'hostile' "
                                   r"before any run: regions\.beam\.E_solid: 100000000000000\.0 is not a modulus "
                                   r"in \(0, 1e\+13\] Pa"),
    (["--E-range", "1e-3", "1e7"], None),  # the lower end is a modulus: the search range is accepted
])
def test_calibrate_checks_every_modulus_it_may_run_before_the_first_run(work, capsys, monkeypatch, extra, message):
    import fenicsfoam.scene

    def no_run(*args, **kwargs):
        raise RuntimeError("a scene was run")

    monkeypatch.setattr(fenicsfoam.scene, "run_scene", no_run)
    (work / "scene.toml").write_text(scene_text().replace(ISO, FOAM).replace(
        "[loads]", '[orientation]\nkind = "uniform"\ndirection = [1.0, 0.0, 0.0]\n[loads]'))
    argv = [fenicsfoam_main, "calibrate", str(work / "scene.toml"), "--probe", "tip_deflection", "--step", "gravity",
            "--target", "-0.01", "--out", str(work / "cal"), *extra]
    if message is None:  # the checks pass: the first run is reached
        with pytest.raises(RuntimeError, match="a scene was run"):
            argv[0](argv[1:])
        return
    status, err = status_of(argv, capsys)
    assert status == 2, err
    assert re.search(message, err) and "Traceback" not in err


def test_a_command_ended_by_the_signal_backstop_prints_the_interrupted_line_last(tmp_path):
    """A main thread stuck in compiled code is ended by the watcher: the command's own last resort (a run's table)
    is printed first, then the usual "PROG COMMAND: interrupted by SIGNAL" line; exit 128 + signal number."""
    script = tmp_path / "stuck.py"
    script.write_text(textwrap.dedent("""
        import hashlib, sys
        from foambase import cli, signals
        signals.FORCE_S = 1.0  # the backstop's deadline, shortened for the test

        def run(args):
            signals.register_last_resort(lambda name: print(f"TABLE of the steps done ({name})", flush=True))
            print("ready", flush=True)
            hashlib.pbkdf2_hmac("sha256", b"x", b"y", 10**9)  # minutes in C without running Python

        command = cli.Command("stuck", "a command stuck in compiled code", lambda parser: None, run)
        sys.exit(cli.dispatch(cli.build_parser("prog", "test", [command]), ["stuck"]))
        """))
    process = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, start_new_session=True)
    try:
        assert process.stdout.readline().strip() == "ready"
        time.sleep(0.2)
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
    assert process.returncode == 130, err
    assert "TABLE of the steps done (SIGINT)" in out
    assert re.search(r"^prog stuck: interrupted by SIGINT \(the main thread was inside a compiled call and was "
                     r"stopped 1 s after the signal\)$", err, re.M) and "Traceback" not in err


def test_ctrl_c_while_the_commands_load_is_one_line_and_exit_130(monkeypatch, capsys):
    # Ctrl-C in the seconds the command modules import the numerical stack: no traceback, the interrupted status
    from fenicsfoam import cli as fenicsfoam_cli
    from foambase import cli

    def interrupted(spec):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "resolve", interrupted)
    assert fenicsfoam_cli.main(["info"]) == cli.EXIT_INTERRUPTED
    err = capsys.readouterr().err
    assert "fenicsfoam: interrupted while loading" in err and "Traceback" not in err
