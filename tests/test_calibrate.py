"""Calibration of E_solid: a known modulus is recovered from a synthetic target (a scene run at that modulus),
unreachable targets and bad requests raise errors naming the value, the calibration file round-trips with the
foam tables it was calibrated through, and a region reading another table refuses it.

The scenes are the shipped Fig. 6 isotropic foam beam and Tripod case B at coarse meshes.
"""

import hashlib
import json
import math
import re
import shutil
import tomllib
from pathlib import Path

import pytest
from mpi4py import MPI

import fenicsfoam.scene
from fenicsfoam.calibrate import (
    CalibrationError,
    calibrate_E_solid,
    calibration_tables,
    foam_table_records,
    read_calibration,
    scene_with_E_solid,
)
from fenicsfoam.scene import SceneError, parse_scene, run_scene
from homogenization.tables import DEFAULT_TABLE, table_paths

SCENES = Path(__file__).resolve().parents[1] / "demos" / "scenes"
COARSE_BEAM_H = 0.0075   # 688 tets
E_TRUE = 7.3e6           # the modulus the synthetic targets are made with (the scenes say 12 MPa)


def iso_beam_text() -> str:
    """The shipped isotropic beam's scene text on the default table (no `table` key): these tests calibrate on
    synthetic targets, whatever the table, and their records name the default table."""
    text = (SCENES / "beam_iso.toml").read_text()
    return "\n".join(line for line in text.splitlines() if not line.startswith("table = ")) + "\n"


def beam(model="linear"):
    scene = tomllib.loads(iso_beam_text())
    scene["geometry"]["h"] = COARSE_BEAM_H
    scene["fem"]["model"] = model
    scene["outputs"] = {"xdmf": False, "png": False}
    return scene


def synthetic(scene, probe, step, relative_to=None):
    """The probe of ``scene`` run with every foam's E_solid = E_TRUE: a measurement whose answer is known."""
    result = run_scene(scene_with_E_solid(scene, E_TRUE), comm=MPI.COMM_SELF)
    return result.probe(probe, relative_to=relative_to)[step]


@pytest.mark.parametrize("model", ["linear", "corotational"])
def test_recovers_a_known_E_solid_on_the_beam(model, tmp_path):
    scene = beam(model)
    target = synthetic(scene, "tip_deflection", "gravity")
    cal = calibrate_E_solid(scene, "tip_deflection", "gravity", target, out_dir=tmp_path, comm=MPI.COMM_SELF)
    assert cal.E_solid == pytest.approx(E_TRUE, rel=1e-6)
    assert cal.achieved == pytest.approx(target, rel=1e-6)
    if model == "linear":  # u = u_D + u_f / E exactly: two runs and a check
        assert cal.runs == 3 and cal.method.startswith("affine")
    else:
        assert cal.method.startswith("Brent") and cal.runs <= 20
    written = json.loads((tmp_path / "calibration.json").read_text())
    assert {"E_solid", "probe", "target", "achieved", "runs"} <= set(written)
    assert written["E_solid"] == cal.E_solid and written["runs"] == cal.runs
    assert read_calibration(tmp_path / "calibration.json") == cal.E_solid
    default = {"table": DEFAULT_TABLE, "regions": ["beam"],
               "sha256": hashlib.sha256(table_paths(DEFAULT_TABLE)["table"].read_bytes()).hexdigest()}
    assert written["foam_tables"] == [default] and calibration_tables(tmp_path / "calibration.json") == [default]


def test_recovers_a_known_E_solid_from_a_component_of_a_group_probe():
    """The tip face's mean vertical displacement (affine in u: exact in 3 runs), and a blocked force: the tip held
    5 mm down by a motion, its reaction's z component (proportional to E_solid, found by Brent's method)."""
    scene = beam("linear")
    scene["probes"] = ["displacement:tip"]
    target = synthetic(scene, "displacement:tip", "gravity")[2]
    cal = calibrate_E_solid(scene, "displacement:tip", "gravity", target, component="z", comm=MPI.COMM_SELF)
    assert cal.E_solid == pytest.approx(E_TRUE, rel=1e-6) and cal.runs == 3 and cal.method.startswith("affine")
    assert cal.to_dict()["component"] == "z"
    pushed = beam("linear")
    pushed["probes"] = ["reaction_force:tip"]
    pushed["loads"]["motion"] = {"cell": {"group": "tip"}}
    pushed["steps"][0]["motions"] = {"cell": {"translation": [0.0, 0.0, -0.005]}}
    force = synthetic(pushed, "reaction_force:tip", "gravity")[2]
    cal = calibrate_E_solid(pushed, "reaction_force:tip", "gravity", force, component="z", comm=MPI.COMM_SELF)
    assert cal.E_solid == pytest.approx(E_TRUE, rel=1e-6) and cal.method.startswith("Brent")


@pytest.mark.parametrize("model", ["linear", "corotational"])
def test_the_reaction_to_gravity_alone_does_not_depend_on_E_solid(model):
    """The clamp carries the weight whatever the modulus: refused after the two affine runs, not searched."""
    scene = beam(model)
    with pytest.raises(CalibrationError, match=r"reaction_force:clamped \(z\) at step 'gravity' does not depend "
                                               r"on E_solid"):
        calibrate_E_solid(scene, "reaction_force:clamped", "gravity", 0.13, component="z", comm=MPI.COMM_SELF)


@pytest.mark.slow
def test_recovers_a_known_E_solid_from_the_tripod_torsion():
    """A nonlinear probe (the Kabsch twist) of a nonlinear model, as a change from rest."""
    scene = tomllib.loads((SCENES / "tripod_case_b_flat.toml").read_text())
    scene["geometry"]["h"] = 0.0075
    scene["outputs"] = {"xdmf": False, "png": False}
    target = synthetic(scene, "center_rotation", "top", relative_to="rest")
    cal = calibrate_E_solid(scene, "center_rotation", "top", target, relative_to="rest", comm=MPI.COMM_SELF)
    assert cal.E_solid == pytest.approx(E_TRUE, rel=1e-6)


@pytest.mark.parametrize("model", ["linear", "corotational"])
def test_a_target_of_the_wrong_sign_is_unreachable(model):
    """Gravity alone bends the beam down: no modulus gives an upward tip (+10 mm)."""
    with pytest.raises(CalibrationError, match=r"target 0\.01 is not reachable.*wrong sign"):
        calibrate_E_solid(beam(model), "tip_deflection", "gravity", 0.01, comm=MPI.COMM_SELF)


def test_a_target_beyond_the_searched_moduli_is_unreachable():
    with pytest.raises(CalibrationError, match=r"target -0\.5 is not reachable .* E_solid in \[6e\+06, 2\.4e\+07\]"):
        calibrate_E_solid(beam("corotational"), "tip_deflection", "gravity", -0.5, E_range=(6e6, 24e6),
                          comm=MPI.COMM_SELF)


@pytest.mark.parametrize("change, match", [
    ({"probe": "tip_angle"}, r"probe 'tip_angle' is unknown; valid: tip_deflection"),
    ({"step": "top"}, r"step 'top' is not a step of scene 'beam_iso'; its steps: \['gravity'\]"),
    ({"relative_to": "gravity"}, r"relative_to 'gravity' is the calibrated step itself"),
    ({"target": math.nan}, r"target nan must be a finite number"),
    ({"E_range": (5e6, 1e6)}, r"E_range \(5000000\.0, 1000000\.0\) must be two increasing positive moduli"),
    ({"probe": "reaction_force:clamped"}, r"probe 'reaction_force:clamped' is a vector \(x, y, z\): give the component "
                                          r"to match, 'x', 'y' or 'z' \(--component\)$"),
    ({"probe": "displacement:tip", "component": "w"}, r"'displacement:tip' is a vector .*\('w' is not one\)"),
    ({"component": "z"}, r"probe 'tip_deflection' is a number, not a vector: give no component \(got 'z'\)"),
    ({"probe": "strain:tip"}, r"probe 'strain:tip' is unknown; valid: .* KIND:GROUP with KIND one of reaction_force"),
])
def test_bad_requests_fail_before_any_run(monkeypatch, change, match):
    def no_run(*args, **kwargs):
        raise AssertionError("a scene was run")

    monkeypatch.setattr(fenicsfoam.scene, "run_scene", no_run)
    request = {"probe": "tip_deflection", "step": "gravity", "target": -0.048, **change}
    with pytest.raises(CalibrationError, match=match):
        calibrate_E_solid(beam(), request.pop("probe"), request.pop("step"), request.pop("target"), **request)


def test_a_scene_without_foam_or_with_two_moduli_is_refused():
    scene = beam()
    scene["regions"]["beam"] = {"tags": "beam", "material": "isotropic", "E": 3e5, "nu": 0.3, "rho": 200.0}
    with pytest.raises(CalibrationError, match=r"scene 'beam_iso' has no foam region.*beam \(isotropic\)"):
        calibrate_E_solid(scene, "tip_deflection", "gravity", -0.048)
    scene = tomllib.loads((SCENES / "tripod_case_a_flat.toml").read_text())
    scene["regions"]["centre"]["E_solid"] = 10e6
    with pytest.raises(CalibrationError, match=r"different E_solid \(\{'arms': 12000000\.0, 'centre': 10000000\.0\}\)"):
        calibrate_E_solid(scene, "center_height", "top", 0.02, relative_to="rest")


def test_a_probe_that_does_not_depend_on_E_solid_is_refused():
    """Linear model, no gravity, servos only: the displacement is the prescribed motion's, whatever E_solid."""
    scene = tomllib.loads((SCENES / "tripod_case_b_flat.toml").read_text())
    scene["geometry"]["h"] = 0.0075
    scene["fem"]["model"] = "linear"
    del scene["loads"]["gravity"]
    for step in scene["steps"]:
        step.pop("gravity", None)
    with pytest.raises(CalibrationError, match=r"center_height at step 'top' does not depend on E_solid"):
        calibrate_E_solid(scene, "center_height", "top", 0.02, comm=MPI.COMM_SELF)


@pytest.mark.parametrize("content, match", [
    (None, r"cannot read calibration file"),
    ("{", r"is not valid JSON"),
    ('{"E_solid": -3}', r"'E_solid' must be a positive modulus in Pa, got -3"),
    ('{"probe": "x"}', r"'E_solid' must be a positive modulus in Pa, got None"),
])
def test_read_calibration_names_the_problem(tmp_path, content, match):
    path = tmp_path / "calibration.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(CalibrationError, match=match):
        read_calibration(path)


def test_a_scene_takes_E_solid_from_a_calibration_file(tmp_path):
    """`E_solid = {calibration = "..."}` (relative to the scene file) runs as the same scene with the number."""
    from fenicsfoam.scene import SceneError, load_scene

    (tmp_path / "cal").mkdir()
    calibration_through(tmp_path / "cal", DEFAULT_TABLE)  # the beam's table
    text = iso_beam_text().replace("h = 0.0024", f"h = {COARSE_BEAM_H}")
    calibrated = text.replace("E_solid = 12e6", 'E_solid = {calibration = "cal/calibration.json"}')
    assert calibrated != text
    (tmp_path / "beam.toml").write_text(calibrated + '\n[outputs]\nxdmf = false\npng = false\n')
    scene = load_scene(tmp_path / "beam.toml")
    assert scene.regions[0].parameters["E_solid"] == E_TRUE
    expected = synthetic(beam("corotational"), "tip_deflection", "gravity")
    assert run_scene(scene, comm=MPI.COMM_SELF).probe("tip_deflection")["gravity"] == pytest.approx(expected,
                                                                                                   rel=1e-12)
    (tmp_path / "beam.toml").write_text(text.replace("E_solid = 12e6", 'E_solid = {calibration = "missing.json"}'))
    with pytest.raises(SceneError, match=r"regions\.beam\.E_solid\.calibration: cannot read calibration file .*"
                                         r"missing\.json"):
        load_scene(tmp_path / "beam.toml")
    (tmp_path / "beam.toml").write_text(text.replace("E_solid = 12e6", 'E_solid = {file = "cal.json"}'))
    with pytest.raises(SceneError, match=r"regions\.beam\.E_solid\.calibration: missing value"):
        load_scene(tmp_path / "beam.toml")


# --------------------------------------------------------------------------------------------------
# The foam tables a calibration was made through
# --------------------------------------------------------------------------------------------------
def calibration_through(directory, *tables, E_solid=E_TRUE):
    """A calibration file recording ``tables`` (as ``calibrate_E_solid`` records them), and its path."""
    path = directory / "calibration.json"
    record = foam_table_records((f"r{i}", table) for i, table in enumerate(tables))
    path.write_text(json.dumps({"E_solid": E_solid, "probe": "tip_deflection", "foam_tables": record}))
    return path


def beam_taking(path, table=None):
    """The coarse beam whose region reads ``table`` (None: no key, the default) and takes E_solid from ``path``."""
    scene = beam()
    scene["regions"]["beam"]["E_solid"] = {"calibration": str(path)}
    if table is not None:
        scene["regions"]["beam"]["table"] = str(table)
    return scene


@pytest.mark.parametrize("recorded, read", [
    ([DEFAULT_TABLE], None), (["equiaxed"], "equiaxed"), (["cube", "equiaxed"], "copy-of-cube"),
    (["cube"], "equiaxed"), (["equiaxed"], None), (["equiaxed"], "cube"), (["cube"], None)])
def test_a_region_reading_its_calibration_table_takes_it(tmp_path, recorded, read):
    """The region's table among the recorded ones: the modulus is taken (tables are compared by content: a CSV
    copy of a recorded table is that table); another table: refused, naming the region and both tables."""
    copy = tmp_path / "copy-of-cube.csv"
    shutil.copyfile(table_paths("cube")["table"], copy)
    read = copy if read == "copy-of-cube" else read
    path = calibration_through(tmp_path, *recorded)
    scene = beam_taking(path, read)
    if (read or DEFAULT_TABLE) in recorded or read == copy:
        assert parse_scene(scene).regions[0].parameters["E_solid"] == E_TRUE
        return
    theirs = recorded[0]
    mine = read or DEFAULT_TABLE
    with pytest.raises(SceneError, match=rf"regions\.beam\.E_solid\.calibration: region 'beam' reads foam table "
                                         rf"'{mine}', but calibration file .* was calibrated through foam table "
                                         rf"'{theirs}': .*Calibrate through '{mine}'"):
        parse_scene(scene)


def test_a_calibration_file_without_its_tables_is_the_former_default_table(tmp_path):
    """An older file without `foam_tables`: calibrated through `cube`, the default table when it was written, so a
    `cube` region takes it and a region on today's default table or on `equiaxed` refuses it."""
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps({"E_solid": E_TRUE, "probe": "tip_deflection"}))
    assert [r["table"] for r in calibration_tables(path)] == ["cube"]
    assert parse_scene(beam_taking(path, "cube")).regions[0].parameters["E_solid"] == E_TRUE
    for table, mine in ((None, DEFAULT_TABLE), ("equiaxed", "equiaxed")):
        with pytest.raises(SceneError, match=rf"reads foam table '{mine}', but .* through foam table 'cube' \(a "
                                             r"calibration file without a 'foam_tables' record is taken as "
                                             r"calibrated through the former default table 'cube'\)"):
            parse_scene(beam_taking(path, table))


def test_a_table_regenerated_since_the_calibration_is_refused(tmp_path):
    table = tmp_path / "table.csv"
    shutil.copyfile(table_paths("equiaxed")["table"], table)
    path = calibration_through(tmp_path, table)
    assert parse_scene(beam_taking(path, table)).regions[0].parameters["E_solid"] == E_TRUE
    rows = table.read_text().splitlines()
    header, first = rows[0].split(","), rows[1].split(",")
    k = header.index("iso_E")
    first[k] = repr(1.01 * float(first[k]))  # the table recomputed: one modulus 1 % off
    table.write_text("\n".join([rows[0], ",".join(first), *rows[2:]]) + "\n")
    with pytest.raises(SceneError, match=rf"reads foam table '{re.escape(str(table))}', which has changed since "
                                         r"calibration file .* calibrate again"):
        parse_scene(beam_taking(path, table))


@pytest.mark.parametrize("record", [[], [{"table": "cube"}], "cube"])
def test_a_malformed_table_record_is_named(tmp_path, record):
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps({"E_solid": E_TRUE, "foam_tables": record}))
    with pytest.raises(SceneError, match=r"'foam_tables' must be a non-empty list of"):
        parse_scene(beam_taking(path))


def test_two_tables_two_calibrations_each_scene_takes_its_own(tmp_path, monkeypatch):
    """demos/experiments.py calibrates the beam once per foam table. With the linear model the tip sag is
    proportional to 1 / (E_s · q) (q: the table's iso_E at 18 %, γ = 1; the two tables' ν differ by 0.001), so the
    two calibrated E_s differ by the tables' ratio of q (11 %) while E_s · q agrees; each scene then runs with the
    calibration of the table its foam reads, and the other table's calibration is refused."""
    from fenicsfoam.materials import foam_material

    monkeypatch.syspath_prepend(str(SCENES.parent))
    import experiments
    base = beam("linear")
    cals = experiments.calibrate_tables(base, ["cube", "equiaxed"], tmp_path, MPI.COMM_SELF)
    q = {t: foam_material(0.18, 1.0, 1.0, 0.3, fit="isotropic", table=t).E for t in cals}
    assert cals["equiaxed"].E_solid / cals["cube"].E_solid == pytest.approx(q["cube"] / q["equiaxed"], rel=2e-3)
    assert abs(cals["equiaxed"].E_solid / cals["cube"].E_solid - 1) > 0.05
    for t, cal in cals.items():
        assert cal.achieved == pytest.approx(experiments.CALIBRATION[3], rel=1e-8)
        assert [r["table"] for r in cal.foam_tables] == [t]
    files = {t: d / "calibration.json" for t, d in experiments.calibration_dirs(tmp_path, list(cals)).items()}
    assert [read_calibration(files[t]) for t in cals] == [cal.E_solid for cal in cals.values()]

    load = experiments.load_scene_dict

    def beams_equiaxed(name, **kwargs):  # the beams on another table than the Tripods
        data = load(name, **kwargs)
        for region in experiments.foam_regions(data):
            region["table"] = "equiaxed" if name.startswith("beam") else "cube"
        return data

    monkeypatch.setattr(experiments, "load_scene_dict", beams_equiaxed)
    names = ("beam_ti_y", "tripod_case_b_flat")
    assert experiments.scene_tables([experiments.scene(n, True, 1) for n in names]) == ["equiaxed", "cube"]
    for name, table in zip(names, ("equiaxed", "cube")):
        data = experiments.scene(name, True, 1, files)
        assert experiments.scene_E_solid(data) == cals[table].E_solid
        assert {r.parameters["E_solid"] for r in parse_scene(data).regions if r.material == "foam"} == {
            cals[table].E_solid}
    wrong = experiments.scene("beam_ti_y", True, 1, {"equiaxed": files["cube"]})
    with pytest.raises(SceneError, match=r"region 'beam' reads foam table 'equiaxed', but .* through foam table "
                                         r"'cube'"):
        parse_scene(wrong)


# --------------------------------------------------------------------------------------------------
# fenicsfoam calibrate
# --------------------------------------------------------------------------------------------------
MPI_ENV = {"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
           "OMPI_MCA_btl_vader_single_copy_mechanism": "none", "OMPI_MCA_rmaps_base_oversubscribe": "1",
           "OPENBLAS_NUM_THREADS": "1"}


def beam_file(directory, model="linear"):
    """The coarse beam as a scene file (the command line reads files): the shipped text, mesh and model edited."""
    text = iso_beam_text()
    edited = text.replace("h = 0.0024", f"h = {COARSE_BEAM_H}").replace('model = "corotational"', f'model = "{model}"')
    assert edited.count(str(COARSE_BEAM_H)) == 1 and f'model = "{model}"' in edited
    path = directory / "beam.toml"
    path.write_text(edited + '\n[outputs]\nxdmf = false\npng = false\n')
    return path


def test_cli_recovers_a_known_E_solid_and_writes_calibration_json(tmp_path, capsys):
    from fenicsfoam.cli import main

    target = synthetic(beam("linear"), "tip_deflection", "gravity")
    out = tmp_path / "cal"
    assert main(["calibrate", str(beam_file(tmp_path)), "--probe", "tip_deflection", "--step", "gravity",
                 "--target", repr(target), "--out", str(out)]) == 0
    written = json.loads((out / "calibration.json").read_text())
    assert written["E_solid"] == pytest.approx(E_TRUE, rel=1e-6)
    assert written["achieved"] == pytest.approx(target, rel=1e-6) and written["target"] == target
    assert written["probe"] == "tip_deflection" and written["runs"] == 3 and written["E_solid_initial"] == 12e6
    printed = capsys.readouterr().out
    assert "E_solid = " in printed and f"through foam table '{DEFAULT_TABLE}'" in printed


@pytest.mark.parametrize("argv, message", [
    (["--target", "nan"], "--target must be a finite number (the probe's SI unit), got nan"),
    (["--target", "-0.048", "--rtol", "0"], "--rtol must be in (0, 1), got 0.0"),
    (["--target", "-0.048", "--E-range", "2e7", "1e7"], "--E-range must be two increasing positive moduli"),
])
def test_cli_usage_errors_exit_2_before_any_run(tmp_path, monkeypatch, capsys, argv, message):
    from fenicsfoam.cli import main

    def no_run(*args, **kwargs):
        raise AssertionError("a scene was run")

    monkeypatch.setattr(fenicsfoam.scene, "run_scene", no_run)
    with pytest.raises(SystemExit) as info:
        main(["calibrate", str(beam_file(tmp_path)), "--probe", "tip_deflection", "--step", "gravity", *argv,
              "--out", str(tmp_path / "cal")])
    assert info.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "cal").exists()


def test_cli_bad_requests_exit_2_naming_the_value(tmp_path, monkeypatch, capsys):
    """An unknown probe or a missing scene: before any run; a wrong-sign target: after the two affine runs."""
    from fenicsfoam.cli import main

    scene = str(beam_file(tmp_path))
    out = str(tmp_path / "cal")
    real_run_scene = fenicsfoam.scene.run_scene
    monkeypatch.setattr(fenicsfoam.scene, "run_scene", lambda *a, **k: pytest.fail("a scene was run"))
    assert main(["calibrate", scene, "--probe", "tip_angle", "--step", "gravity", "--target", "1", "--out", out]) == 2
    assert "probe 'tip_angle' is unknown; valid: tip_deflection" in capsys.readouterr().err
    assert main(["calibrate", str(tmp_path / "missing.toml"), "--probe", "tip_deflection", "--step", "gravity",
                 "--target", "-0.048", "--out", out]) == 2
    assert "missing.toml" in capsys.readouterr().err
    monkeypatch.setattr(fenicsfoam.scene, "run_scene", real_run_scene)
    assert main(["calibrate", scene, "--probe", "tip_deflection", "--step", "gravity", "--target", "0.01",
                 "--out", out]) == 2
    assert "target 0.01 is not reachable" in capsys.readouterr().err
    assert not (tmp_path / "cal").exists()


def test_cli_under_mpirun_matches_the_serial_calibration(tmp_path):
    """Two ranks find the serial E_solid (the probes do not depend on the partition); errors are printed once."""
    import os
    import subprocess
    import sys

    scene = beam_file(tmp_path)
    target = synthetic(beam("linear"), "tip_deflection", "gravity")
    base = ["mpirun", "-n", "2", sys.executable, "-m", "mpi4py", "-m", "fenicsfoam.cli", "calibrate", str(scene),
            "--probe", "tip_deflection", "--step", "gravity", "--out", str(tmp_path / "cal")]
    env = {**os.environ, **MPI_ENV}
    ok = subprocess.run([*base, "--target", repr(target)], capture_output=True, text=True, env=env, timeout=600)
    assert ok.returncode == 0, ok.stderr[-3000:]
    assert ok.stdout.count("E_solid = ") == 1
    assert json.loads((tmp_path / "cal" / "calibration.json").read_text())["E_solid"] == pytest.approx(E_TRUE,
                                                                                                        rel=1e-6)
    bad = subprocess.run([*base, "--target", "0.01"], capture_output=True, text=True, env=env, timeout=600)
    assert bad.returncode == 2, bad.stderr[-3000:]
    assert bad.stderr.count("target 0.01 is not reachable") == 1
