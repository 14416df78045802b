"""Periodic finite-element RVE homogenization with dolfinx_mpc (the reference for the FFT solver).

Problem solved
--------------
On the periodic cell ``Y = box`` (default the unit cube ``[0, 1]³``) meshed by ``mesh`` with a piecewise-constant
stiffness ``C(x)`` (one 6×6 Voigt matrix per cell tag), for each of the six unit macroscopic strains ``E_J``
(Voigt order 11, 22, 33, 23, 13, 12 with engineering shear: for shear ``J`` the unit strain is ``γ = 1``, i.e.
``E_ij = E_ji = ½``) find the periodic fluctuation ``v_J ∈ [P_k]³`` with

    ∫_Y ε(w) : C : (E_J + ε(v_J)) dx = 0      for every periodic w,

then

    C_IJ       = ⟨E_I : σ_J⟩ = (1/|Y|) ∫_Y [C : (E_J + ε(v_J))]_I dx          (stress average, ``result.C_raw``)
    C^energy_IJ = (1/|Y|) ∫_Y (E_I + ε(v_I)) : C : (E_J + ε(v_J)) dx          (energy, symmetric by construction)

``|Y|`` is the volume of the box, not of the mesh: a solid-only foam mesh averages with void as zero stress. The
stress ``σ = ∂ψ/∂ε`` derives from the energy density ``ψ(ε) = ½ ε_M · C_M ε_M`` (Mandel vectors, so that the
6×6 ``C_M = W C W``, ``W = diag(1, 1, 1, √2, √2, √2)``, is the tensor in an orthonormal basis). By Galerkin
orthogonality the two stiffnesses differ only by the algebraic residual, so their difference
(``info["energy_vs_stress_rel_diff"]``) measures the linear solve, not the discretisation.

Discrete choices
----------------
* Heterogeneity is data: ``C_M`` is one DG0 field of 6×6 tensors filled from the cell tags; one form for all cells.
* Periodicity: ONE ``create_periodic_constraint_geometrical`` call. Slaves are the dofs on the faces
  ``x = x1``, ``y = y1``, ``z = z1`` (edges and corners included); the relation sends every coordinate that equals
  its upper bound to the lower bound, so an edge dof ``(x1, y1, z)`` maps to ``(x0, y0, z)`` and the seven upper
  corners map to the single master corner ``(x0, y0, z0)``. No master is a slave and no dof is constrained twice
  (three successive calls are silently wrong on edges and corners: measured edge jumps of 5e-2 and an
  asymmetric C). The mesh must be periodic node for node (the master of every slave is a node of the opposite
  face).
* Rigid translations: the three components of ONE dof are set to zero — the dof nearest the box centre among the
  dofs that are neither slaves nor masters (not on the box boundary) and belong to a cell of non-zero stiffness;
  ties are broken by coordinates, so the same point is chosen whatever the partition. The right-hand side is
  orthogonal to translations, so the reaction at that dof vanishes and the stresses are exact. (The RVE corner is
  NOT pinned: it is a periodic master, and dolfinx_mpc 0.5 mishandles a Dirichlet condition on a master.)
* Void: a phase whose stiffness is exactly zero is allowed. Dofs that touch only zero-stiffness cells have an
  exactly zero row and column in the constrained matrix; their diagonal is set to 1 (right-hand side 0), which
  fixes them at zero without changing any other equation. The result is the exact zero-void limit — no ersatz
  stiffness. Their number is ``info["n_void_dofs"]``.
* Solver: one matrix assembly, one factorization (MUMPS LDLᵀ through a KSP with options prefix
  :data:`OPTIONS_PREFIX`) and six right-hand sides. A rigid-body near-nullspace is attached to the matrix, so
  ``petsc_options=iterative_options()`` (CG + GAMG) works for large meshes.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from typing import Any

import dolfinx
import dolfinx.fem.petsc
import dolfinx_mpc
import numpy as np
import ufl
from dolfinx import fem
from mpi4py import MPI
from petsc4py import PETSc

from foambase.cells import owned_cell_tags
from foambase.errors import InputError, NotConvergedError
from foambase.nullspace import rigid_body_modes
from homogenization.result import LOAD_CASES, HomogenizationResult
from homogenization.tensors import VOIGT_PAIRS, check_stiffness, voigt_to_mandel

__all__ = ["OPTIONS_PREFIX", "default_options", "homogenize_fem", "iterative_options", "unit_strain"]

logger = logging.getLogger(__name__)

#: PETSc options prefix of the RVE linear solver.
OPTIONS_PREFIX = "fenicsfoam_rve_"

#: Element degrees that are supported (and tested).
DEGREES = (1, 2)

_UNIT_BOX = ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))


def default_options() -> dict[str, Any]:
    """Default PETSc options (without prefix): one MUMPS LDLᵀ factorization, reused for the six load cases.

    The constrained matrix is symmetric (slave, pinned and void rows are identity rows), so MUMPS's symmetric
    factorization (``pc_type cholesky``, MUMPS ``SYM = 2``) applies; it stores half the factor of an LU.
    """
    return {"ksp_type": "preonly", "pc_type": "cholesky", "pc_factor_mat_solver_type": "mumps"}


def iterative_options(rtol: float = 1e-8) -> dict[str, Any]:
    """PETSc options for CG + smoothed-aggregation AMG (GAMG) with the rigid-body near-nullspace.

    Faster than the direct solver beyond ~50k dofs (see README). The error of C is of the order of the relative
    residual squared times the condition (measured: rtol 1e-8 → 2e-10, rtol 1e-6 → 2e-8 on a 15k-dof inclusion);
    ``info["energy_vs_stress_rel_diff"]`` tracks it. ``pc_gamg_threshold`` 0.01 (drop weak couplings while
    aggregating) cut the CG iterations by 40 % on that problem.
    """
    return {"ksp_type": "cg", "ksp_rtol": rtol, "ksp_max_it": 2000, "pc_type": "gamg", "pc_gamg_threshold": 0.01}


def unit_strain(J: int) -> np.ndarray:
    """The 3×3 unit macroscopic strain of Voigt case ``J``: ``E_ii = 1`` (J < 3), ``E_ij = E_ji = ½`` (γ_ij = 1)."""
    i, j = VOIGT_PAIRS[J]
    E = np.zeros((3, 3))
    E[i, j] += 0.5
    E[j, i] += 0.5
    return E


# --------------------------------------------------------------------------------------------------
# Constitutive law in UFL
# --------------------------------------------------------------------------------------------------
def _mandel(e):
    """3×3 UFL strain → Mandel 6-vector, written symmetrically in (ij, ji) so that ∂ψ/∂ε is a symmetric tensor."""
    s = 1.0 / np.sqrt(2.0)
    return ufl.as_vector([e[0, 0], e[1, 1], e[2, 2], s * (e[1, 2] + e[2, 1]), s * (e[0, 2] + e[2, 0]),
                          s * (e[0, 1] + e[1, 0])])


def _stress(C_M, eps):
    """``σ = ∂ψ/∂ε`` with ``ψ(ε) = ½ ε_M · C_M ε_M``."""
    eps = ufl.variable(eps)
    psi = 0.5 * ufl.dot(_mandel(eps), ufl.dot(C_M, _mandel(eps)))
    return ufl.diff(psi, eps)


def _strain(v):
    return ufl.sym(ufl.grad(v))


# --------------------------------------------------------------------------------------------------
# Input checks and data
# --------------------------------------------------------------------------------------------------
def _check_degree(degree) -> int:
    if isinstance(degree, bool) or not isinstance(degree, (int, np.integer)) or int(degree) not in DEGREES:
        raise InputError(f"degree must be one of {DEGREES}, got {degree!r}")
    return int(degree)


def _check_box(box) -> np.ndarray:
    b = np.asarray(box, dtype=float)
    if b.shape != (2, 3) or not np.all(np.isfinite(b)) or np.any(b[1] <= b[0]):
        raise InputError(f"box must be ((x0, y0, z0), (x1, y1, z1)) with x1 > x0 etc., got {box!r}")
    return b


def _owned_cell_tags(mesh, cell_tags, comm) -> np.ndarray:
    """Tag of every owned cell (raises if some cell has none); the set of tags present is checked by the caller."""
    tags = owned_cell_tags(mesh, cell_tags, -1)
    n_untagged = comm.allreduce(int(np.count_nonzero(tags < 0)), op=MPI.SUM)
    if n_untagged:
        raise InputError(f"{n_untagged} cells of the mesh have no tag in cell_tags; every cell needs a material")
    return tags


def _check_materials(materials: Mapping[int, np.ndarray], tags_present: set[int]) -> dict[int, np.ndarray]:
    if not isinstance(materials, Mapping) or not materials:
        raise InputError(f"materials must be a non-empty mapping cell tag -> 6×6 Voigt stiffness, got {materials!r}")
    given = {int(t) for t in materials}
    missing, unused = sorted(tags_present - given), sorted(given - tags_present)
    if missing:
        raise InputError(f"cell tags {missing} are in the mesh but have no material (materials has tags "
                         f"{sorted(given)}, the mesh has {sorted(tags_present)})")
    if unused:
        raise InputError(f"materials given for cell tags {unused} that are not in the mesh "
                         f"(the mesh has tags {sorted(tags_present)})")
    checked = {}
    for tag, C in materials.items():
        check_stiffness(C, allow_zero=True, name=f"materials[{tag}]")
        checked[int(tag)] = np.asarray(C, dtype=float)
    if all(not C.any() for C in checked.values()):
        raise InputError("all materials are zero: at least one phase needs a non-zero stiffness")
    return checked


def _check_inside_box(mesh, box: np.ndarray, tol: float, comm) -> None:
    x = mesh.geometry.x[:, :3]
    lo, hi = np.empty(3), np.empty(3)
    comm.Allreduce(x.min(axis=0) if len(x) else np.full(3, np.inf), lo, op=MPI.MIN)
    comm.Allreduce(x.max(axis=0) if len(x) else np.full(3, -np.inf), hi, op=MPI.MAX)
    if np.any(lo < box[0] - tol) or np.any(hi > box[1] + tol):
        raise InputError(f"the mesh spans [{lo.tolist()}, {hi.tolist()}], outside the periodic box "
                         f"[{box[0].tolist()}, {box[1].tolist()}]; pass box= to match the mesh")


def _stiffness_field(mesh, tags: np.ndarray, materials: dict[int, np.ndarray]):
    """DG0 field of 6×6 Mandel stiffnesses, set on the owned cells from their tags, then scattered to ghosts."""
    Q = fem.FunctionSpace(mesh, ufl.TensorElement("DG", mesh.ufl_cell(), 0, shape=(6, 6)))
    C_M = fem.Function(Q, name="C_mandel")
    values = np.zeros((len(tags), 36))
    for tag, C in materials.items():
        values[tags == tag] = voigt_to_mandel(C).ravel()
    blocks = Q.dofmap.list.array.reshape(-1, Q.dofmap.dof_layout.num_dofs)[: len(tags), 0]
    C_M.x.array.reshape(-1, 36)[blocks] = values
    C_M.x.scatter_forward()
    return C_M


def _volumes_by_tag(mesh, tags: np.ndarray, comm) -> dict[int, float]:
    """Meshed volume of each tag, summed over ranks."""
    Q0 = fem.FunctionSpace(mesh, ("DG", 0))
    vol = fem.assemble_vector(fem.form(ufl.TestFunction(Q0) * ufl.dx))
    cells = Q0.dofmap.list.array[: len(tags)]
    local = {int(t): float(vol.array[cells[tags == t]].sum()) for t in np.unique(tags)}
    all_tags = sorted({t for d in comm.allgather(local) for t in d})
    return {t: comm.allreduce(local.get(t, 0.0), op=MPI.SUM) for t in all_tags}


# --------------------------------------------------------------------------------------------------
# Periodicity and rigid translations
# --------------------------------------------------------------------------------------------------
def _periodic_constraint(V, box: np.ndarray, tol: float, comm):
    """One geometrical periodic constraint: upper faces, edges and corners → their images on the lower faces.

    Raises if some upper-face dof is not tied to exactly one master node with weight 1: dolfinx_mpc silently
    leaves a dof free when its image is outside the mesh, and interpolates when the image is not a node.
    """
    lo, hi = box[0][:, None], box[1][:, None]

    def on_upper_face(x):
        return np.any(np.abs(x[:3] - hi) < tol, axis=0)

    def to_master(x):
        out = x.copy()
        upper = np.abs(x[:3] - hi) < tol
        out[:3] = np.where(upper, lo, x[:3])
        return out

    mpc = dolfinx_mpc.MultiPointConstraint(V)
    mpc.create_periodic_constraint_geometrical(V, on_upper_face, to_master, [])
    mpc.finalize()

    n_owned, bs = V.dofmap.index_map.size_local, V.dofmap.index_map_bs
    upper_blocks = fem.locate_dofs_geometrical(V, on_upper_face)
    n_upper = comm.allreduce(int(np.count_nonzero(upper_blocks < n_owned)) * bs, op=MPI.SUM)
    slaves = mpc.slaves[mpc.slaves < n_owned * bs]
    coeffs, offsets = mpc.coefficients()
    # nodal: one master of weight 1; further weights below 1e-8 are round-off of the basis evaluation at the
    # image point (seen on cut-cell foam meshes: an extra 1e-13 weight through a poorly shaped neighbour cell)
    starts, counts = offsets[slaves], offsets[slaves + 1] - offsets[slaves]
    segment = np.repeat(np.arange(len(slaves)), counts)
    weight = coeffs[np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts) + np.repeat(starts, counts)]
    largest = np.full(len(slaves), -np.inf)
    np.maximum.at(largest, segment, weight)
    rest = np.bincount(segment, weights=np.abs(weight), minlength=len(slaves)) - np.abs(largest)
    nodal = (np.abs(largest - 1.0) < 1e-8) & (rest < 1e-8)
    n_nodal = comm.allreduce(int(np.count_nonzero(nodal)), op=MPI.SUM)
    if n_nodal != n_upper:
        raise InputError(f"{n_upper - n_nodal} of the {n_upper} dofs on the upper faces of the box have no "
                         "node-for-node image on the lower faces; the mesh must be periodic node for node on "
                         "opposite faces of the box")
    return mpc


def _pinned_dof_bc(V, x: np.ndarray, tags, materials, box: np.ndarray, tol: float, comm):
    """Zero Dirichlet condition on the interior, stiff dof nearest the box centre; returns (bc, point).

    ``x`` are the coordinates of the local dofs (blocks) of ``V``.
    """
    n_owned = V.dofmap.index_map.size_local
    interior = np.all((x > box[0] + tol) & (x < box[1] - tol), axis=1)
    stiff_tags = [t for t, C in materials.items() if C.any()]
    dofs_per_cell = V.dofmap.dof_layout.num_dofs
    cell_dofs = V.dofmap.list.array.reshape(-1, dofs_per_cell)[: len(tags)]
    in_stiff_cell = np.zeros(len(x), dtype=bool)
    in_stiff_cell[cell_dofs[np.isin(tags, stiff_tags)].ravel()] = True
    candidates = np.flatnonzero(interior & in_stiff_cell)
    candidates = candidates[candidates < n_owned]
    best = None
    if len(candidates):
        centre = box.mean(axis=0)
        # keys rounded to the geometric tolerance, so that round-off cannot make ranks or partitions disagree
        keys = np.round(np.column_stack([np.linalg.norm(x[candidates] - centre, axis=1), x[candidates]]) / tol)
        i = np.lexsort(keys.T[::-1])[0]
        best = (tuple(keys[i].astype(np.int64).tolist()), x[candidates[i]])
    found = [k for k in comm.allgather(best) if k is not None]
    if not found:
        raise InputError("no dof inside the box belongs to a cell with non-zero stiffness, so rigid translations "
                         "cannot be removed; refine the mesh (at least one interior node is needed)")
    point = min(found, key=lambda k: k[0])[1]
    dofs = fem.locate_dofs_geometrical(V, lambda y: np.all(np.abs(y[:3] - point[:, None]) < tol, axis=0))
    bc = fem.dirichletbc(np.zeros(3, dtype=PETSc.ScalarType), dofs, V)
    return bc, point


def _make_solver(A: PETSc.Mat, options: dict[str, Any], comm) -> PETSc.KSP:
    ksp = PETSc.KSP().create(comm)
    ksp.setOptionsPrefix(OPTIONS_PREFIX)
    ksp.setOperators(A)
    opts = PETSc.Options()
    for k, v in options.items():
        opts[OPTIONS_PREFIX + k] = v
    try:
        ksp.setFromOptions()
    finally:
        for k in options:
            del opts[OPTIONS_PREFIX + k]
    ksp.setConvergenceHistory(reset=True)
    return ksp


# --------------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------------
def homogenize_fem(mesh: dolfinx.mesh.Mesh, cell_tags: dolfinx.mesh.MeshTagsMetaClass,
                   materials: Mapping[int, np.ndarray], *, degree: int = 1, comm: MPI.Comm | None = None,
                   petsc_options: Mapping[str, Any] | None = None, box=_UNIT_BOX) -> HomogenizationResult:
    """Homogenized 6×6 Voigt stiffness of a periodic RVE mesh with piecewise-constant phases.

    Parameters
    ----------
    mesh
        Tetrahedral (or hexahedral) mesh of the periodic cell, periodic node for node on opposite faces of
        ``box``. It may cover only part of the box (a solid-only foam mesh): averages are over the box volume.
    cell_tags
        Cell tags; every cell must carry a tag (e.g. SOLID = 1, VOID = 2 from ``meshes.foam.mesh_rve``).
    materials
        Cell tag → 6×6 Voigt stiffness (order 11, 22, 33, 23, 13, 12, engineering shear). Any symmetric
        positive-definite matrix; an exactly zero matrix is a void phase (see the module docstring). Every tag in
        the mesh needs a material and every material a tag in the mesh.
    degree
        Lagrange degree of the fluctuation, 1 or 2.
    comm
        Communicator for the reductions; defaults to (and must be congruent with) ``mesh.comm``.
    petsc_options
        PETSc options (without prefix) that update :func:`default_options`; they are set under the prefix
        :data:`OPTIONS_PREFIX` for this solve only.
    box
        ``((x0, y0, z0), (x1, y1, z1))``, the periodic cell; default the unit cube.

    Returns
    -------
    HomogenizationResult
        ``method="fem"``; ``C_raw`` from stress averages (column J = ⟨σ⟩ for unit strain E_J), ``C`` its
        symmetric part; ``iterations`` (1 per case for a direct solve, else the Krylov count); ``residuals``
        (Krylov history, or ``[‖b‖, ‖b - A x‖]`` for a direct solve); ``info`` with ``n_dofs``, ``degree``,
        ``timings`` in s (``setup``, ``assembly``, ``factorization`` — or preconditioner set-up —, ``solves``
        per case, ``averages``),
        ``C_energy``, ``energy_vs_stress_rel_diff``, ``constraint``, ``pinned_point``, ``n_void_dofs``,
        ``volume_fractions`` (meshed volume of each tag / box volume) and the PETSc options used.

    """
    t_start = time.perf_counter()
    degree = _check_degree(degree)
    box = _check_box(box)
    comm = mesh.comm if comm is None else comm
    if MPI.Comm.Compare(comm, mesh.comm) not in (MPI.IDENT, MPI.CONGRUENT):
        raise InputError("comm must be the mesh's communicator (or congruent with it)")
    if mesh.geometry.dim != 3 or mesh.topology.dim != 3:
        raise InputError(f"a 3D volume mesh is needed, got gdim={mesh.geometry.dim}, tdim={mesh.topology.dim}")
    options = {**default_options(), **dict(petsc_options or {})}
    tol = 1e-8 * float(np.max(box[1] - box[0]))
    box_volume = float(np.prod(box[1] - box[0]))

    tags = _owned_cell_tags(mesh, cell_tags, comm)
    tags_present = {int(t) for t in set().union(*comm.allgather(set(np.unique(tags).tolist())))}
    materials = _check_materials(materials, tags_present)
    _check_inside_box(mesh, box, tol, comm)

    # ---- spaces, data, constraint, pinned dof
    V = fem.VectorFunctionSpace(mesh, ("CG", degree))
    C_M = _stiffness_field(mesh, tags, materials)
    mpc = _periodic_constraint(V, box, tol, comm)
    x_dofs = V.tabulate_dof_coordinates()[:, :3]
    bc, pinned_point = _pinned_dof_bc(V, x_dofs, tags, materials, box, tol, comm)

    # ---- forms: compiled once; the macroscopic strain is a Constant updated per load case
    E_macro = fem.Constant(mesh, np.zeros((3, 3), dtype=PETSc.ScalarType))
    u, w = ufl.TrialFunction(V), ufl.TestFunction(V)
    a = fem.form(ufl.inner(_stress(C_M, _strain(u)), _strain(w)) * ufl.dx)
    L = fem.form(-ufl.inner(_stress(C_M, E_macro), _strain(w)) * ufl.dx)
    V_mpc = mpc.function_space
    v_a, v_b = fem.Function(V_mpc), fem.Function(V_mpc)
    E_a, E_b = (fem.Constant(mesh, np.zeros((3, 3), dtype=PETSc.ScalarType)) for _ in range(2))
    T0 = fem.TensorFunctionSpace(mesh, ("DG", 0))  # per-cell integrals of the stress tensor
    stress_form = fem.form(ufl.inner(_stress(C_M, E_a + _strain(v_a)), ufl.TestFunction(T0)) * ufl.dx)
    energy_form = fem.form(ufl.inner(_stress(C_M, E_a + _strain(v_a)), E_b + _strain(v_b)) * ufl.dx)
    t_setup = time.perf_counter() - t_start

    # ---- one assembly, void rows, one factorization
    t0 = time.perf_counter()
    A = dolfinx_mpc.assemble_matrix(a, mpc, bcs=[bc])
    diagonal = A.getDiagonal()
    void_rows = diagonal.array == 0.0
    n_void_dofs = comm.allreduce(int(np.count_nonzero(void_rows)), op=MPI.SUM)
    if n_void_dofs:
        diagonal.array[void_rows] = 1.0
        A.setDiagonal(diagonal, addv=PETSc.InsertMode.INSERT_VALUES)
    A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
    A.setNearNullSpace(rigid_body_modes(V, centre=box.mean(axis=0)))
    t_assembly = time.perf_counter() - t0

    t0 = time.perf_counter()
    ksp = _make_solver(A, options, comm)
    ksp.setUp()
    t_factor = time.perf_counter() - t0

    # ---- six right-hand sides
    b = dolfinx.la.create_petsc_vector(V_mpc.dofmap.index_map, V_mpc.dofmap.index_map_bs)
    r = A.createVecLeft()
    solutions, iterations, residuals, t_solves = [], [], [], []
    direct = ksp.getType() == PETSc.KSP.Type.PREONLY
    for J in range(6):
        t0 = time.perf_counter()
        E_macro.value[:] = unit_strain(J)
        dolfinx_mpc.assemble_vector(L, mpc, b)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        fem.petsc.set_bc(b, [bc])
        v = fem.Function(V_mpc)
        ksp.solve(b, v.vector)
        reason = ksp.getConvergedReason()
        if reason <= 0:
            raise NotConvergedError(f"RVE solve for load case {LOAD_CASES[J]} did not converge: KSP reason {reason} "
                                    f"(options {options})")
        if direct:
            A.mult(v.vector, r)
            r.aypx(-1.0, b)  # r = b - A x
            history = [b.norm(), r.norm()]
        else:
            history = ksp.getConvergenceHistory()
        v.x.scatter_forward()
        mpc.backsubstitution(v.vector)
        solutions.append(v.x.array.copy())
        iterations.append(1 if direct else int(ksp.getIterationNumber()))
        residuals.append([float(h) for h in history])
        t_solves.append(time.perf_counter() - t0)

    # ---- averages: stress-based C_raw and energy-based C_energy, over the box volume
    t0 = time.perf_counter()
    strains = [unit_strain(J) for J in range(6)]
    owned_T0 = T0.dofmap.list.array[: len(tags)]

    def mean_stress(J) -> np.ndarray:
        """Voigt vector of (1/|Y|) ∫ σ(E_J + ε(v_J)) dx."""
        E_a.value[:], v_a.x.array[:] = strains[J], solutions[J]
        local = fem.assemble_vector(stress_form).array.reshape(-1, 9)[owned_T0].sum(axis=0)
        total = np.empty(9)
        comm.Allreduce(local, total, op=MPI.SUM)
        sigma = total.reshape(3, 3) / box_volume
        return np.array([0.5 * (sigma[i, j] + sigma[j, i]) for i, j in VOIGT_PAIRS])

    def mean_energy(I, J) -> float:
        """(1/|Y|) ∫ (E_I + ε(v_I)) : C : (E_J + ε(v_J)) dx."""
        E_a.value[:], v_a.x.array[:] = strains[J], solutions[J]
        E_b.value[:], v_b.x.array[:] = strains[I], solutions[I]
        return comm.allreduce(fem.assemble_scalar(energy_form), op=MPI.SUM) / box_volume

    C_raw = np.column_stack([mean_stress(J) for J in range(6)])
    C_energy = np.zeros((6, 6))
    for I in range(6):
        for J in range(I, 6):
            C_energy[I, J] = C_energy[J, I] = mean_energy(I, J)
    t_means = time.perf_counter() - t0

    scale = np.abs(C_energy).max()
    volumes = _volumes_by_tag(mesh, tags, comm)
    info = {
        "n_dofs": V.dofmap.index_map.size_global * V.dofmap.index_map_bs,
        "n_cells": mesh.topology.index_map(3).size_global,
        "degree": degree,
        "n_ranks": comm.size,
        "constraint": "periodic, one create_periodic_constraint_geometrical call: upper faces/edges/corners → "
                      "lower images (seven upper corners → the master corner)",
        "n_slaves": comm.allreduce(int(mpc.num_local_slaves), op=MPI.SUM),
        "rigid_translations": "zero Dirichlet on the interior stiff dof nearest the box centre",
        "pinned_point": pinned_point.tolist(),
        "n_void_dofs": n_void_dofs,
        "volume_fractions": {t: vol / box_volume for t, vol in volumes.items()},
        "box": box.tolist(),
        "petsc_options": {OPTIONS_PREFIX + k: v for k, v in options.items()},
        "ksp_type": ksp.getType(),
        "pc_type": ksp.getPC().getType(),
        "timings": {"setup": t_setup, "assembly": t_assembly, "factorization": t_factor, "solves": t_solves,
                    "averages": t_means},
        "C_energy": C_energy,
        "energy_vs_stress_rel_diff": float(np.abs(C_energy - C_raw).max() / scale) if scale > 0 else 0.0,
    }
    ksp.destroy()
    A.destroy()
    wall = time.perf_counter() - t_start
    logger.info("FEM RVE: %d dofs (P%d), assembly %.3g s, factorization %.3g s, 6 solves %.3g s, total %.3g s",
                info["n_dofs"], degree, t_assembly, t_factor, sum(t_solves), wall)
    return HomogenizationResult.from_columns(C_raw, method="fem", iterations=iterations, residuals=residuals,
                                             wall_s=wall, converged=True, info=info)
