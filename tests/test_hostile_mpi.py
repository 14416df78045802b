"""Under ``mpirun -n 2`` a failure on one rank stops every rank with one message and the documented exit status.

Each case runs ``mpirun -n 2 fenicsfoam run`` (or a small script through :func:`foambase.cli.dispatch`) in a
subprocess with a timeout, so a deadlock fails the test instead of hanging the suite. The user's functions live in
a module written into the working directory; each misbehaves on rank 1 only (raises, calls ``sys.exit``, returns
values outside the foam table, cannot be imported). These tests spawn their own ``mpirun`` and are not marked
``mpi``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

BIN = Path(sys.executable).parent
REPO = Path(__file__).resolve().parents[1]
MPI_ENV = {"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
           "OMPI_MCA_btl_vader_single_copy_mechanism": "none", "OMPI_MCA_rmaps_base_oversubscribe": "1",
           "OPENBLAS_NUM_THREADS": "1"}
#: A deadlock shows as this timeout; a run that works takes about 10 s on two shared cores.
TIMEOUT = 120

USER = '''
import sys
import numpy as np
from mpi4py import MPI

RANK = MPI.COMM_WORLD.rank


def raises(x):
    if RANK == 1:
        raise ValueError("bad point on rank 1")
    return np.full(len(x), 0.2)


def exits(x):
    if RANK == 1:
        sys.exit(0)
    return np.full(len(x), 0.2)


def out_of_table(x):
    return np.full(len(x), 0.2 if RANK == 0 else 0.9)


def direction_raises(x):
    if RANK == 1:
        raise ValueError("no direction on rank 1")
    return np.tile([1.0, 0.0, 0.0], (len(x), 1))
'''
ONE_RANK_IMPORT = '''
from mpi4py import MPI
if MPI.COMM_WORLD.rank == 1:
    raise ImportError("not installed on this node")
import numpy as np


def density(x):
    return np.full(len(x), 0.2)
'''

HEAD = """name = "hostile"
probes = ["tip_deflection"]
[geometry]
builder = "beam"
h = 0.0075
[fem]
model = "linear"
"""
TAIL = """[loads]
gravity = [0.0, 0.0, -9.81]
clamp = "clamped"
[[steps]]
label = "g"
gravity = 1.0
[outputs]
png = false
"""


def graded(function: str) -> str:
    return HEAD + f"""[regions.beam]
tags = "beam"
material = "foam"
density = {{function = "{function}"}}
gamma = 1.0
E_solid = 1e6
nu_solid = 0.3
rho_solid = 1000.0
[orientation]
kind = "uniform"
direction = [1.0, 0.0, 0.0]
""" + TAIL


def oriented(function: str) -> str:
    return HEAD + f"""[regions.beam]
tags = "beam"
material = "transverse_isotropic"
E_t = 1e6
E_l = 2e6
nu_t = 0.3
nu_tl = 0.3
G_l = 3e5
rho = 1000.0
[orientation]
kind = "callable"
function = "{function}"
""" + TAIL


def fenicsfoam() -> list[str]:
    script = BIN / "fenicsfoam"
    return [str(script)] if script.exists() else [sys.executable, "-m", "fenicsfoam.cli"]


def mpirun(argv: list[str], cwd: Path) -> tuple[subprocess.CompletedProcess, float]:
    env = {**os.environ, **MPI_ENV, "PYTHONPATH": os.pathsep.join([str(cwd), str(REPO)])}
    start = time.monotonic()
    result = subprocess.run(["mpirun", "-n", "2", *argv], cwd=cwd, env=env, capture_output=True, text=True,
                            timeout=TIMEOUT)
    return result, time.monotonic() - start


@pytest.fixture
def work(tmp_path):
    (tmp_path / "user.py").write_text(USER)
    (tmp_path / "onerank.py").write_text(ONE_RANK_IMPORT)
    return tmp_path


@pytest.mark.parametrize("scene, code, message", [
    (graded("user:raises"), 2, "regions.beam.density: user:raises(x) raised ValueError: bad point on rank 1"),
    pytest.param(graded("user:exits"), 2, "regions.beam.density: user:exits(x) raised SystemExit: 0",
                 marks=pytest.mark.slow),
    pytest.param(graded("onerank:density"), 2, "regions.beam.density: cannot import 'onerank:density': "
                 "ImportError: not installed on this node", marks=pytest.mark.slow),
    pytest.param(oriented("user:direction_raises"), 2, "orientation.function: user:direction_raises(x) raised "
                 "ValueError", marks=pytest.mark.slow),
], ids=["density-raises", "density-sys-exit", "import-error", "orientation-raises"])
def test_a_user_function_failing_on_one_rank_stops_every_rank(work, scene, code, message):
    (work / "scene.toml").write_text(scene)
    result, _ = mpirun([*fenicsfoam(), "run", "scene.toml", "--out", "out"], work)
    assert result.returncode == code, result.stderr
    assert result.stderr.count(message) == 1 and "Traceback" not in result.stderr, result.stderr
    assert not (work / "out").exists()  # refused before the run folder is made


@pytest.mark.slow
def test_cells_out_of_the_table_on_one_rank_are_counted_on_all_ranks(work):
    """Rank 1's cells are outside the table: every rank stops, and the count is the total over both ranks."""
    (work / "scene.toml").write_text(graded("user:out_of_table"))
    result, _ = mpirun([*fenicsfoam(), "run", "scene.toml", "--out", "out"], work)
    assert result.returncode == 2, result.stderr
    counted = [line for line in result.stderr.splitlines() if "have density outside the tabulated range" in line]
    assert len(counted) == 1, result.stderr
    n_bad = int(counted[0].split("region 'beam': ")[1].split(" cell(s)")[0])
    # the same scene serially: every cell out of the table gives the beam's cell count
    (work / "all_out.py").write_text("import numpy as np\n\ndef f(x):\n    return np.full(len(x), 0.9)\n")
    (work / "all.toml").write_text(graded("all_out:f"))
    serial = subprocess.run([*fenicsfoam(), "run", "all.toml", "--out", "out"], cwd=work, capture_output=True,
                            text=True, timeout=TIMEOUT, env={**os.environ, "PYTHONPATH": f"{work}{os.pathsep}{REPO}"})
    assert serial.returncode == 2, serial.stderr
    n_all = int(serial.stderr.split("region 'beam': ")[1].split(" cell(s)")[0])
    assert 0 < n_bad < n_all  # rank 1's cells only, but all of them: neither 0 nor one rank's share of both


STUCK = '''
import sys
from foambase import cli
from foambase.errors import InputError


def run(args):
    from mpi4py import MPI
    comm = MPI.COMM_WORLD
    if comm.rank == 1:
        if args.kind == "input":
            raise InputError("--kind: rank 1 refuses its share")
        if args.kind == "bug":
            raise ZeroDivisionError("a bug on rank 1")
        sys.exit(0)
    comm.Barrier()  # rank 0 waits for rank 1 in a collective call
    return 0


COMMAND = cli.Command("stuck", "fails on rank 1 only", lambda p: p.add_argument("--kind"), run)
sys.exit(cli.main_single(COMMAND, "stuck"))
'''


@pytest.mark.parametrize("kind, code, message", [
    ("input", 2, "stuck: error on rank 1 only: --kind: rank 1 refuses its share"),
    pytest.param("bug", 1, "stuck: unexpected error on rank 1 only", marks=pytest.mark.slow),
    pytest.param("exit", 1, "stuck: error on rank 1 only: the command did not finish: sys.exit(0) was called",
                 marks=pytest.mark.slow),
])
def test_an_error_on_one_rank_anywhere_stops_the_job_with_its_exit_status(work, kind, code, message):
    """The command line's safety net: rank 0 waits in a barrier that rank 1 never reaches; the job ends anyway."""
    (work / "stuck.py").write_text(STUCK)
    result, seconds = mpirun([sys.executable, "stuck.py", "--kind", kind], work)
    assert result.returncode == code, result.stderr
    assert result.stderr.count(message) == 1, result.stderr
    assert seconds < 60
