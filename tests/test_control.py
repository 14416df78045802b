"""Inverse servo control (fenicsfoam.control): it recovers a forward run whose angles it did not see (all four centre
probes to 1e-6), finds the least motion with fewer targets, reports unreachable targets with the closest pose, refuses
bad input before any work, and the command gives the same answer serially and under mpirun -n 2."""

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from fenicsfoam.cli import main
from fenicsfoam.control import InverseController, UnreachableTargetError, _tangent_basis, control_servos
from fenicsfoam.scene import parse_scene, run_scene
from foambase.errors import InputError, NotConvergedError

ROOT = Path(__file__).resolve().parents[1]
PROBES = ["center_height", "center_rotation", "center_tilt_x", "center_tilt_y"]
UNSEEN = [30.0, 22.0, 35.0]  # the forward run's angles; the controller starts from the scene's 38°, 38°, 38°


def case_b(**last_step) -> dict:
    data = tomllib.loads((ROOT / "demos" / "scenes" / "tripod_case_b_flat.toml").read_text())
    data["geometry"]["h"] = 0.008
    data["outputs"] = {"png": False, "xdmf": False}
    data["probes"] = PROBES
    data["steps"][-1].update(last_step)
    return data


@pytest.fixture(scope="module")
def forward():
    """The probes of a plain scene run at the unseen angles (the scene's load path, from the reference state)."""
    return run_scene(parse_scene(case_b(servo_deg=UNSEEN))).steps[-1].probes


@pytest.mark.mpi
def test_three_targets_recover_an_unseen_forward_run(forward):
    targets = {k: forward[k] for k in ("center_height", "center_rotation", "center_tilt_x")}
    controller = InverseController(parse_scene(case_b()))
    result = controller.solve(targets)
    assert result.reached and result.initial_deg == [38.0, 38.0, 38.0]
    np.testing.assert_allclose(result.servo_deg, UNSEEN, rtol=0, atol=1e-5)
    # every probe of the controlled state (including the untargeted tilt about y) equals the forward run's
    values = controller.design.values()
    for name in PROBES:
        assert values[name] == pytest.approx(forward[name], rel=1e-6), name
    assert result.scene_solves >= result.iterations + 1 and result.iterations <= 15
    # a second solve starts from this one (warm start): the same targets are met at once
    again = controller.solve(targets)
    assert again.iterations == 0 and again.scene_solves == 1


def test_fewer_targets_give_the_least_motion(forward):
    targets = {k: forward[k] for k in ("center_height", "center_rotation")}
    controller = InverseController(parse_scene(case_b()))
    result = controller.solve(targets)
    theta, theta0 = np.array(result.servo_deg), np.array(result.initial_deg)
    for name, value in targets.items():
        assert result.achieved[name] == pytest.approx(value, rel=1e-6)
    # the unseen angles meet the same targets: the least motion is no longer than theirs
    assert np.linalg.norm(theta - theta0) <= np.linalg.norm(np.array(UNSEEN) - theta0) + 1e-6
    # KKT: θ − θ⁰ is orthogonal to the targets' level set (its tangent: the null space of their gradients)
    gradients = controller.design.gradient(list(targets), ["servo0", "servo1", "servo2"])
    G = np.array([[gradients[n][s] for s in ("servo0", "servo1", "servo2")] for n in targets])
    assert np.max(np.abs(_tangent_basis(G).T @ (theta - theta0))) < 1e-4


def test_an_unconverged_least_motion_is_an_error(forward, tmp_path):
    # the same request with too few steps for the least-motion iteration: the targets are met, but not the KKT
    # condition, so it is an error (exit 3) and control.json holds the last pose with reached = false
    targets = {k: forward[k] for k in ("center_height", "center_rotation")}
    with pytest.raises(NotConvergedError, match="did not converge in 12 iterations") as info:
        control_servos(parse_scene(case_b()), targets, max_iterations=12, out_dir=tmp_path)
    assert info.value.exit_code == 3 and info.value.closest.kkt_residual > 1e-3
    written = json.loads((tmp_path / "control.json").read_text())
    assert written["reached"] is False and written["servo_deg"] == info.value.closest.servo_deg


def test_an_unreachable_target_reports_the_closest_pose(tmp_path):
    with pytest.raises(UnreachableTargetError, match="outside the reachable set") as info:
        control_servos(parse_scene(case_b()), {"center_height": 0.08}, out_dir=tmp_path)
    closest = info.value.closest
    assert info.value.exit_code == 3 and not closest.reached
    assert 0.02 < closest.achieved["center_height"] < 0.08
    written = json.loads((tmp_path / "control.json").read_text())
    assert written["reached"] is False and written["servo_deg"] == closest.servo_deg
    # the closest pose is a local maximum of the height: a step either way along the servos lowers it
    design = InverseController(parse_scene(case_b())).design
    design.set_servo_deg(closest.servo_deg)
    top = design.solve()["center_height"]
    for delta in (-0.5, 0.5):
        if -20 <= closest.servo_deg[0] + delta <= 60:
            assert design.solve_last(np.array(closest.servo_deg) + delta)["center_height"] < top


@pytest.mark.parametrize("targets, kwargs, message", [
    ({"center_heigth": 0.02}, {}, "unknown target 'center_heigth'"),
    ({"center_height": float("nan")}, {}, "finite"),
    ({}, {}, "at least one target"),
    ({"center_height": 0.02}, {"servo_range": (40.0, 60.0)}, r"initial servo angles \[38.0, 38.0, 38.0\]"),
    ({"center_height": 0.02}, {"servo_range": (10.0, 5.0)}, "servo range"),
])
def test_bad_input_is_refused_before_any_work(targets, kwargs, message, monkeypatch):
    import fenicsfoam.design
    monkeypatch.setattr(fenicsfoam.design.SceneDesign, "__init__", lambda *a, **k: pytest.fail("built a model"))
    with pytest.raises(InputError, match=message):
        control_servos(parse_scene(case_b()), targets, **kwargs)


def test_a_scene_without_servos_is_refused():
    data = tomllib.loads((ROOT / "demos" / "scenes" / "beam_ti_z.toml").read_text())
    with pytest.raises(InputError, match="needs the tripod builder with three servos"):
        control_servos(parse_scene(data), {"center_height": 0.02})


def write_scene(path: Path) -> Path:
    data = case_b()
    lines = [f'name = "{data["name"]}"', f'probes = {json.dumps(PROBES)}', "[geometry]", 'builder = "tripod"',
             "h = 0.008", "[fem]"]
    lines += [f"{k} = {json.dumps(v)}" for k, v in data["fem"].items() if k != "petsc"]
    lines += ["[regions.plate]"]
    lines += [f"{k} = {json.dumps(v)}" for k, v in data["regions"]["plate"].items()]
    lines += ["[orientation]"] + [f"{k} = {json.dumps(v)}" for k, v in data["orientation"].items()]
    lines += ["[loads]", "gravity = [0.0, 0.0, -9.81]", "servos = true", "[outputs]", "png = false", "xdmf = false"]
    for step in data["steps"]:
        lines += ["[[steps]]"] + [f"{k} = {json.dumps(v)}" for k, v in step.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_command_line_exit_codes(tmp_path, forward, capsys):
    scene = write_scene(tmp_path / "b.toml")
    with pytest.raises(SystemExit) as exit_info:
        main(["control", str(scene), "--target", "center_height=nope", "--out", str(tmp_path / "x")])
    assert exit_info.value.code == 2 and not (tmp_path / "x").exists()
    (tmp_path / "a_file").write_text("")
    assert main(["control", str(scene), "--target", "center_height=0.02", "--out", str(tmp_path / "a_file")]) == 2
    assert "is a file, not a directory" in capsys.readouterr().err
    assert main(["control", str(scene), "--target", "center_height=0.08", "--out", str(tmp_path / "far")]) == 3
    assert json.loads((tmp_path / "far" / "control.json").read_text())["reached"] is False
    status = main(["control", str(scene), "--target", f"center_height={forward['center_height']!r}",
                   "--out", str(tmp_path / "ok")])
    assert status == 0
    written = json.loads((tmp_path / "ok" / "control.json").read_text())
    assert list(written)[:5] == ["servo_deg", "target", "achieved", "iterations", "scene_solves"]
    assert written["achieved"]["center_height"] == pytest.approx(forward["center_height"], rel=1e-6)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns its own serial and mpirun processes")
def test_mpirun_equals_serial(tmp_path, forward):
    scene = write_scene(tmp_path / "b.toml")
    targets = [f"--target={k}={forward[k]!r}" for k in ("center_height", "center_rotation", "center_tilt_x")]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMPI_ALLOW_RUN_AS_ROOT": "1",
           "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1", "OMPI_MCA_rmaps_base_oversubscribe": "1"}
    command = [sys.executable, "-m", "mpi4py", "-m", "fenicsfoam.cli", "control", str(scene), *targets]
    results = {}
    for name, prefix in (("serial", []), ("mpi", ["mpirun", "-n", "2"])):
        subprocess.run([*prefix, *command, "--out", str(tmp_path / name)], check=True, env=env, cwd=tmp_path,
                       capture_output=True, timeout=900)
        results[name] = json.loads((tmp_path / name / "control.json").read_text())
    serial, mpi = results["serial"], results["mpi"]
    np.testing.assert_allclose(mpi["servo_deg"], serial["servo_deg"], rtol=0, atol=1e-7)
    for name, value in serial["achieved"].items():
        assert mpi["achieved"][name] == pytest.approx(value, rel=1e-9)
    assert mpi["iterations"] == serial["iterations"]
