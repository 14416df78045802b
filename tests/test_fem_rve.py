"""Periodic FEM RVE homogenization (homogenization.fem) against closed forms, bounds and a serial/parallel check.

Meshes are dolfinx's structured unit cubes: periodic node for node, and conforming to planes x = k/N, so cells
tagged by their midpoint give exact laminates and cubic inclusions.
"""

import numpy as np
import pytest
from dolfinx import mesh as dmesh
from mpi4py import MPI

from homogenization.fem import homogenize_fem, iterative_options, unit_strain
from homogenization.tensors import (
    VOIGT_PAIRS,
    isotropic_voigt,
    rotate_voigt,
    rotation_from_axis,
    transverse_isotropic_voigt,
    voigt_to_mandel,
)

ONE_RANK_SKIP = pytest.mark.skipif(
    MPI.COMM_WORLD.size < 2,
    reason="compares a COMM_WORLD run with a COMM_SELF run: on one rank they are the same computation "
           "(runs under mpirun -n 2)")

C_ISO = isotropic_voigt(10.0, 0.3)
C_SOFT = isotropic_voigt(1.0, 0.2)
# A transversely isotropic phase with its l axis off every coordinate axis: fully anisotropic in the RVE frame.
C_TI = rotate_voigt(transverse_isotropic_voigt(E_t=4.0, E_l=1.0, nu_t=0.3, nu_tl=0.2, G_l=0.5),
                    rotation_from_axis([1.0, 2.0, 3.0]))
EXACT = 1e-10  # P1/P2 reproduce piecewise-linear fluctuations: only round-off and the direct solve remain


def unit_cube(n, comm=MPI.COMM_WORLD):
    return dmesh.create_unit_cube(comm, n, n, n)


def tag_cells(msh, tag_of_midpoints):
    """Cell tags from a vectorised function of the (n, 3) cell midpoints."""
    n = msh.topology.index_map(3).size_local + msh.topology.index_map(3).num_ghosts
    cells = np.arange(n, dtype=np.int32)
    tags = np.asarray(tag_of_midpoints(dmesh.compute_midpoints(msh, 3, cells)), dtype=np.int32)
    return dmesh.meshtags(msh, 3, cells, tags)


def laminate(phases, fractions, axis):
    """Exact stiffness of a rank-one laminate with layers normal to e_axis (Voigt, engineering shear).

    Components N with an index equal to ``axis`` (ε·n) may jump, their tractions σ_N are continuous; the in-plane
    strains ε_T are continuous (= E_T). Per phase ε_N = C_NN⁻¹ (σ_N − C_NT E_T), and ⟨ε_N⟩ = E_N gives
    σ_N = ⟨C_NN⁻¹⟩⁻¹ (E_N + ⟨C_NN⁻¹ C_NT⟩ E_T); then ⟨σ_T⟩ = ⟨C_TN ε_N + C_TT E_T⟩.
    """
    N = [I for I, pair in enumerate(VOIGT_PAIRS) if axis in pair]
    T = [I for I in range(6) if I not in N]
    inv_NN = [np.linalg.inv(C[np.ix_(N, N)]) for C in phases]
    A = np.linalg.inv(sum(f * iC for f, iC in zip(fractions, inv_NN)))
    B = sum(f * iC @ C[np.ix_(N, T)] for f, iC, C in zip(fractions, inv_NN, phases))
    C_eff = np.zeros((6, 6))
    for J in range(6):
        E = np.eye(6)[J]
        sigma_N = A @ (E[N] + B @ E[T])
        sigma = np.zeros(6)
        sigma[N] = sigma_N
        for f, iC, C in zip(fractions, inv_NN, phases):
            eps_N = iC @ (sigma_N - C[np.ix_(N, T)] @ E[T])
            sigma[T] += f * (C[np.ix_(T, N)] @ eps_N + C[np.ix_(T, T)] @ E[T])
        C_eff[:, J] = sigma
    return C_eff


def void_laminate(C_solid, f_solid, axis):
    """Laminate of a solid layer and a void layer: σ_N = 0 everywhere, in-plane C = f (C_TT − C_TN C_NN⁻¹ C_NT)."""
    N = [I for I, pair in enumerate(VOIGT_PAIRS) if axis in pair]
    T = [I for I in range(6) if I not in N]
    C_eff = np.zeros((6, 6))
    C_eff[np.ix_(T, T)] = f_solid * (C_solid[np.ix_(T, T)]
                                     - C_solid[np.ix_(T, N)] @ np.linalg.solve(C_solid[np.ix_(N, N)],
                                                                               C_solid[np.ix_(N, T)]))
    return C_eff


def rel_err(C, C_ref):
    return np.abs(C - C_ref).max() / np.abs(C_ref).max()


def check_consistent(r):
    """Symmetry of C_raw and agreement of the energy and stress-average stiffnesses (Galerkin orthogonality)."""
    assert r.method == "fem"
    assert r.asymmetry < EXACT
    assert r.info["energy_vs_stress_rel_diff"] < EXACT
    assert len(r.iterations) == 6 and len(r.residuals) == 6


def test_unit_strain_is_engineering_voigt():
    for J, (i, j) in enumerate(VOIGT_PAIRS):
        E = unit_strain(J)
        gamma = E[i, j] + E[j, i]  # engineering component: ε_ii for normals, γ_ij = 2 ε_ij for shears
        assert gamma == pytest.approx(1.0 if i != j else 2.0)
        assert np.count_nonzero(E) == (1 if i == j else 2)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_laminate_closed_forms_are_consistent(axis):
    """The reference formulas themselves: equal phases give the phase; a vanishing phase gives the void laminate."""
    assert rel_err(laminate([C_TI, C_TI], [0.3, 0.7], axis), C_TI) < EXACT
    assert rel_err(laminate([C_TI, 1e-9 * C_ISO], [0.3, 0.7], axis), void_laminate(C_TI, 0.3, axis)) < 1e-7


@pytest.mark.mpi
@pytest.mark.parametrize("C", [C_ISO, C_TI], ids=["isotropic", "rotated-TI"])
def test_homogeneous_cube_returns_the_material(C):
    msh = unit_cube(3)
    r = homogenize_fem(msh, tag_cells(msh, lambda x: np.full(len(x), 7)), {7: C})
    check_consistent(r)
    assert rel_err(r.C, C) < EXACT
    assert r.iterations == [1] * 6
    assert r.info["volume_fractions"] == {7: pytest.approx(1.0)}
    assert r.info["n_void_dofs"] == 0


@pytest.mark.mpi
@pytest.mark.parametrize("degree, n", [(1, 4), (2, 2)])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_laminate_matches_closed_form(axis, degree, n):
    f = 0.25 if n == 4 else 0.5
    msh = unit_cube(n)
    cell_tags = tag_cells(msh, lambda x: np.where(x[:, axis] < f, 1, 2))
    r = homogenize_fem(msh, cell_tags, {1: C_TI, 2: C_ISO}, degree=degree)
    check_consistent(r)
    assert rel_err(r.C, laminate([C_TI, C_ISO], [f, 1 - f], axis)) < EXACT
    assert r.info["volume_fractions"] == {1: pytest.approx(f), 2: pytest.approx(1 - f)}


@pytest.mark.parametrize("degree", [1, 2])
def test_laminate_on_hexahedra(degree):
    msh = dmesh.create_unit_cube(MPI.COMM_WORLD, 4, 4, 4, dmesh.CellType.hexahedron)
    r = homogenize_fem(msh, tag_cells(msh, lambda x: np.where(x[:, 1] < 0.25, 1, 2)), {1: C_TI, 2: C_ISO},
                       degree=degree)
    check_consistent(r)
    assert rel_err(r.C, laminate([C_TI, C_ISO], [0.25, 0.75], axis=1)) < EXACT


def gmsh_laminate(h, f, axis, comm=MPI.COMM_WORLD):
    """Unstructured periodic mesh of the unit cube cut by the plane x_axis = f (tags 1 below, 2 above).

    gmsh (rank 0) meshes the two boxes conformingly, every upper face periodic with its translate on the lower face.
    """
    import gmsh
    from dolfinx.io import gmshio

    if comm.rank == 0:
        gmsh.initialize()
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("laminate")
        normal = np.eye(3)[axis]
        below = gmsh.model.occ.addBox(0, 0, 0, *(1 - (1 - f) * normal))
        above = gmsh.model.occ.addBox(*(f * normal), *(1 - f * normal))
        gmsh.model.occ.fragment([(3, below)], [(3, above)])
        gmsh.model.occ.synchronize()
        e = 1e-6
        for d in range(3):
            shift = np.eye(4)
            shift[d, 3] = 1.0
            upper_lo = np.full(3, -e)
            upper_lo[d] = 1 - e
            for _, surface in gmsh.model.getEntitiesInBoundingBox(*upper_lo, *np.full(3, 1 + e), dim=2):
                bbox = np.array(gmsh.model.getBoundingBox(2, surface)) - np.tile(np.eye(3)[d], 2)
                (_, master), = gmsh.model.getEntitiesInBoundingBox(*(bbox[:3] - e), *(bbox[3:] + e), dim=2)
                gmsh.model.mesh.setPeriodic(2, [surface], [master], shift.ravel().tolist())
        for _, volume in gmsh.model.getEntities(3):
            centre = gmsh.model.occ.getCenterOfMass(3, volume)
            gmsh.model.addPhysicalGroup(3, [volume], 1 if centre[axis] < f else 2)
        gmsh.option.setNumber("Mesh.CharacteristicLengthMax", h)
        gmsh.model.mesh.generate(3)
    msh, cell_tags, _ = gmshio.model_to_mesh(gmsh.model, comm, 0, gdim=3)
    if comm.rank == 0:
        gmsh.finalize()
    return msh, cell_tags


@pytest.mark.mpi
@pytest.mark.parametrize("axis, degree", [(0, 1), (1, 1), (2, 1), (1, 2)])
def test_laminate_on_unstructured_gmsh_mesh(axis, degree):
    """An unstructured periodic mesh (as the foam's) still reproduces the laminate exactly."""
    msh, cell_tags = gmsh_laminate(0.3, 0.3, axis)
    r = homogenize_fem(msh, cell_tags, {1: C_TI, 2: C_ISO}, degree=degree)
    check_consistent(r)
    assert rel_err(r.C, laminate([C_TI, C_ISO], [0.3, 0.7], axis)) < EXACT
    assert r.info["volume_fractions"] == {1: pytest.approx(0.3), 2: pytest.approx(0.7)}


def test_void_layer_is_exact_and_equals_solid_only_mesh():
    """A zero-stiffness void needs no ersatz: void-only dofs are removed, and a mesh of the solid alone, averaged
    over the whole cube, gives the same C."""
    msh = unit_cube(4)
    cell_tags = tag_cells(msh, lambda x: np.where(x[:, 1] < 0.5, 1, 2))
    r = homogenize_fem(msh, cell_tags, {1: C_TI, 2: np.zeros((6, 6))})
    check_consistent(r)
    assert rel_err(r.C, void_laminate(C_TI, 0.5, axis=1)) < EXACT
    assert r.info["n_void_dofs"] > 0

    solid_cells = cell_tags.indices[cell_tags.values == 1]
    solid, *_ = dmesh.create_submesh(msh, 3, solid_cells)
    r_solid = homogenize_fem(solid, tag_cells(solid, lambda x: np.ones(len(x))), {1: C_TI})
    assert rel_err(r_solid.C, r.C) < EXACT
    assert r_solid.info["volume_fractions"] == {1: pytest.approx(0.5)}


def cube_inclusion(msh):
    """Stiff cube [1/4, 3/4]³ (tag 1, volume 1/8) in a soft matrix (tag 2)."""
    return tag_cells(msh, lambda x: np.where(np.all(np.abs(x - 0.5) < 0.25, axis=1), 1, 2))


def test_p2_and_refinement_converge_on_an_inclusion():
    """Displacement FEM over-estimates the energy: C_h − C is positive semi-definite, P1 ⊂ P2 on the same mesh
    gives C_P1 ⪰ C_P2, and the error to a fine P2 reference decreases under refinement and with the degree."""
    materials = {1: C_ISO, 2: C_SOFT}
    C = {}
    for degree, n in [(1, 4), (1, 8), (2, 4), (2, 8)]:
        msh = unit_cube(n)
        r = homogenize_fem(msh, cube_inclusion(msh), materials, degree=degree)
        check_consistent(r)
        C[degree, n] = r.C
    reference = C[2, 8]
    err = {k: rel_err(v, reference) for k, v in C.items() if k != (2, 8)}
    assert err[1, 8] < 0.6 * err[1, 4]
    assert err[2, 4] < 0.6 * err[1, 4]
    tol = -1e-10 * np.abs(reference).max()
    assert np.linalg.eigvalsh(voigt_to_mandel(C[1, 4] - C[2, 4])).min() > tol   # nested spaces
    for key in [(1, 4), (1, 8), (2, 4)]:
        assert np.linalg.eigvalsh(voigt_to_mandel(C[key] - reference)).min() > tol
    # and below the Voigt (uniform strain) bound
    voigt = C_ISO / 8 + C_SOFT * 7 / 8
    assert np.linalg.eigvalsh(voigt_to_mandel(voigt - reference)).min() > 0


def test_gamg_with_rigid_body_near_nullspace_matches_lu():
    msh = unit_cube(4)
    cell_tags = cube_inclusion(msh)
    materials = {1: C_ISO, 2: C_SOFT}
    lu = homogenize_fem(msh, cell_tags, materials)
    cg = homogenize_fem(msh, cell_tags, materials, petsc_options=iterative_options(rtol=1e-12))
    assert cg.info["ksp_type"] == "cg" and cg.info["pc_type"] == "gamg"
    assert all(it > 1 for it in cg.iterations)
    assert all(len(h) == it + 1 for h, it in zip(cg.residuals, cg.iterations))
    assert rel_err(cg.C, lu.C) < 1e-8


@ONE_RANK_SKIP
@pytest.mark.mpi
@pytest.mark.parametrize("degree", [1, 2])
def test_parallel_equals_serial(degree):
    """Under mpirun: the distributed result equals a serial solve of the same mesh on every rank."""
    materials = {1: C_TI, 2: C_SOFT, 3: np.zeros((6, 6))}

    def tags(x):  # a stiff TI rod along z, a void rod along z (with void-only nodes), a soft matrix
        left, front = x[:, 0] < 0.5, x[:, 1] < 0.5
        return np.where(left & front, 1, np.where(~left & ~front, 3, 2))

    results = []
    for comm in (MPI.COMM_WORLD, MPI.COMM_SELF):
        msh = unit_cube(4, comm)
        results.append(homogenize_fem(msh, tag_cells(msh, tags), materials, degree=degree))
    parallel, serial = results
    assert parallel.info["n_ranks"] == MPI.COMM_WORLD.size
    assert parallel.info["pinned_point"] == pytest.approx(serial.info["pinned_point"], abs=1e-12)
    assert parallel.info["n_void_dofs"] == serial.info["n_void_dofs"] > 0
    assert rel_err(parallel.C, serial.C) < EXACT
    assert rel_err(parallel.info["C_energy"], serial.info["C_energy"]) < EXACT
    check_consistent(parallel)


# ---- errors ----------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def two_phase():
    msh = unit_cube(2)
    return msh, tag_cells(msh, lambda x: np.where(x[:, 0] < 0.5, 1, 2))


@pytest.mark.mpi
def test_error_tag_without_material(two_phase):
    with pytest.raises(ValueError, match=r"cell tags \[2\] are in the mesh but have no material"):
        homogenize_fem(*two_phase, {1: C_ISO})


@pytest.mark.mpi
def test_error_material_without_tag(two_phase):
    with pytest.raises(ValueError, match=r"materials given for cell tags \[5\] that are not in the mesh"):
        homogenize_fem(*two_phase, {1: C_ISO, 2: C_ISO, 5: C_ISO})


@pytest.mark.parametrize("degree", [0, 3, 1.0, True])
def test_error_bad_degree(two_phase, degree):
    with pytest.raises(ValueError, match=r"degree must be one of \(1, 2\)"):
        homogenize_fem(*two_phase, {1: C_ISO, 2: C_ISO}, degree=degree)


def test_error_bad_material(two_phase):
    with pytest.raises(ValueError, match=r"materials\[2\]"):
        homogenize_fem(*two_phase, {1: C_ISO, 2: -C_ISO})
    with pytest.raises(ValueError, match="all materials are zero"):
        homogenize_fem(*two_phase, {1: np.zeros((6, 6)), 2: np.zeros((6, 6))})


def test_error_untagged_cells(two_phase):
    msh, cell_tags = two_phase
    keep = cell_tags.values == 1
    partial = dmesh.meshtags(msh, 3, cell_tags.indices[keep], cell_tags.values[keep])
    with pytest.raises(ValueError, match="cells of the mesh have no tag"):
        homogenize_fem(msh, partial, {1: C_ISO})


def test_error_mesh_outside_box(two_phase):
    with pytest.raises(ValueError, match="outside the periodic box"):
        homogenize_fem(*two_phase, {1: C_ISO, 2: C_ISO}, box=((0, 0, 0), (0.5, 1, 1)))


def test_error_mesh_without_periodic_image():
    """A solid-only mesh that reaches x = 1 but not x = 0: dolfinx_mpc would leave those dofs free."""
    msh = unit_cube(4)
    cell_tags = tag_cells(msh, lambda x: np.where(x[:, 0] > 0.5, 1, 2))
    right, *_ = dmesh.create_submesh(msh, 3, cell_tags.indices[cell_tags.values == 1])
    with pytest.raises(ValueError, match="75 of the 129 dofs on the upper faces of the box have no node-for-node"):
        homogenize_fem(right, tag_cells(right, lambda p: np.ones(len(p))), {1: C_ISO})


@pytest.mark.mpi
def test_error_mesh_not_periodic_node_for_node():
    msh = unit_cube(3)
    x = msh.geometry.x
    on_face = np.isclose(x[:, 0], 1.0) & (x[:, 1] > 0.1) & (x[:, 1] < 0.9) & (x[:, 2] > 0.1) & (x[:, 2] < 0.9)
    x[on_face, 1] += 0.05  # the x = 1 face no longer matches the x = 0 face
    with pytest.raises(ValueError, match="no node-for-node image"):
        homogenize_fem(msh, tag_cells(msh, lambda p: np.ones(len(p))), {1: C_ISO})
