"""The default foam table (the paper's foam, ``homogenization.tables.DEFAULT_TABLE``): the table pipeline's oracles
on it, its interpolation (exact at the nodes, monotone where the data are), its range errors, and every shipped
scene reading it."""

import tomllib
from pathlib import Path

import numpy as np
import pytest

from fenicsfoam.material.table import FoamTable, foam_table
from fenicsfoam.materials import TransverseIsotropic, foam_material
from homogenization import tables
from homogenization.tensors import isotropic_voigt

SCENES = Path(__file__).resolve().parents[1] / "demos" / "scenes"
E_TPU = 12e6
MODULI = ("ti_E_t", "ti_E_l", "ti_G_l", "iso_E", "E1", "E2", "E3", "G23", "G13", "G12")
RATIOS = ("ti_nu_t", "ti_nu_tl", "iso_nu")


@pytest.fixture(scope="module")
def table():
    return tables.read_csv(tables.table_paths(tables.DEFAULT_TABLE)["table"])


@pytest.fixture(scope="module")
def samples():
    return tables.read_csv(tables.table_paths(tables.DEFAULT_TABLE)["samples"])


def test_the_default_is_the_papers_foam_over_the_whole_grid(table, samples):
    """Densities 0.09–0.35 × γ 0.1–1, every node a full set of seeds, every sample at its density, the rows the
    polyhedral wall foam with pores of 0.0045 E_s: the hex8 side of the rotated … hex8 bracket at γ 0.3, the
    midpoint elsewhere (γ 0.2 on a grid 1.5× finer), with the bracket's widths everywhere; the rows at γ 0.1,
    0.5 and 1 are the samples of the all-midpoint table."""
    assert tables.DEFAULT_TABLE in tables.shipped_tables() and tables.DEFAULT_TABLE in tables.TABLE_NOTES
    assert set(tables.shipped_tables()) <= set(tables.TABLE_NOTES)
    densities = (0.09, 0.12, 0.15, 0.18, 0.22, 0.26, 0.30, 0.35)
    gammas = (0.1, 0.2, 0.3, 0.5, 1.0)
    assert set(zip(table["density"], table["gamma"], strict=True)) == {(d, g) for d in densities for g in gammas}
    assert np.all(table["n_seeds"] == 3) and len(samples["density"]) == 3 * len(densities) * len(gammas)
    assert np.all(np.abs(samples["measured_density"] - samples["density"]) < 0.002)
    assert set(samples["distance"]) == {"polyhedral"} and set(samples["box"]) == {"equiaxed"}
    hex8 = samples["gamma"] == 0.3
    assert set(samples["discretization"][hex8]) == {"hex8"} and set(samples["discretization"][~hex8]) == {"bracket"}
    assert set(samples["pore_modulus"]) == {0.0045} and np.all(samples["bracket_G12"] > 0)
    finer = samples["gamma"] == 0.2
    assert set(samples["resolution"][finer & (samples["density"] == 0.18)]) == {"90x150x150"}
    midpoint = tables.read_csv(tables.table_paths("equiaxed_polyhedral_bracket_pores0p0045")["samples"])
    same = ~np.isin(midpoint["gamma"], (0.2, 0.3))
    for name in tables.C_ENTRIES + ("bracket_E2",):
        np.testing.assert_array_equal(samples[name][~hex8 & ~finer], midpoint[name][same])
    # on the same voxels as the midpoint table (γ = 0.3) the hex8 side lies above the midpoint; on the finer grid
    # (γ = 0.2) the bracket is narrower than on the midpoint table's
    assert np.all(samples["E2"][hex8] > midpoint["E2"][midpoint["gamma"] == 0.3])
    assert np.all(samples["bracket_E2"][finer] < midpoint["bracket_E2"][midpoint["gamma"] == 0.2])
    assert foam_table(None).path == str(tables.table_paths(tables.DEFAULT_TABLE)["table"])


def test_every_sample_is_an_admissible_stiffness_below_the_voigt_bound(samples):
    """C symmetric positive definite and below the two phases' Voigt bound (ρ C_s + (1 − ρ) C_pore); that its ti_*
    columns are the fit of C is checked with every shipped table's (test_tables.py)."""
    for i in range(len(samples["density"])):
        C = tables.row_stiffness({k: samples[k][i] for k in tables.C_ENTRIES})
        rho, e = samples["density"][i], samples["pore_modulus"][i]
        voigt = (rho + (1 - rho) * e) * isotropic_voigt(1.0, tables.NU_SOLID)
        assert np.linalg.eigvalsh(C).min() > 0 and np.linalg.eigvalsh(voigt - C).min() > 0, i


def test_interpolation_is_exact_at_every_node(table):
    for i in range(len(table["density"])):
        d, g = float(table["density"][i]), float(table["gamma"][i])
        m = foam_material(d, g, E_TPU, 0.3, rho_solid=1190.0)
        assert isinstance(m, TransverseIsotropic)
        np.testing.assert_allclose([m.E_t, m.E_l, m.G_l, m.nu_t, m.nu_tl, m.rho],
                                   [E_TPU * table["ti_E_t"][i], E_TPU * table["ti_E_l"][i],
                                    E_TPU * table["ti_G_l"][i], table["ti_nu_t"][i], table["ti_nu_tl"][i],
                                    1190.0 * d], rtol=1e-12)
        iso = foam_material(d, g, E_TPU, 0.3, fit="isotropic")
        np.testing.assert_allclose([iso.E, iso.nu], [E_TPU * table["iso_E"][i], table["iso_nu"][i]], rtol=1e-12)


def test_interpolation_is_monotone_where_the_data_are(table):
    """Between two neighbouring nodes (in density at a tabulated γ, in γ at a tabulated density) every column
    stays within its two node values (PCHIP: no overshoot), on 25 points per interval."""
    interp = FoamTable(tables.table_paths(tables.DEFAULT_TABLE)["table"])
    gammas, densities = np.unique(table["gamma"]), np.unique(table["density"])

    def node(name, d, g):
        (i,) = np.flatnonzero((table["density"] == d) & (table["gamma"] == g))
        return table[name][i]

    checked = 0
    for name in MODULI + RATIOS:
        for g in gammas:
            for a, b in zip(densities[:-1], densities[1:], strict=True):
                x = np.linspace(a, b, 25)
                v = interp.column(name, x, np.full_like(x, g)).value
                lo, hi = sorted((node(name, a, g), node(name, b, g)))
                assert np.all(v >= lo * (1 - 1e-12)) and np.all(v <= hi * (1 + 1e-12)), (name, g, a, b)
                checked += 1
        for d in densities:
            for a, b in zip(gammas[:-1], gammas[1:], strict=True):
                y = np.geomspace(a, b, 25)
                v = interp.column(name, np.full_like(y, d), y).value
                lo, hi = sorted((node(name, d, a), node(name, d, b)))
                assert np.all(v >= lo * (1 - 1e-12)) and np.all(v <= hi * (1 + 1e-12)), (name, d, a, b)
                checked += 1
    assert checked == len(MODULI + RATIOS) * (gammas.size * (densities.size - 1) + densities.size * (gammas.size - 1))


def test_moduli_grow_with_density_and_the_foam_is_soft_along_l_below_gamma_one(table):
    for g in np.unique(table["gamma"]):
        rows = np.flatnonzero(table["gamma"] == g)
        rows = rows[np.argsort(table["density"][rows])]
        for name in ("ti_E_t", "ti_E_l", "ti_G_l", "iso_E"):
            assert np.all(np.diff(table[name][rows]) > 0), (name, g)
    for d in np.unique(table["density"]):
        m = foam_material(float(d), 0.1, E_TPU, 0.3)
        assert m.E_t / m.E_l > 5 and m.E_t / m.G_l > 10


@pytest.mark.parametrize(("density", "gamma", "match"), [
    (0.05, 0.1, r"density = 0.05 is outside the tabulated range \[0.09, 0.35\] of the foam table "
                r"'paper_foam'"),
    (0.4, 0.5, r"density = 0.4 is outside the tabulated range \[0.09, 0.35\]"),
    (0.2, 0.05, r"gamma = 0.05 is outside the tabulated range \[0.1, 1\] of the foam table "
                r"'paper_foam'"),
])
def test_a_density_or_gamma_outside_the_grid_is_named_with_the_range(density, gamma, match):
    with pytest.raises(ValueError, match=match):
        foam_material(density, gamma, E_TPU, 0.3)


def test_every_shipped_scene_reads_the_default_table():
    """No shipped scene names a foam table: each foam region reads the default (and so does every graded field)."""
    foams = 0
    for path in sorted(SCENES.glob("*.toml")):
        scene = tomllib.loads(path.read_text())
        for name, region in scene.get("regions", {}).items():
            if region.get("material") == "foam":
                assert "table" not in region, (path.name, name)
                assert tables.resolve_table(region.get("table"))[0] == tables.DEFAULT_TABLE
                foams += 1
    assert foams >= 10  # the beams, the Tripods, the fingers
