"""Uncertainty from the foam table's seed scatter: zero for samples without scatter, equal to a closed form on a
linear beam (tip = c / E for gravity alone), growing with the scatter; summary.json carries probes_std.

Synthetic samples tables are made from the shipped one by moving each seed's row about the shipped mean table.
"""

import csv
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from fenicsfoam.uncertainty import run_with_uncertainty, seed_tables
from homogenization.tables import AGGREGATED, SAMPLES_CSV, TABLE_CSV, read_csv

SCENES = Path(__file__).resolve().parents[1] / "demos" / "scenes"
COARSE_BEAM_H = 0.0075  # 688 tets
#: relative deviation of seeds 0, 1, 2 from the mean in the synthetic tables (times the scatter factor k)
DEVIATION = {0: -0.1, 1: 0.02, 2: 0.08}


def beam(model="linear", half_step=False):
    scene = tomllib.loads((SCENES / "beam_iso.toml").read_text())
    scene["regions"]["beam"]["table"] = "cube"  # the table whose samples the synthetic tables move
    scene["geometry"]["h"] = COARSE_BEAM_H
    scene["fem"]["model"] = model
    scene["outputs"] = {"xdmf": False, "png": False}
    if half_step:
        scene["steps"] = [{"label": "half", "gravity": 0.5}, *scene["steps"]]
    return scene


def synthetic_samples(path, k, only=None):
    """The shipped samples with every seed's row set to the shipped mean × (1 + k · DEVIATION[seed]).

    ``only``: move only these columns (the others are set to the mean exactly); k = 0 gives no scatter at all.
    """
    mean = read_csv(TABLE_CSV)
    with open(SAMPLES_CSV, newline="") as f:
        rows = list(csv.DictReader(f))
    for row in rows:
        node = (mean["density"] == float(row["density"])) & (mean["gamma"] == float(row["gamma"]))
        (i,) = np.flatnonzero(node)
        for name in AGGREGATED:
            factor = 1.0 + k * DEVIATION[int(row["seed"])] if only is None or name in only else 1.0
            row[name] = repr(float(mean[name][i]) * factor)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return path


def test_seed_tables_reproduce_each_seed(tmp_path):
    tables = seed_tables(SAMPLES_CSV, tmp_path)
    samples = read_csv(SAMPLES_CSV)
    assert sorted(tables) == sorted(set(samples["seed"].astype(int)))
    for seed, path in tables.items():
        table = read_csv(path)
        rows = samples["seed"] == seed
        assert len(table["density"]) == rows.sum()
        for d, g, e in zip(samples["density"][rows], samples["gamma"][rows], samples["ti_E_t"][rows]):
            (i,) = np.flatnonzero((table["density"] == d) & (table["gamma"] == g))
            assert table["ti_E_t"][i] == e


def test_zero_scatter_gives_zero_std(tmp_path):
    samples = synthetic_samples(tmp_path / "samples.csv", k=0.0)
    result = run_with_uncertainty(beam("corotational"), samples_csv=samples, comm=MPI.COMM_SELF)
    assert len(result.samples) == 3
    assert result.probes_std == [{"tip_deflection": 0.0}]


@pytest.mark.mpi
def test_std_equals_the_closed_form_and_grows_with_the_scatter(mpi_tmp_path):
    """Linear model, gravity only, seeds differing only in E: tip_s = tip · E_mean / E_s exactly."""
    comm = MPI.COMM_WORLD
    stds = []
    for k in (0.5, 1.0, 2.0):
        path = mpi_tmp_path / f"samples_{k}.csv"
        if comm.rank == 0:
            synthetic_samples(path, k, only={"iso_E"})
        comm.Barrier()
        result = run_with_uncertainty(beam("linear", half_step=True), samples_csv=path, comm=comm)
        tip = result.nominal.steps[1].probes["tip_deflection"]
        expected = np.std([tip / (1.0 + k * d) for d in DEVIATION.values()], ddof=1)
        assert result.probes_std[1]["tip_deflection"] == pytest.approx(expected, rel=1e-9)
        # half the load: half the deflection, so the change from "half" to "gravity" has half the σ
        assert result.probe_std("tip_deflection")["half"] == pytest.approx(expected / 2, rel=1e-9)
        change = result.probe_std("tip_deflection", relative_to="half")
        assert change["gravity"] == pytest.approx(expected / 2, rel=1e-9) and change["half"] == 0.0
        stds.append(result.probes_std[1]["tip_deflection"])
    assert 0 < stds[0] < stds[1] < stds[2]


def test_summary_json_has_probes_std_beside_probes(tmp_path):
    result = run_with_uncertainty(beam("linear"), tmp_path, comm=MPI.COMM_SELF)
    summary = json.loads((tmp_path / "summary.json").read_text())
    (step,) = summary["steps"]
    assert set(step["probes_std"]) == set(step["probes"]) == {"tip_deflection"}
    assert step["probes_std"]["tip_deflection"] == result.probes_std[0]["tip_deflection"] > 0
    assert summary["uncertainty"]["method"].startswith("per-seed tables")
    assert [s["seed"] for s in summary["uncertainty"]["samples"]] == [0, 1, 2]
    assert "±" in result.table()


def test_a_scene_without_foam_has_no_table_scatter():
    scene = beam()
    scene["regions"]["beam"] = {"tags": "beam", "material": "isotropic", "E": 3e5, "nu": 0.3, "rho": 200.0}
    result = run_with_uncertainty(scene, comm=MPI.COMM_SELF)
    assert result.probes_std == [{"tip_deflection": 0.0}] and result.samples == []


def test_a_seed_missing_a_table_node_is_refused(tmp_path):
    with open(SAMPLES_CSV, newline="") as f:
        rows = list(csv.DictReader(f))
    rows = [r for r in rows if not (r["seed"] == "2" and float(r["density"]) == 0.3 and float(r["gamma"]) == 0.1)]
    path = tmp_path / "samples.csv"
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    with pytest.raises(ValueError, match=r"seed 2 has no sample at \(density, gamma\) = \(0\.3, 0\.1\)"):
        seed_tables(path, tmp_path)


def test_a_seed_that_fails_counts_for_the_steps_it_completed(tmp_path, monkeypatch):
    """Seed 1 stops in the last step: 'half' has σ over the 3 seeds, 'gravity' over seeds 0 and 2."""
    import fenicsfoam.scene
    from fenicsfoam.solver import ConvergenceError

    real_run_scene = fenicsfoam.scene.run_scene
    calls = []

    def run_scene(scene, out_dir=None, *, comm=None):
        calls.append(scene.name)
        if len(calls) != 3:  # nominal, seed 0, seed 1 (fails), seed 2
            return real_run_scene(scene, out_dir, comm=comm)
        first = fenicsfoam.scene.parse_scene({**scene.raw, "steps": scene.raw["steps"][:1]})
        real_run_scene(first, out_dir, comm=comm)
        raise ConvergenceError("gravity", 0.5, "DIVERGED_MAX_IT", 3)

    monkeypatch.setattr(fenicsfoam.scene, "run_scene", run_scene)
    samples = synthetic_samples(tmp_path / "samples.csv", 1.0, only={"iso_E"})
    result = run_with_uncertainty(beam("linear", half_step=True), samples_csv=samples, comm=MPI.COMM_SELF)
    assert len(calls) == 4
    assert "error" in result.samples[1] and list(result.samples[1]["steps"]) == ["half"]
    tip = result.nominal.steps[1].probes["tip_deflection"]
    every = [tip / 2 / (1.0 + d) for d in DEVIATION.values()]
    assert result.probes_std[0]["tip_deflection"] == pytest.approx(np.std(every, ddof=1), rel=1e-9)
    two = [tip / (1.0 + DEVIATION[k]) for k in (0, 2)]
    assert result.probes_std[1]["tip_deflection"] == pytest.approx(np.std(two, ddof=1), rel=1e-9)


def test_vector_probes_get_a_std_per_component(tmp_path):
    """Linear beam under gravity, seeds differing only in E: the tip's mean displacement scales as 1/E_s in every
    component (σ per component = the closed form), and the clamp's reaction is the weight whatever E_s (σ = 0)."""
    scene = beam("linear", half_step=True)
    scene["probes"] = ["displacement:tip", "reaction_force:clamped", "tip_deflection"]
    samples = synthetic_samples(tmp_path / "samples.csv", 1.0, only={"iso_E"})
    result = run_with_uncertainty(scene, tmp_path / "out", samples_csv=samples, comm=MPI.COMM_SELF)
    weight = abs(result.nominal.steps[1].probes["reaction_force:clamped"][2])
    assert weight > 0
    for step, std in zip(result.nominal.steps, result.probes_std):
        u = step.probes["displacement:tip"]
        expected = [np.std([c / (1.0 + d) for d in DEVIATION.values()], ddof=1) for c in u]
        assert isinstance(std["displacement:tip"], list) and len(std["displacement:tip"]) == 3
        assert std["displacement:tip"] == pytest.approx(expected, rel=1e-9, abs=1e-9 * abs(u[2]))
        assert std["displacement:tip"][2] == pytest.approx(std["tip_deflection"], rel=1e-9)
        assert std["reaction_force:clamped"] == pytest.approx([0.0] * 3, abs=1e-9 * weight)
    change = result.probe_std("displacement:tip", relative_to="half")
    assert change["half"] == [0.0] * 3
    sigma = result.probes_std[1]["displacement:tip"]
    assert change["gravity"] == pytest.approx([s / 2 for s in sigma], rel=1e-9, abs=1e-9 * sigma[2])
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["steps"][1]["probes_std"]["displacement:tip"] == result.probes_std[1]["displacement:tip"]
    assert "displacement:tip = (" in result.table() and " N" in result.table()


# --------------------------------------------------------------------------------------------------
# fenicsfoam run --uncertainty
# --------------------------------------------------------------------------------------------------
def beam_file(directory):
    """The coarse linear beam, loaded at half and full gravity, as a scene file."""
    text = (SCENES / "beam_iso.toml").read_text()
    edited = text.replace("h = 0.0024", f"h = {COARSE_BEAM_H}").replace('model = "corotational"', 'model = "linear"')
    # the table whose samples the synthetic tables move
    edited = edited.replace('fit = "isotropic"', 'fit = "isotropic"\ntable = "cube"')
    assert edited.count('table = "cube"') == 1
    edited = edited.replace('[[steps]]\nlabel = "gravity"', '[[steps]]\nlabel = "half"\ngravity = 0.5\n\n'
                            '[[steps]]\nlabel = "gravity"')
    assert edited.count('label = "half"') == 1 and 'model = "linear"' in edited
    path = directory / "beam.toml"
    path.write_text(edited + '\n[outputs]\nxdmf = false\npng = false\n')
    return path


def test_cli_run_uncertainty_reports_value_and_std(tmp_path, capsys):
    """summary.json: probes_std beside probes in every step, the closed form of the synthetic scatter; printed ±."""
    from fenicsfoam.cli import main

    samples = synthetic_samples(tmp_path / "samples.csv", 1.0, only={"iso_E"})
    out = tmp_path / "out"
    assert main(["run", str(beam_file(tmp_path)), "--out", str(out), "--uncertainty", "--samples", str(samples)]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert [s["label"] for s in summary["steps"]] == ["half", "gravity"]
    for step in summary["steps"]:
        assert set(step["probes_std"]) == set(step["probes"]) == {"tip_deflection"}
        tip = step["probes"]["tip_deflection"]
        expected = np.std([tip / (1.0 + d) for d in DEVIATION.values()], ddof=1)
        assert step["probes_std"]["tip_deflection"] == pytest.approx(expected, rel=1e-9)
        assert f"± {1e3 * expected:.2g} mm" in printed
    assert summary["uncertainty"]["method"].startswith("per-seed tables")


def test_cli_run_uncertainty_zero_scatter_and_usage_errors(tmp_path, capsys):
    from fenicsfoam.cli import main

    scene = str(beam_file(tmp_path))
    samples = synthetic_samples(tmp_path / "samples.csv", 0.0)
    assert main(["run", scene, "--out", str(tmp_path / "zero"), "--uncertainty", "--samples", str(samples)]) == 0
    summary = json.loads((tmp_path / "zero" / "summary.json").read_text())
    assert [s["probes_std"] for s in summary["steps"]] == [{"tip_deflection": 0.0}] * 2
    for argv, message in ((["--samples", str(samples)], "--samples is used only with --uncertainty"),
                          (["--uncertainty", "--samples", str(tmp_path / "none.csv")], "none.csv' does not exist")):
        with pytest.raises(SystemExit) as info:
            main(["run", scene, "--out", str(tmp_path / "bad"), *argv])
        assert info.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_cli_run_uncertainty_under_mpirun_matches_serial(tmp_path):
    import os
    import subprocess
    import sys

    from fenicsfoam.cli import main

    scene = str(beam_file(tmp_path))
    samples = str(synthetic_samples(tmp_path / "samples.csv", 1.0))
    assert main(["run", scene, "--out", str(tmp_path / "serial"), "--uncertainty", "--samples", samples]) == 0
    env = {**os.environ, "OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
           "OMPI_MCA_btl_vader_single_copy_mechanism": "none", "OMPI_MCA_rmaps_base_oversubscribe": "1",
           "OPENBLAS_NUM_THREADS": "1"}
    result = subprocess.run(["mpirun", "-n", "2", sys.executable, "-m", "mpi4py", "-m", "fenicsfoam.cli", "run", scene,
                             "--out", str(tmp_path / "two"), "--uncertainty", "--samples", samples],
                            capture_output=True, text=True, env=env, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.count("probes ± standard deviation") == 1
    serial, two = (json.loads((tmp_path / d / "summary.json").read_text())["steps"] for d in ("serial", "two"))
    for a, b in zip(serial, two):
        assert b["probes_std"]["tip_deflection"] == pytest.approx(a["probes_std"]["tip_deflection"], rel=1e-7)
        assert b["probes"]["tip_deflection"] == pytest.approx(a["probes"]["tip_deflection"], rel=1e-9)
