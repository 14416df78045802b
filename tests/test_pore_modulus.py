"""Sweeps with pores of a small stiffness (SweepSettings.pore_modulus): their own table, cache and rows."""

import numpy as np
import pytest

from foambase.errors import InputError


def test_sweep_with_stiff_pores_is_the_fft_of_its_image_with_that_pore_phase_and_has_its_own_entries(tmp_path):
    from mpi4py import MPI

    from homogenization import tables
    from homogenization.fft import homogenize_fft
    from homogenization.tensors import isotropic_voigt
    from meshes.foam import VoronoiFoam

    sample = tables.Sample(0.3, 1.0, 1)
    rotated = {"discretization": "rotated"}  # the shipped tables' voxels, homogenize_fft's default (compared below)
    void = tables.SweepSettings(n_cells=3, resolution=12, tol=1e-6, **rotated)
    pores = tables.SweepSettings(n_cells=3, resolution=12, tol=1e-6, pore_modulus=0.01, **rotated)
    # void pores keep the historical names and cache keys; stiff pores get their own
    assert tables.cache_name(sample, void) == tables.cache_name(sample, tables.SweepSettings(
        n_cells=3, resolution=12, tol=1e-6, pore_modulus=0.0, **rotated))
    assert (void.name, pores.name) == ("cube", "cube_pores0p01")
    assert tables.cache_name(sample, void) != tables.cache_name(sample, pores)
    assert tables.SweepSettings(box="equiaxed", distance="polyhedral", pore_modulus=0.0045, **rotated).name == \
        "equiaxed_polyhedral_pores0p0045"
    assert tables.SweepSettings(box="equiaxed", distance="polyhedral", pore_modulus=0.0045).name == \
        "equiaxed_polyhedral_hex8_pores0p0045"  # the default voxels
    tables.table_paths("equiaxed_polyhedral_pores0p0045")  # a valid table name
    [b] = tables.run_sweep([sample], pores, tmp_path, MPI.COMM_SELF, progress=False, threads=1)
    assert b["pore_modulus"] == 0.01
    # the row is the FFT of the foam's image with the pore phase (an independent call), stiffer than with void
    img = VoronoiFoam(3, 0.3, 1.0, seed=1).voxelize(12).astype(np.int8)
    C = homogenize_fft(img, [isotropic_voigt(0.01, 0.3), isotropic_voigt(1.0, 0.3)], tol=1e-6, threads=1).C
    assert b["C11"] == pytest.approx(C[0, 0], rel=1e-12) and b["C44"] == pytest.approx(C[3, 3], rel=1e-12)
    C0 = homogenize_fft(img, [np.zeros((6, 6)), isotropic_voigt(1.0, 0.3)], tol=1e-6, threads=1).C
    assert b["C11"] > C0[0, 0] and b["C44"] > C0[3, 3]
    [again] = tables.run_sweep([sample], pores, tmp_path, MPI.COMM_SELF, progress=False, threads=1)
    assert again == b  # read back from the cache
    assert tables.settings_from_row(b) == pores and tables.settings_dict(pores)["pore_modulus"] == 0.01


@pytest.mark.parametrize("bad", [-0.01, 0.7, 1e-9, True, "0.01", float("nan")])
def test_a_bad_pore_modulus_is_refused_naming_it(bad):
    from homogenization import tables

    with pytest.raises(InputError, match="pore_modulus must be 0") as err:
        tables.SweepSettings(pore_modulus=bad)
    assert repr(bad) in str(err.value)
