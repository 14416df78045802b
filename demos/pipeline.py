"""The main job of `make demo`: foam → homogenized table → Tripod case B, on the shipped defaults.

1. Foam: one stochastic Voronoi foam of the Tripod's material (15 %, γ = 0.1) is generated and homogenized by
   the FFT solver at the shipped table's settings — the same computation each sample of the table is.
2. Table: ``foam_material`` interpolates the shipped, seed-averaged table at (15 %, γ = 0.1) into the TI
   constants of the plate (TPU: E_s = 12 MPa, ν_s = 0.3); the single foam above is compared with it (their
   difference is the seed scatter of one RVE).
3. Robot: ``demos/scenes/tripod_case_b.toml`` (whole plate TI 15 % foam, spiral l field) through
   ``fenicsfoam.scene.run_scene``: rest, middle (+19°) and top (+38°) servo positions; the centre's height and
   rotation as changes from rest, beside the paper's Table I.

Outputs under ``--out``: ``tripod_case_b/`` (summary.json, probes.csv,
solution.xdmf, pictures) and ``pipeline.json``. ``--ci`` runs a smaller foam and a coarser plate.
"""

import argparse
import json
import sys
import tomllib
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenicsfoam.materials import foam_material
from fenicsfoam.scene import run_scene
from homogenization import tables

SCENE = Path(__file__).resolve().parent / "scenes" / "tripod_case_b.toml"
#: Paper Table I, case B: (simulated, real) at rest, middle, top.
TABLE_I_B = {"center_height": ((68.67, 80.73, 87.0), (73.5, 85.8, 94.0)),
             "center_rotation": ((-9.31, 8.15, 27.21), (0.0, 5.53, 22.1))}


def homogenize_one_foam(density: float, gamma: float, settings: tables.SweepSettings, comm) -> dict | None:
    """Stage 1: one foam sample, exactly as the table's sweep computes it (rank 0)."""
    if comm.rank != 0:
        return None
    return tables.homogenize_sample(tables.Sample(density, gamma, seed=0), settings)


def main(out: Path, ci: bool) -> int:
    comm = MPI.COMM_WORLD
    out.mkdir(parents=True, exist_ok=True)
    scene = tomllib.loads(SCENE.read_text())
    region = scene["regions"]["plate"]
    density, gamma = region["density"], region["gamma"]
    settings = tables.SweepSettings(n_cells=6, resolution=24, tol=1e-3) if ci else tables.SweepSettings()
    failures = []

    # 1–2. foam → homogenized constants, against the shipped table
    sample = homogenize_one_foam(density, gamma, settings, comm)
    material = foam_material(density, gamma, region["E_solid"], region["nu_solid"], rho_solid=region["rho_solid"],
                             fit=region["fit"])
    if comm.rank == 0:
        t = {k: v for k, v in zip(*_table_row(density, gamma), strict=True)}
        print(f"foam {density:.0%}, gamma = {gamma}: one RVE (n_cells = {settings.n_cells}, N = "
              f"{settings.resolution}, {sample['wall_s']:.1f} s) vs the shipped table (mean ± std over seeds)")
        print(f"{'':8s} {'one RVE':>10s} {'table':>10s} {'± std':>9s}   (normalised by E_s)")
        for name in ("E1", "E2", "E3", "G23", "G12"):
            print(f"{name:8s} {sample[name]:10.3e} {t[name]:10.3e} {t[name + '_std']:9.1e}")
        print(f"plate material (fit = {region['fit']}): " + ", ".join(
            f"{k} = {v / 1e3:.1f} kPa" if k.startswith(("E", "G")) else f"{k} = {v:.3f}"
            for k, v in material.constants.items()) + f", rho = {material.rho:.1f} kg/m³")
        if not sample["E1"] < min(sample["E2"], sample["E3"]):
            failures.append("the gamma = 0.1 foam is not softest along its x axis")

    # 3. Tripod case B
    if ci:
        scene["geometry"]["h"] = 0.006
        scene["outputs"] = {"png": [scene["steps"][-1]["label"]]}
    result = run_scene(scene, out / "tripod_case_b", comm=comm)
    height = {k: 1e3 * v for k, v in result.probe("center_height").items()}
    angle = result.probe("center_rotation")
    if comm.rank == 0:
        print(result.table())
        print(f"\nTripod case B, change from rest ({result.n_cells} tets; paper: simulated / real robot)")
        print(f"{'':8s} {'Δheight (mm)':>13s} {'paper':>7s} {'real':>7s} | {'Δangle (deg)':>13s} {'paper':>7s} "
              f"{'real':>7s}")
        for i, label in enumerate(("middle", "top"), start=1):
            ps, pr = (TABLE_I_B["center_height"][k][i] - TABLE_I_B["center_height"][k][0] for k in (0, 1))
            qs, qr = (TABLE_I_B["center_rotation"][k][i] - TABLE_I_B["center_rotation"][k][0] for k in (0, 1))
            print(f"{label:8s} {height[label] - height['rest']:13.2f} {ps:7.2f} {pr:7.2f} | "
                  f"{angle[label] - angle['rest']:13.2f} {qs:7.2f} {qr:7.2f}")
        if not height["rest"] < height["middle"] < height["top"]:
            failures.append(f"the centre does not rise from rest to middle to top: {height} mm")
        if not abs(angle["top"] - angle["rest"]) > 1.0:
            failures.append(f"the spiral plate does not twist: {angle} deg")
        record = {"foam_sample": sample, "plate_material": material.constants | {"rho": material.rho},
                  "tripod_case_b": result.summary()["steps"], "failures": failures}
        _write_json(out / "pipeline.json", record)
        for f in failures:
            print(f"CHECK FAILED: {f}", file=sys.stderr)
    return 1 if comm.bcast(failures) else 0


def _table_row(density: float, gamma: float):
    t = tables.read_csv(tables.TABLE_CSV)
    rows = np.flatnonzero(np.isclose(t["density"], density) & np.isclose(t["gamma"], gamma))
    if len(rows) != 1:
        raise SystemExit(f"(density, gamma) = ({density}, {gamma}) is not a node of {tables.TABLE_CSV}")
    return list(t), [t[k][rows[0]] for k in t]


def _write_json(path: Path, data: dict) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=2, default=float))
    tmp.replace(path)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out"))
    parser.add_argument("--ci", action="store_true", help="smaller foam and coarser plate for the test suite")
    a = parser.parse_args()
    sys.exit(main(a.out, a.ci))
