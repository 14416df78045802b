"""Inverse actuation of any actuator (fenicsfoam.control, fenicsfoam.design): the adjoint gradients of pressure and
cable factors (second-order Taylor remainders, also of a contact force), a pressure recovered from a forward run it
did not see (a displacement target and a contact-force target), the closest state when out of reach (exit 3), and
bad input refused before any work."""

import copy
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from fenicsfoam.control import InverseController, control_servos
from fenicsfoam.design import SceneDesign
from fenicsfoam.scene import parse_scene, run_scene
from foambase.errors import InputError

SCENES = Path(__file__).resolve().parents[1] / "demos" / "scenes"
UNSEEN = 0.6  # the forward run's pressure factor (12 kPa); the controller starts from the scene's 0.25
CONTACT = 0.8  # a pressure factor (16 kPa) at which the tip presses on the table (it lands near 0.6)


def finger(name="finger_pneumatic", contact=False, factor=0.25):
    """The demo finger, coarse (h = 4 mm, P1): rest, then one actuation step; optionally a table under its tip."""
    data = tomllib.loads((SCENES / f"{name}.toml").read_text())
    data["geometry"]["h"] = 0.004
    data["fem"]["degree"] = 1
    data["fem"]["petsc"] = {"snes_rtol": 1e-12}
    data["outputs"] = {"png": False, "xdmf": False}
    load = "chamber" if name == "finger_pneumatic" else "tendon"
    data["steps"] = [data["steps"][0], {"label": "actuate", "loads": {load: factor}}]
    data["probes"] = ["displacement:tip"]
    if contact:  # 4.5 mm under the tip face's bottom edge: the tip lands on it above ~0.6 (12 kPa)
        data["contacts"] = {"table": {"group": "tip", "obstacle": "plane", "point": [0.0, 0.0, -0.012],
                                      "normal": [0.0, 0.0, 1.0]}}
        data["probes"].append("contact_force:table")
    return data


def taylor_rates(design, load, probes):
    steps = 0.2 / 2.0 ** np.arange(4)
    base = design.solve()
    gradient = design.gradient(probes, [load])
    s0 = design.get(load)
    remainders = {p: [] for p in probes}
    for h in steps:
        design.set({load: s0 + h})
        values = design.solve_last_step()
        for p in probes:
            remainders[p].append(abs(values[p] - base[p] - h * gradient[p][load]))
    return {p: np.log2(np.array(r[:-1]) / np.array(r[1:])) for p, r in remainders.items()}


@pytest.mark.mpi
@pytest.mark.parametrize("name, load, contact", [("finger_pneumatic", "chamber", True),
                                                 ("finger_cable", "tendon", False)])
def test_load_factor_gradients_are_exact(name, load, contact):
    # a gradient error δ would leave a remainder ~ h δ (rate 1); exact gradients give rate 2
    # from a factor where the tip presses on the table (the steps only press it harder): a smooth contact force
    design = SceneDesign(parse_scene(finger(name, contact, factor=CONTACT if contact else 0.5)))
    probes = ["displacement:tip[2]", "displacement:tip[0]"] + (["contact_force:table[2]"] if contact else [])
    for p in probes:
        design.add_probe(p)
    if contact:
        assert design.solve()["contact_force:table[2]"] > 1e-3, "the tip must press on the table at the base factor"
    rates = taylor_rates(design, load, probes)
    for p, r in rates.items():
        assert r[-1] > 1.9 and r.min() > 1.5, (p, r)


@pytest.mark.mpi
@pytest.mark.parametrize("contact", [False, True])
def test_inverse_actuation_recovers_an_unseen_pressure(tmp_path, contact):
    # with the table: a factor at which the tip presses on it (at 0.6 it barely touches it)
    factor = CONTACT if contact else UNSEEN
    unseen = finger(contact=contact)
    unseen["steps"][-1]["loads"]["chamber"] = factor
    probes = run_scene(parse_scene(unseen), comm=MPI.COMM_WORLD).steps[-1].probes
    target = ({"contact_force:table[2]": probes["contact_force:table"][2]} if contact else
              {"displacement:tip[2]": probes["displacement:tip"][2]})
    out = Path(MPI.COMM_WORLD.bcast(str(tmp_path)))  # one directory on every rank
    result = control_servos(parse_scene(finger(contact=contact)), target, unknowns={"chamber": (0.0, 2.0)},
                            out_dir=out)
    assert result.reached and result.initial == {"chamber": 0.25}
    assert result.unknowns["chamber"] == pytest.approx(factor, abs=1e-6)
    written = json.loads((out / "control.json").read_text())
    assert written["unknowns"] == result.unknowns and written["bounds"] == {"chamber": [0.0, 2.0]}


def to_toml(data, path=""):
    """A scene dict as TOML (tables, arrays of tables, and JSON-compatible values, which TOML reads alike)."""
    simple = {k: v for k, v in data.items() if not isinstance(v, dict) and not _tables(v)}
    lines = [f"{json.dumps(k)} = {_value(v)}" for k, v in simple.items()]
    for key, value in data.items():
        name = f"{path}.{json.dumps(key)}" if path else json.dumps(key)
        if isinstance(value, dict):
            lines += [f"[{name}]", to_toml(value, name)]
        elif _tables(value):
            for item in value:
                lines += [f"[[{name}]]", to_toml(item, name)]
    return "\n".join(lines)


def _tables(value):
    return isinstance(value, list) and value and all(isinstance(v, dict) for v in value)


def _value(value):
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    return json.dumps(value)


def test_an_unreachable_target_gives_the_closest_state_at_the_bound(tmp_path):
    from fenicsfoam.cli import main
    scene = tmp_path / "finger.toml"
    scene.write_text(to_toml(finger()))
    # the tip cannot rise 5 cm with a chamber factor within [0, 1]: the closest state is at the upper bound
    status = main(["control", str(scene), "--unknown", "chamber=0:1", "--target", "displacement:tip[2]=-0.05",
                   "--out", str(tmp_path / "far")])
    assert status == 3
    written = json.loads((tmp_path / "far" / "control.json").read_text())
    assert written["reached"] is False and written["unknowns"]["chamber"] == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("unknowns, targets, message", [
    ({"pump": (0, 1)}, {"displacement:tip[2]": 0.0}, "unknown 'pump' is not a servo or a named actuating load"),
    ({"chamber": None}, {"displacement:tip[2]": 0.0}, "give the bounds of its factor"),
    ({"chamber": (1, 0)}, {"displacement:tip[2]": 0.0}, "must be finite with lo < hi"),
    ({"servo0": None}, {"displacement:tip[2]": 0.0}, "not a servo or a named actuating load"),
    ({"chamber": (0, 1)}, {"displacement:tip[3]": 0.0}, "unknown target 'displacement:tip[3]'"),
    ({"chamber": (0, 1)}, {"displacement:nowhere[2]": 0.0}, "unknown facet group 'nowhere'"),
    ({"chamber": (0, 1)}, {"contact_force:table[2]": 1.0}, "no contact named 'table'"),
    ({"chamber": (0, 1)}, {"center_height": 0.0}, "needs the tripod builder"),
    ({"chamber": (0, 1)}, {"displacement:tip[2]": 0.0, "displacement:tip[0]": 0.0}, "2 targets for 1 unknowns"),
    ({"chamber": (0.5, 1)}, {"displacement:tip[2]": 0.0}, "initial values {'chamber': 0.25}"),
])
def test_bad_unknowns_and_targets_are_refused_before_any_work(unknowns, targets, message, monkeypatch):
    import fenicsfoam.design
    monkeypatch.setattr(fenicsfoam.design.SceneDesign, "__init__", lambda *a, **k: pytest.fail("built a model"))
    with pytest.raises(InputError, match=message.replace("[", r"\[").replace("(", r"\(").replace("{", r"\{")):
        control_servos(parse_scene(finger()), targets, unknowns=unknowns)


def test_a_cable_factor_cannot_be_bounded_below_zero():
    with pytest.raises(InputError, match="a cable's factor must stay >= 0"):
        InverseController(parse_scene(finger("finger_cable")), unknowns={"tendon": (-1.0, 1.0)})


def test_motion_gradients_with_cables_are_refused():
    # a cable's tangent on prescribed nodes is left out of the solver's matrix: a motion gradient would be inexact
    data = copy.deepcopy(finger("finger_cable"))
    data["loads"]["motion"] = {"lift": {"group": "base"}}
    data["loads"].pop("clamp")
    data["steps"][-1]["motions"] = {"lift": {"translation": [0.0, 0.0, 0.001]}}
    design = SceneDesign(parse_scene(data))
    design.solve()
    design.adjoint.factor()
    design.add_probe("displacement:tip[2]")
    with pytest.raises(InputError, match="motion gradients do not cover cable loads"):
        design.adjoint.gradient(design.probes["displacement:tip[2]"], motions=["lift"])
