"""The ``homogenize`` command line: image and foam inputs, JSON content, argument errors (exit code 2)."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from homogenization.cli import HOMOGENIZE_DISCRETIZATION, main
from homogenization.fft import homogenize_fft
from homogenization.tensors import closest_transverse_isotropic, isotropic_voigt


def porous_image(n=8):
    """A solid with a spherical pore and a cylindrical channel along x: transversely isotropic about x."""
    x = (np.arange(n) + 0.5) / n - 0.5
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return ~((X**2 + Y**2 + Z**2 < 0.3**2) | (Y**2 + Z**2 < 0.15**2))


@pytest.fixture
def image_file(tmp_path):
    path = tmp_path / "phases.npy"
    np.save(path, porous_image())
    return path


def test_image_to_json(image_file, tmp_path, capsys):
    out = tmp_path / "result.json"
    assert main(["--image", str(image_file), "--E-solid", "2", "--nu-solid", "0.25", "--tol", "1e-8",
                 "--threads", "1", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    C = np.array(data["C"])
    materials = [np.zeros((6, 6)), isotropic_voigt(2.0, 0.25)]
    library = homogenize_fft(porous_image().astype(np.int8), materials, tol=1e-8, threads=1,
                             discretization=HOMOGENIZE_DISCRETIZATION)
    expected = library.C
    assert np.allclose(C, expected, rtol=1e-12, atol=1e-14)
    ti = closest_transverse_isotropic(expected, axis=0)
    assert data["ti_fit"]["axis"] == [1.0, 0.0, 0.0]
    assert data["ti_fit"]["E_l"] == pytest.approx(ti.E_l, rel=1e-10)
    assert data["ti_fit"]["error"] == pytest.approx(ti.error, rel=1e-6, abs=1e-12)
    assert data["engineering_constants"]["E1"] > data["engineering_constants"]["E2"]  # channel along x
    assert data["inputs"]["E_solid"] == 2.0 and data["inputs"]["image"] == str(image_file)
    # the command's default voxels, fully integrated (the library's default stays rotated), solved by pcg
    assert HOMOGENIZE_DISCRETIZATION == "hex8" and data["inputs"]["discretization"] == "hex8"
    assert data["info"]["scheme"] == library.info["scheme"] == "pcg" and data["info"]["discretization"] == "hex8"
    assert len(data["iterations"]) == 6 and data["converged"] is True
    assert data["software"]["fenicsfoam"] and data["solid_fraction"] == pytest.approx(porous_image().mean())
    assert "isotropic_fit" in data and data["info"]["time_per_iteration_s"] > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["phases.npy", "result.json"]  # no temporary file left
    assert "TI fit (l = x)" in capsys.readouterr().out


@pytest.mark.parametrize("E_solid", ["1e200", "1e-170", "1.3e308", "2e-308"])
def test_extreme_moduli_give_the_normalised_constants(image_file, tmp_path, E_solid):
    """--E-solid in any unit the doubles hold: C / E_solid equals the run at E_solid = 1 (a solver that formed
    squared norms of 1e200 stopped at iteration 0 and returned the Voigt bound, E1/E 0.197 instead of 0.029)."""
    runs = {}
    for E in ("1", E_solid):
        out = tmp_path / f"{E}.json"
        assert main(["--image", str(image_file), "--E-solid", E, "--threads", "1", "--out", str(out)]) == 0
        runs[E] = json.loads(out.read_text())
    C1, C = np.array(runs["1"]["C"]), np.array(runs[E_solid]["C"]) / float(E_solid)
    assert runs[E_solid]["iterations"] == runs["1"]["iterations"] and min(runs["1"]["iterations"]) > 5
    assert np.abs(C - C1).max() < 1e-12 * np.abs(C1).max()
    e, e1 = runs[E_solid]["engineering_constants"], runs["1"]["engineering_constants"]
    assert e["E1"] / float(E_solid) == pytest.approx(e1["E1"], rel=1e-12) and e["nu12"] == pytest.approx(e1["nu12"])


def test_solid_image_gives_the_solids_closed_form_stiffness(tmp_path):
    """An all-solid image: C is the isotropic stiffness of --E-solid, --nu-solid (λ = Eν/((1+ν)(1−2ν)),
    μ = E/(2(1+ν)), written out here), and the isotropic fit is exact."""
    np.save(tmp_path / "solid.npy", np.ones((6, 6, 6), dtype=bool))
    out = tmp_path / "solid.json"
    assert main(["--image", str(tmp_path / "solid.npy"), "--E-solid", "3", "--nu-solid", "0.2", "--threads", "1",
                 "--out", str(out)]) == 0
    E, nu = 3.0, 0.2
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    exact = np.diag([2 * mu] * 3 + [mu] * 3) + np.pad(np.full((3, 3), lam), ((0, 3), (0, 3)))
    data = json.loads(out.read_text())
    np.testing.assert_allclose(np.array(data["C"]), exact, rtol=1e-13, atol=1e-13 * E)
    assert data["isotropic_fit"]["E"] == pytest.approx(E, rel=1e-13)
    assert data["isotropic_fit"]["nu"] == pytest.approx(nu, rel=1e-13)


def run_error(argv, capsys):
    """Exit status 2: argparse's usage errors exit, the command's checks return it."""
    try:
        status = main(argv)
    except SystemExit as info:
        status = info.code
    assert status == 2
    return capsys.readouterr().err


@pytest.mark.parametrize("extra,match", [
    (["--tol", "-1"], "--tol must be in"),
    (["--nu-solid", "0.5"], "--nu-solid must be in"),
    (["--E-solid", "0"], "--E-solid must be > 0"),
    (["--threads", "0"], "--threads must be >= 1"),
    (["--maxiter", "0"], "--maxiter must be >= 1"),
    (["--scheme", "fancy"], "--scheme: invalid choice"),
    (["--density", "0.2"], "not allowed with argument"),
    (["--out", "/nonexistent-dir/r.json"], "--out .*does not exist"),
])
def test_bad_arguments_exit_2(image_file, capsys, extra, match):
    err = run_error(["--image", str(image_file), *extra], capsys)
    assert re.search(match, err), err


def test_bad_images_exit_2(tmp_path, capsys):
    assert "no such file" in run_error(["--image", str(tmp_path / "missing.npy")], capsys)
    np.save(tmp_path / "three.npy", np.full((4, 4, 4), 2, dtype=np.int8))
    assert "0/1 integer phases" in run_error(["--image", str(tmp_path / "three.npy")], capsys)
    np.save(tmp_path / "flat.npy", np.ones((4, 4), dtype=bool))
    assert "3-D array" in run_error(["--image", str(tmp_path / "flat.npy")], capsys)
    (tmp_path / "junk.npy").write_text("not an array")
    assert "cannot read" in run_error(["--image", str(tmp_path / "junk.npy")], capsys)


def test_foam_arguments_are_checked(capsys):
    assert "--gamma must be in (0, 1]" in run_error(["--density", "0.2", "--gamma", "1.5"], capsys)
    assert "--density must be in (0, 1)" in run_error(["--density", "1.2"], capsys)


def test_non_percolating_solid_fails_with_exit_1(tmp_path, capsys):
    image = np.zeros((6, 6, 6), dtype=bool)
    image[2:4, 2:4, 2:4] = True  # an isolated cube of solid: C_hom = 0
    np.save(tmp_path / "island.npy", image)
    assert main(["--image", str(tmp_path / "island.npy"), "--out", str(tmp_path / "r.json")]) == 1
    assert "not positive definite" in capsys.readouterr().err
    assert not (tmp_path / "r.json").exists()


def test_console_script(image_file, tmp_path):
    script = Path(sys.executable).parent / "homogenize"
    out = tmp_path / "r.json"
    ok = subprocess.run([str(script), "--image", str(image_file), "--out", str(out)], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    assert np.array(json.loads(out.read_text())["C"]).shape == (6, 6)
    bad = subprocess.run([str(script), "--image", str(image_file), "--tol", "2"], capture_output=True, text=True)
    assert bad.returncode == 2 and "--tol must be in (0, 1)" in bad.stderr


def test_foam_path(tmp_path):
    from meshes import foam as foam_module

    out = tmp_path / "foam.json"
    args = dict(density=0.3, gamma=0.5, cells=4, seed=2, resolution=16)
    assert main([f"--{k}={v}" for k, v in args.items()] + ["--out", str(out)]) == 0
    data = json.loads(out.read_text())
    image = foam_module.VoronoiFoam(n_cells=4, density=0.3, gamma=0.5, seed=2).voxelize(16)
    expected = homogenize_fft(image.astype(np.int8), [np.zeros((6, 6)), isotropic_voigt(1.0, 0.3)],
                              tol=1e-4, threads=1, discretization=HOMOGENIZE_DISCRETIZATION).C  # the command's defaults
    assert np.allclose(np.array(data["C"]), expected, rtol=1e-10, atol=1e-14)
    assert data["inputs"]["density"] == 0.3 and data["inputs"]["gamma"] == 0.5
    assert data["solid_fraction"] == pytest.approx(image.mean())


#: A tiny polyhedral wall foam in its equiaxed box (0.5, 1, 1): 8 × 16 × 16 voxels, walls about two voxels thick.
WALL_FOAM = dict(density=0.5, gamma=0.5, cells=4, seed=1, resolution=16)


def wall_foam_stiffness(tol: float) -> tuple[np.ndarray, np.ndarray]:
    """The library's C of :data:`WALL_FOAM` homogenized in its box, and its phase image."""
    from meshes.foam import VoronoiFoam

    foam = VoronoiFoam(WALL_FOAM["cells"], WALL_FOAM["density"], WALL_FOAM["gamma"], seed=WALL_FOAM["seed"],
                       box="equiaxed", distance="polyhedral")
    image = foam.voxelize(WALL_FOAM["resolution"]).astype(np.int8)
    C = homogenize_fft(image, [np.zeros((6, 6)), isotropic_voigt(1.0, 0.3)], tol=tol, threads=1,
                       box=tuple(foam.box), discretization=HOMOGENIZE_DISCRETIZATION).C
    return C, image


@pytest.mark.slow  # two wall-foam builds; the mpi case below runs the same path in the fast suite
def test_equiaxed_polyhedral_foam_path(tmp_path):
    """--box equiaxed --distance polyhedral homogenizes the wall foam in the box (γ, 1, 1) with cubic voxels: the
    JSON's C is the library's, the box and the foam are recorded."""
    out = tmp_path / "walls.json"
    assert main([f"--{k}={v}" for k, v in WALL_FOAM.items()]
                + ["--box", "equiaxed", "--distance", "polyhedral", "--tol", "1e-6", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    expected, image = wall_foam_stiffness(tol=1e-6)
    assert image.shape == (8, 16, 16)
    assert np.abs(np.array(data["C"]) - expected).max() < 1e-10 * np.abs(expected).max()
    assert data["info"]["box"] == [0.5, 1.0, 1.0]
    assert data["inputs"]["box"] == "equiaxed" and data["inputs"]["distance"] == "polyhedral"
    assert data["solid_fraction"] == pytest.approx(image.mean())


@pytest.mark.parametrize("extra,match", [
    (["--box", "long"], r"argument --box: invalid choice: 'long' \(choose from 'cube', 'equiaxed'\)"),
    (["--distance", "manhattan"], r"argument --distance: invalid choice: 'manhattan'"),
    (["--box", "equiaxed", "--gamma", "0.3", "--resolution", "16"],
     r"--resolution 16 with --gamma 0.3 gives 4.8"),
])
def test_bad_box_and_distance_exit_2(capsys, extra, match):
    err = run_error(["--density", "0.3", "--cells", "4", *extra], capsys)
    assert re.search(match, err), err


def test_box_and_distance_need_a_foam(image_file, capsys):
    err = run_error(["--image", str(image_file), "--distance", "polyhedral"], capsys)
    assert "--box cube --distance polyhedral describe a foam: they need --density" in err


@pytest.mark.mpi
def test_distributed_run_matches_serial(tmp_path):
    """Under mpirun -n K the one RVE is split over the ranks (foam voxelized on rank 0 and scattered, image
    memory-mapped); rank 0 writes the JSON; C equals the serial solve of the same image."""
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    folder = Path(comm.bcast(str(tmp_path)))  # one folder for all ranks
    image = porous_image(9)  # 9 planes: uneven slabs on 2 ranks
    if comm.Get_rank() == 0:
        np.save(folder / "img.npy", image)
    comm.Barrier()
    materials = [np.zeros((6, 6)), isotropic_voigt(1.0, 0.3)]
    out = folder / "image.json"
    assert main(["--image", str(folder / "img.npy"), "--tol", "1e-10", "--threads", "1", "--out", str(out)]) == 0
    comm.Barrier()
    data = json.loads(out.read_text())
    expected = homogenize_fft(image.astype(np.int8), materials, tol=1e-10, threads=1,
                              discretization=HOMOGENIZE_DISCRETIZATION).C
    assert np.abs(np.array(data["C"]) - expected).max() < 1e-10 * np.abs(expected).max()
    assert data["info"].get("ranks", 1) == comm.Get_size()
    assert data["solid_fraction"] == pytest.approx(image.mean())

    foam_module = pytest.importorskip("meshes.foam")
    out = folder / "foam.json"
    args = dict(density=0.3, gamma=0.5, cells=4, seed=2, resolution=16)
    assert main([f"--{k}={v}" for k, v in args.items()] + ["--threads", "1", "--out", str(out)]) == 0
    comm.Barrier()
    foam = foam_module.VoronoiFoam(n_cells=4, density=0.3, gamma=0.5, seed=2).voxelize(16)
    expected = homogenize_fft(foam.astype(np.int8), materials, tol=1e-4, threads=1,
                              discretization=HOMOGENIZE_DISCRETIZATION).C  # the command's defaults
    assert np.abs(np.array(json.loads(out.read_text())["C"]) - expected).max() < 1e-10 * np.abs(expected).max()


@pytest.mark.mpi
def test_distributed_bad_arguments_stop_every_rank(tmp_path):
    """Under mpirun the arguments and files are checked before any work and every rank returns exit status 2."""
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    if comm.Get_size() == 1:
        pytest.skip("needs mpirun -n 2 or more")
    folder = Path(comm.bcast(str(tmp_path)))
    foam = ["--density", "0.3", "--cells", "4", "--resolution", "16", "--threads", "1"]
    assert main([*foam, "--scheme", "cg"]) == 2  # distributed mode runs pcg only
    assert main(["--image", str(folder / "missing.npy")]) == 2  # checked on rank 0, known to all
    assert main([*foam, "--out", str(folder)]) == 2  # a directory where a file is expected
    assert main([*foam, "--density", "0.01", "--cells", "2", "--resolution", "8"]) == 1  # the solid does not
    #                                                      percolate: C is not positive definite, on every rank
    comm.Barrier()
    assert sorted(p.name for p in folder.iterdir() if not p.name.endswith(".json")) == []


@pytest.mark.mpi
def test_distributed_equiaxed_polyhedral_foam_matches_serial(tmp_path):
    """Under mpirun the wall foam of the equiaxed box is voxelized on rank 0, its box sent to every rank: C equals
    the serial solve of the same image in the same box."""
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    out = Path(comm.bcast(str(tmp_path))) / "walls.json"
    assert main([f"--{k}={v}" for k, v in WALL_FOAM.items()]
                + ["--box", "equiaxed", "--distance", "polyhedral", "--tol", "1e-6", "--out", str(out)]) == 0
    comm.Barrier()
    data = json.loads(out.read_text())
    assert data["info"]["box"] == [0.5, 1.0, 1.0] and data["info"].get("ranks", 1) == comm.Get_size()
    if comm.Get_rank() == 0:
        expected, _ = wall_foam_stiffness(tol=1e-6)
        assert np.abs(np.array(data["C"]) - expected).max() < 1e-8 * np.abs(expected).max()
