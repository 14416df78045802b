"""The Fig. 4 comparison (studies/fig4.py): the paper's rows, their power laws, and a table read at their densities."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "studies"))
import fig4  # noqa: E402

from fenicsfoam.material.table import FoamTable  # noqa: E402
from homogenization.tables import to_csv  # noqa: E402


def test_paper_rows_are_the_published_three_densities_per_series():
    rows = fig4.paper_rows()
    assert [(r["series"], r["density"]) for r in rows] == [
        ("transverse", 0.0918), ("transverse", 0.2639), ("transverse", 0.3422),
        ("isotropic", 0.0901), ("isotropic", 0.2323), ("isotropic", 0.3297)]
    iso = rows[4]
    assert (iso["gamma"], iso["E_x"], iso["E_z"], iso["nu_zx"], iso["G_xy"]) == (1.0, 0.07927, 0.06311, 0.2250,
                                                                                  0.03006)
    # the compliance symmetry ν_ij/E_i = ν_ji/E_j makes the transverse foam's ν_xz = ν_zx E_x/E_z small
    tr = rows[0]
    assert tr["nu_zx"] * tr["E_x"] / tr["E_z"] == pytest.approx(0.0453, abs=1e-4)


def test_power_law_fit_recovers_an_exact_power_law():
    rows = [{"series": s, "density": d, **{q: 0.5 * d**1.5 for q in fig4.QUANTITIES}}
            for s in fig4.SERIES for d in (0.1, 0.2, 0.3)]
    for law in fig4.scaling(rows):
        assert law["n"] == pytest.approx(1.5, abs=1e-12)
        assert law["C"] == pytest.approx(0.5, rel=1e-12)
        assert law["max_misfit"] < 1e-12


@pytest.fixture
def tiny_table(tmp_path):
    """A table with nodes at five of the paper's densities, at γ = 0.1 and 1: every column 0.8 × the paper's value
    (at the node of the same series; 1.0 elsewhere), every ``*_std`` column 0.1 × it."""
    paper = {(r["gamma"], r["density"]): r for r in fig4.paper_rows()}
    densities = (0.0901, 0.0918, 0.2323, 0.2639, 0.3297)
    rows = []
    for g in (0.1, 1.0):
        for d in densities:
            row = {"density": d, "gamma": g}
            for q, col in fig4.QUANTITIES.items():
                v = 0.8 * paper[(g, d)][q] if (g, d) in paper else 1.0
                row[col], row[col + "_std"] = v, 0.1 * v
            rows.append(row)
    return FoamTable(to_csv(rows, tmp_path / "tiny.csv"))


def test_table_comparison_reads_the_table_at_the_paper_densities_it_covers(tiny_table):
    comparison = fig4.compare_table(tiny_table, fig4.paper_rows(), "tiny")
    covered = {(c["series"], c["density"]) for c in comparison}
    # 0.3422 lies beyond the table's last density: never extrapolated
    assert covered == {("transverse", 0.0918), ("transverse", 0.2639), ("isotropic", 0.0901),
                       ("isotropic", 0.2323), ("isotropic", 0.3297)}
    assert len(comparison) == 5 * len(fig4.QUANTITIES)
    for c in comparison:
        assert c["ratio"] == pytest.approx(0.8, rel=1e-12)
        assert c["ours_std"] == pytest.approx(0.1 * c["ours"], rel=1e-12)
    text = fig4.format_comparison(comparison)
    assert text.count("\n") == 1 + 5 and "(0.8)" in text


def test_shipped_single_density_tables_are_compared_at_their_nodes():
    from fenicsfoam.material.table import foam_table

    table = foam_table("equiaxed_polyhedral")
    assert fig4.compare_table(table, fig4.paper_rows(), "equiaxed_polyhedral") == []   # 18 % only
    nodes = fig4.table_nodes(table, "equiaxed_polyhedral")
    assert {(n["series"], n["density"]) for n in nodes} == {("transverse", 0.18), ("isotropic", 0.18)}
    iso = next(n for n in nodes if n["series"] == "isotropic")
    assert iso["E_x"] == pytest.approx(float(table.data["E1"][np.isclose(table.data["gamma"], 1.0)][0]))



@pytest.mark.parametrize("gamma, shape", [(1.0, (24, 24, 24)), (0.1, (10, 50, 50))])
def test_gauge_edge_skeleton_lies_where_three_cells_meet(gamma, shape):
    """At every skeleton point three distinct seeds are gauge-nearest to within twice the gauge's largest change
    between a voxel centre and its corner (brute force over 27 periodic images of each seed)."""
    from meshes.gauge import default_polytope

    skeleton, box = fig4.gauge_edge_skeleton(8, gamma, 3, shape)
    assert len(skeleton) > 50
    nu = default_polytope().deformed(gamma)
    seeds = np.random.default_rng(3).random((8, 3)) * box
    shifts = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), axis=-1).reshape(-1, 3) * box
    v = skeleton[:, None, None, :] - (seeds[None, :, None, :] + shifts[None, None, :, :])
    d = np.sort(np.max(v @ nu.T, axis=-1).min(axis=2), axis=1)          # per seed, then sorted
    # |g(a) − g(b)| ≤ max_i |ν_i · (a − b)| ≤ max_i Σ_k |ν_ik| h_k / 2 between a voxel centre and its corner
    bound = 2.0 * float((np.abs(nu) @ (box / np.array(shape))).max()) / 2.0
    assert np.all(d[:, 2] - d[:, 0] <= bound * (1 + 1e-12))
    # and the skeleton is special: random points of the box have gaps beyond the bound and a median 2× larger
    x = np.random.default_rng(0).random((500, 3)) * box
    v = x[:, None, None, :] - (seeds[None, :, None, :] + shifts[None, None, :, :])
    dx = np.sort(np.max(v @ nu.T, axis=-1).min(axis=2), axis=1)
    assert np.mean(dx[:, 2] - dx[:, 0] > bound) > 0.2
    assert np.median(d[:, 2] - d[:, 0]) < 0.5 * np.median(dx[:, 2] - dx[:, 0])


def test_gauge_edge_image_holds_the_density_and_turns_into_the_layers_at_low_gamma():
    img1, info1 = fig4.gauge_edge_image(8, 0.25, 1.0, 3, (24, 24, 24))
    img01, info01 = fig4.gauge_edge_image(8, 0.25, 0.1, 3, (10, 50, 50))
    for img, info in ((img1, info1), (img01, info01)):
        assert abs(img.mean() - 0.25) < 0.03 and info["measured_density"] == img.mean()
    # isotropic skeleton: mean |cos x| near 1/2; flattened cells: edges mostly in the y–z layers
    assert 0.35 < info1["edge_dir_abs_cos_x"] < 0.65 and info01["edge_dir_abs_cos_x"] < 0.3


def test_hybrid_image_holds_the_density_splits_it_by_the_strut_fraction_and_refuses_a_bad_one():
    shape = (10, 40, 40)
    fields = {"psi": fig4.wall_field(8, 0.1, 3, shape, upper=np.inf)[0]}
    total = int(np.ceil(0.26 * np.prod(shape)))
    images = {}
    for phi in (0.0, 0.5, 1.0):
        img, info = fig4.hybrid_image(8, 0.26, 0.1, 3, shape, phi, fields)
        images[phi] = img
        # with walls the union holds the target voxel count (ψ has ties only at round-off); the struts alone
        # (φ = 1) hold it to within one shell of ties of the skeleton distance
        assert abs(int(img.sum()) - total) <= (2 if phi < 1 else 0.03 * img.size)
        assert info["measured_density"] == img.mean()
        # the struts alone hold at least their share and at most one shell of ties more
        assert phi * 0.26 <= info["strut_density"] <= phi * 0.26 + 0.03
    # φ = 0: the wall level set alone; φ = 1: the struts alone; in between both member sets are present
    assert np.array_equal(images[0.0], fields["psi"] <= np.sort(fields["psi"].ravel())[total - 1])
    assert np.array_equal(images[1.0], fields["skeleton"] <= fig4._quantile_level(fields["skeleton"], total))
    assert (images[0.5] & ~images[1.0]).any() and (images[0.5] & ~images[0.0]).any()
    with pytest.raises(ValueError, match="1.5"):
        fig4.hybrid_image(8, 0.26, 0.1, 3, shape, 1.5, fields)


def test_homogenize_image_with_a_compliant_pore_phase_gives_the_voigt_modulus_along_a_laminate():
    """Layers normal to x, 4 of 10 solid, pores of modulus 0.01 and the same ν: along the layers the strain is
    uniform, so E_y = E_z = 0.4 · 1 + 0.6 · 0.01 exactly; with void pores the same image gives 0.4."""
    img = np.zeros((10, 6, 6), dtype=bool)
    img[:4] = True
    soft = fig4.homogenize_image(img, (1.0, 1.0, 1.0), "rotated", 1e-8, 200, "normal", void_modulus=0.01)
    assert soft["E2"] == pytest.approx(0.406, rel=1e-6) and soft["E3"] == pytest.approx(0.406, rel=1e-6)
    assert soft["islands"] == 0 and soft["edge_contacts_x"] == 0
    void = fig4.homogenize_image(img, (1.0, 1.0, 1.0), "hex8", 1e-8, 200, "normal")
    assert void["E2"] == pytest.approx(0.4, rel=1e-6)


def test_held_out_rows_lie_inside_their_series_and_are_compared_like_the_others(tiny_table):
    """The fourth density of each series sits between the used ones, so a table covering the used rows is read
    there by interpolation (never extrapolated); each held-out row is in no fit."""
    held = fig4.paper_rows(held_out=True)
    used = fig4.paper_rows()
    assert [(r["series"], r["density"]) for r in held] == [("transverse", 0.1798), ("isotropic", 0.1534)]
    for r in held:
        densities = [u["density"] for u in used if u["series"] == r["series"]]
        assert min(densities) < r["density"] < max(densities) and r["gamma"] == fig4.SERIES[r["series"]]
    comparison = fig4.compare_table(tiny_table, held, "tiny")
    assert {(c["series"], c["density"]) for c in comparison} == {("transverse", 0.1798), ("isotropic", 0.1534)}
    assert all(c["ours"] > 0 and np.isfinite(c["ratio"]) for c in comparison)
