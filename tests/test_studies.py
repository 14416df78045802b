"""The Tripod studies run end to end: the sweeps' mirror-symmetric end points (l along or across the arms,
spiral of circles or radial) do not twist, to round-off; outputs are written."""

import csv
import subprocess
import sys
from pathlib import Path

import pytest

STUDIES = Path(__file__).resolve().parents[1] / "studies"


def test_tripod_sweeps_end_points_are_mirror_symmetric(tmp_path):
    out = tmp_path / "sweeps"
    result = subprocess.run([sys.executable, str(STUDIES / "tripod_sweeps.py"), "--step", "90", "--out", str(out)],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    for design in ("case_a_offset", "case_b_pitch"):
        assert (out / f"{design}.png").stat().st_size > 0
        with open(out / f"{design}.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        assert [float(r["value_deg"]) for r in rows] == [0.0, 90.0]
        for r in rows:
            assert r["status"] == "ok"
            assert abs(float(r["da_top_deg"])) < 1e-9, r
            assert float(r["dh_top_mm"]) > float(r["dh_middle_mm"]) > 0


@pytest.mark.slow
def test_tripod_twist_quick_study_runs(tmp_path):
    result = subprocess.run([sys.executable, str(STUDIES / "tripod_twist.py"), "--quick", "--out", str(tmp_path)],
                            capture_output=True, text=True, timeout=1800)
    assert result.returncode == 0, result.stderr[-3000:]
    with open(tmp_path / "tripod_twist.csv", newline="") as f:
        rows = {(r["group"], r["label"], r["kinematics"]): r for r in csv.DictReader(f)}
    plus = rows[("layout", "l +30° from the arm", "flat")]
    minus = rows[("layout", "l -30° from the arm", "flat")]
    assert float(plus["da_top"]) == pytest.approx(-float(minus["da_top"]), abs=1e-9 * abs(float(plus["da_top"])))
    assert abs(float(rows[("layout", "l +0° from the arm", "as_built")]["da_top"])) < 1e-9
