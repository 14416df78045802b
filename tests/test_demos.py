"""Every demo and study runs at its fast ``--ci`` size, serially and under ``mpirun -n 2``, and passes its checks.

Scripts in ``demos/`` and ``studies/`` are discovered, not listed (as dolfinx's ``python/demo/test.py`` does), so
a new one is tested the day it lands; modules whose name starts with ``_`` are shared helpers, not scripts. Each
script takes ``--ci`` (a small, fast size) and ``--out DIR``, checks its own result and exits non-zero when a
check fails; this test only asserts the exit status, and shows the script's output when it fails.

The ``mpirun`` cases spawn their own ``mpirun``; they are not marked ``mpi`` (which would nest them inside the
``mpirun -n 2 pytest -m mpi`` run of ``make test``).
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DEMOS = sorted(p for folder in ("demos", "studies") for p in (ROOT / folder).glob("*.py") if not p.name.startswith("_"))
# --ci runs of more than about a minute (wall_foam: three polyhedral wall foams built and homogenized; tripod_as_built:
# two as-built Tripods, ≈ 30 s serial, a measurement study) run in
# `make test-all`; their library paths are tested in the fast suite (test_tables, test_rve_box, test_polyhedral_foam).
# gripper: a pressure sweep with contact and an inverse-actuation solve, ≈ 30 s serial --ci on the shared 2-core box.
SLOW = {("studies", "wall_foam"), ("studies", "tripod_as_built"), ("demos", "gripper")}
CASES = [pytest.param(p, marks=pytest.mark.slow) if (p.parent.name, p.stem) in SLOW else p for p in DEMOS]
TIMEOUT_S = 900


def _run(command: list[str], cwd: Path, **env_extra: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMPI_ALLOW_RUN_AS_ROOT": "1",
           "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1", "OMPI_MCA_rmaps_base_oversubscribe": "1", **env_extra}
    result = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert result.returncode == 0, (
        f"{' '.join(command)} exited with {result.returncode}\n--- stdout\n{result.stdout[-4000:]}"
        f"\n--- stderr\n{result.stderr[-4000:]}"
    )
    return result


def test_demos_and_studies_are_found():
    names = {(demo.parent.name, demo.name) for demo in DEMOS}
    assert {("demos", "pipeline.py"), ("studies", "speed_accuracy.py")} <= names


@pytest.mark.parametrize("demo", CASES, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_demo_serial(demo, tmp_path):
    _run([sys.executable, str(demo), "--ci", "--out", str(tmp_path / "out")], cwd=tmp_path)


def test_make_demo_is_quiet(tmp_path):
    """``make demo``'s pipeline with an empty FFCx cache (every form compiled afresh) prints no INFO line."""
    result = _run([sys.executable, str(ROOT / "demos" / "pipeline.py"), "--ci", "--out", str(tmp_path / "out")],
                  cwd=tmp_path, XDG_CACHE_HOME=str(tmp_path / "cache"))
    chatter = [line for line in (result.stdout + result.stderr).splitlines() if "INFO" in line]
    assert not chatter, f"{len(chatter)} INFO lines, e.g. {chatter[:3]}"
    assert "all checks passed" in result.stdout


@pytest.mark.parametrize("demo", CASES, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_demo_mpirun(demo, tmp_path):
    _run(["mpirun", "-n", "2", sys.executable, "-m", "mpi4py", str(demo), "--ci", "--out", str(tmp_path / "out")],
         cwd=tmp_path)
