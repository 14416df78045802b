"""Graded foam fields in scenes: zero-width blends and uniform fields reduce to the sharp scenes, per-tag fields equal
separate regions, blends lie between their regions, and bad field descriptions are refused naming their key."""

import copy
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fenicsfoam.scene import SceneError, parse_scene, run_scene

pytestmark = pytest.mark.mpi

SCENES = Path(__file__).resolve().parents[1] / "demos" / "scenes"


def case_a(h=0.01):
    data = tomllib.loads((SCENES / "tripod_case_a_flat.toml").read_text())
    data["geometry"]["h"] = h
    data["outputs"] = {"png": False, "xdmf": False}
    data["steps"] = data["steps"][:1] + [{"label": "top", "servo_deg": [38.0, 30.0, 20.0], "increments": 3}]
    return data


def probes(data):
    return run_scene(parse_scene(data)).steps[-1].probes


def uniform_density(points):
    return np.full(len(points), 0.30)


@pytest.fixture(scope="module")
def sharp():
    return probes(case_a())


def test_zero_width_blend_and_uniform_fields_reduce_to_the_sharp_scene(sharp):
    blended = case_a()
    blended["blends"] = [{"regions": ["arms", "centre"], "width": 0.0}]
    fields = case_a()
    fields["regions"]["arms"]["density"] = {"function": "tests.test_scene_graded:uniform_density"}
    fields["regions"]["centre"]["gamma"] = {"per_tag": {"centre": 1.0}}
    for data in (blended, fields):
        values = probes(data)
        for name, value in sharp.items():
            assert values[name] == pytest.approx(value, rel=1e-9, abs=1e-12), (name, values, sharp)


def test_per_tag_field_equals_separate_regions():
    graded = case_a()
    graded["regions"]["arms"]["density"] = {"per_tag": {"arm0": 0.30, "arm1": 0.22, "arm2": 0.26}}
    split = case_a()
    arms = split["regions"].pop("arms")
    for i, density in enumerate((0.30, 0.22, 0.26)):
        split["regions"][f"arm{i}"] = {**copy.deepcopy(arms), "tags": f"arm{i}", "density": density}
    a, b = probes(graded), probes(split)
    for name in a:
        assert a[name] == pytest.approx(b[name], rel=1e-9, abs=1e-12)
    assert abs(a["center_rotation"]) > 0.1  # unequal arms: the centre turns


def test_a_wide_blend_changes_the_result_between_its_regions(sharp):
    data = case_a()
    data["blends"] = [{"regions": ["arms", "centre"], "width": 0.008}]
    result = run_scene(parse_scene(data))
    arms, centre = result.materials["arms"], result.materials["centre"]
    assert arms["type"] == "graded TransverseIsotropic" and centre["type"] == "graded Isotropic"
    assert 0.15 < arms["density_range"][0] < 0.30 and arms["density_range"][1] == 0.30
    assert centre["density_range"][0] == 0.15 and 0.15 < centre["density_range"][1] < 0.30
    assert 0.1 < arms["gamma_range"][1] < 1.0 and 0.1 < centre["gamma_range"][0] < 1.0
    assert result.steps[-1].probes["center_height"] != pytest.approx(sharp["center_height"], rel=1e-4)


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(blends=[{"regions": ["arms", "nowhere"], "width": 0.004}]),
     r"^blends\[0\]\.regions: 'nowhere' is not a foam region"),
    (lambda d: d.update(blends=[{"regions": ["arms", "centre"], "width": -1.0}]), r"^blends\[0\]\.width: -1\.0"),
    (lambda d: d["regions"]["arms"].update(density={"per_tag": {"arm0": 0.3}}),
     r"^regions\.arms\.density\.per_tag: cell tags \[12, 13, 22, 23\] of the region have no value"),
    (lambda d: d["regions"]["arms"].update(density={"per_tag": {"arm0": 0.3, "arm1": 0.3, "arm2": 1.5}}),
     r"^regions\.arms\.density\.per_tag\.arm2: 1\.5 is out of range"),
    (lambda d: d["regions"]["arms"].update(density={"per_tag": {"centre": 0.3}}),
     r"^regions\.arms\.density\.per_tag\.centre: cell tag 1 is not a tag of this region"),
    (lambda d: d["regions"]["arms"].update(gamma={"function": "nocolon"}),
     r"^regions\.arms\.gamma\.function: expected 'module:function'"),
    (lambda d: d["regions"]["arms"].update(gamma={"table": 3}), r"^regions\.arms\.gamma: expected a number"),
    (lambda d: (d["regions"]["arms"].update(density={"per_tag": {"arms": 0.3}}),
                d.update(blends=[{"regions": ["arms", "centre"], "width": 0.004}])),
     r"^blends\[0\]\.regions: region 'arms' gives density as a field"),
])
def test_bad_fields_are_refused_before_any_work(change, message):
    data = case_a()
    change(data)
    with pytest.raises(SceneError, match=message):
        parse_scene(data)


def out_of_table(points):
    return np.full(len(points), 0.5)


def test_a_function_field_outside_the_table_is_refused_naming_the_region():
    data = case_a()
    data["regions"]["arms"]["density"] = {"function": "tests.test_scene_graded:out_of_table"}
    with pytest.raises(SceneError, match=r"region 'arms': \d+ cell\(s\) have density outside the tabulated range"):
        run_scene(parse_scene(data))


def test_graded_fields_and_designs_refuse_another_foam_table():
    # per-cell constants come from the default table: a region naming another one is refused before any mesh
    from fenicsfoam.design import SceneDesign
    from fenicsfoam.scene import SceneError

    data = case_a()
    data["blends"] = [{"regions": ["arms", "centre"], "width": 0.005}]
    data["regions"]["arms"].update(table="equiaxed", density=0.18)  # the equiaxed table holds 18 % only
    with pytest.raises(SceneError, match="regions.arms.table: graded foam fields read the default foam table"):
        run_scene(parse_scene(data))
    del data["blends"]
    with pytest.raises(SceneError, match="regions.arms.table: designs read the default foam table"):
        SceneDesign(parse_scene(data))
