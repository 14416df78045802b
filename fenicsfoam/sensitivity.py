"""Adjoint sensitivities of probes at a converged equilibrium: d(probe)/d(parameter), exact for the discrete problem.

The discrete problem (:class:`fenicsfoam.solver.ElasticityProblem`) is: find the nodal displacement ``u`` with
the free rows of the assembled residual zero and the constrained dofs at their prescribed values,

    R_f(u, m) = 0,    u_b = g(θ),

``m`` the DG0 coefficient data (moduli, mass density, *l* axis per cell) and ``g(θ)`` the rigid motions'
Dirichlet values (servo angles θ). A probe ``J(u)`` (:mod:`fenicsfoam.probes`, each with ``gradient(u)``) then
depends on the parameters through ``u``. With ``j = ∂J/∂u``, the adjoint ``λ`` (zero on constrained dofs) solves

    J_ffᵀ λ_f = j_f,

with ``J_ff`` the free–free block of the *exact* tangent ``∂R/∂u`` (the solver's Jacobian: its form, which for the
corotational model includes the change of the polar rotation with ``u`` and the contacts' Nitsche terms, and the
cables' tangent blocks; ``tests/test_solver.py`` checks its Taylor remainder). Differentiating ``R_f(u(p), p) = 0``
gives

    dJ/dm_c = − λ · ∂R/∂m_c                      (one assembly of a DG0 form per coefficient: every cell at once)
    dJ/dθ   =   j · w − λ · (J w),  w = ∂g/∂θ    (the lifted boundary values: ``w`` is zero on free dofs)
    dJ/ds   = − λ · ∂R/∂s                        (a load factor: the load's term at factor 1, tested with λ)

where ``∂R/∂m`` is ``ufl.derivative`` of the residual form with the test function replaced by ``λ``, and
``J w`` the action of the unconstrained Jacobian form on ``w``. One factorization of the tangent serves every
probe (one transposed solve each); parameters that act through several coefficients are chained from these
per-cell gradients (:mod:`fenicsfoam.design`). Everything is collective and partition-independent (sums by
``allreduce``; per-cell results on the owned cells).

Nothing here is built until a sensitivity is asked for: a plain scene run never compiles these forms.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import assemble_vector
from petsc4py import PETSc

from foambase.errors import ComputationError, InputError

__all__ = ["Adjoint", "ProbeGradient", "material_coefficients", "motion_direction"]

logger = logging.getLogger(__name__)


def motion_direction(motion, X: np.ndarray, angle: float) -> np.ndarray:
    """``∂u/∂θ = R'(θ)(X − p)`` of a :class:`~fenicsfoam.bcs.RigidMotion` at points ``X`` (n, 3), per radian.

    ``R(θ) = I + sin θ K + (1 − cos θ) K²`` gives ``R' = cos θ K + sin θ K²``.
    """
    n = np.asarray(motion.axis, dtype=float)
    n = n / np.linalg.norm(n)
    K = np.array([[0.0, -n[2], n[1]], [n[2], 0.0, -n[0]], [-n[1], n[0], 0.0]])
    dR = np.cos(angle) * K + np.sin(angle) * (K @ K)
    return (np.asarray(X, dtype=float) - np.asarray(motion.point, dtype=float)) @ dR.T


@dataclass
class ProbeGradient:
    """The derivatives of one probe at the current equilibrium."""

    value: float                                            #: the probe's value
    fields: dict[str, np.ndarray] = field(default_factory=dict)  #: ∂J/∂(DG0 coefficient), per owned cell (× components)
    motions: dict[str, float] = field(default_factory=dict)      #: ∂J/∂θ per motion (per radian)
    loads: dict[str, float] = field(default_factory=dict)        #: ∂J/∂s per external load factor


class Adjoint:
    """Adjoint solves at the current (converged) state of an :class:`~fenicsfoam.solver.ElasticityProblem`.

    Parameters
    ----------
    problem
        The problem, at a converged state (after ``solve_step``).
    prefix
        PETSc options prefix of the adjoint solver (default: MUMPS LU, ``preonly``); its own, never the
        problem's.

    Call :meth:`factor` after every new equilibrium (it assembles and factors the exact tangent there), then
    :meth:`gradient` per probe.

    """

    def __init__(self, problem, prefix: str = "adjoint_"):
        if not prefix or not prefix.endswith("_"):
            raise InputError(f"the options prefix must be non-empty and end with '_', got {prefix!r}")
        if not problem.model.exact_tangent:
            raise InputError(f"adjoint sensitivities need the exact tangent; the {problem.model.name!r} model's "
                             "tangent is approximate (the rotation held fixed): use 'corotational', 'bonet_burton', "
                             "'svk' or 'linear' to differentiate this problem")
        self.problem = problem
        self._load_forms: dict[str, Any] = {}
        self._one = None
        V = problem.V
        self._lam = fem.Function(V, name="adjoint")
        self._w = fem.Function(V, name="motion_direction")
        self._action = None
        self._field_forms: dict[int, fem.FormMetaClass] = {}
        self._A = None
        self._state = None
        self.solves = 0
        self.factorizations = 0
        comm = V.mesh.comm
        self._ksp = PETSc.KSP().create(comm)
        self._ksp.setOptionsPrefix(prefix)
        db = PETSc.Options()
        defaults = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
        added = [prefix + k for k in defaults if not db.hasName(prefix + k)]
        for key in added:
            db[key] = defaults[key[len(prefix):]]
        self._ksp.setFromOptions()
        for key in added:
            db.delValue(key)
        self._rhs = problem.u.vector.duplicate()
        self._solution = problem.u.vector.duplicate()
        bs = V.dofmap.index_map_bs
        n_owned = V.dofmap.index_map.size_local
        rows = [m.dofs[m.dofs < n_owned] for m in problem.motions.values()]
        blocks = np.unique(np.concatenate(rows)) if rows else np.zeros(0, dtype=np.int32)
        self._bc_rows = (bs * blocks[:, None] + np.arange(bs)).ravel()

    # ----------------------------------------------------------------------------------------------
    def factor(self) -> None:
        """Assemble the exact tangent at the current ``u`` (identity on constrained dofs) and factor it."""
        self._A = self.problem.assemble_tangent(self._A)
        self._ksp.setOperators(self._A)
        self._ksp.setUp()
        self.factorizations += 1
        self._state = self.problem.u.x.array.copy()

    def _check_factored(self) -> None:
        u = self.problem.u.x.array
        if self._state is None or self._state.shape != u.shape or not np.array_equal(self._state, u):
            raise ComputationError("the adjoint solver is not factored at the current state: call factor() after "
                                   "every new equilibrium")

    def solve(self, dJdu: np.ndarray) -> fem.Function:
        """The adjoint ``λ`` for the probe gradient ``dJdu`` (owned dofs): ``J_ffᵀ λ_f = j_f``, ``λ_b = 0``."""
        self._check_factored()
        self._rhs.array[:] = dJdu
        self._rhs.array[self._bc_rows] = 0.0
        self._ksp.solveTranspose(self._rhs, self._solution)
        reason = self._ksp.getConvergedReason()
        if reason < 0:
            raise ComputationError(f"the adjoint solve failed (KSP converged reason {reason})")
        self.solves += 1
        self._solution.copy(self._lam.vector)
        self._lam.x.scatter_forward()
        return self._lam

    def _field_form(self, coefficient: fem.Function) -> fem.FormMetaClass:
        key = id(coefficient)
        if key not in self._field_forms:
            q = ufl.TestFunction(coefficient.function_space)
            r = ufl.replace(self.problem.residual_form, {self.problem.residual_form.arguments()[0]: self._lam})
            self._field_forms[key] = fem.form(ufl.derivative(r, coefficient, q))
        return self._field_forms[key]

    def field_gradient(self, coefficient: fem.Function) -> np.ndarray:
        """``−λ · ∂R/∂m_c`` for the DG0 coefficient ``m`` (a coefficient of the residual), per owned cell."""
        b = assemble_vector(self._field_form(coefficient))
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        space = coefficient.function_space
        bs = space.dofmap.index_map_bs
        n = space.mesh.topology.index_map(space.mesh.topology.dim).size_local
        dofs = space.dofmap.list.array.reshape(-1, space.dofmap.dof_layout.num_dofs)[:n, 0]
        values = -b.array.reshape(-1, bs)[dofs]
        b.destroy()
        return values[:, 0].copy() if bs == 1 else values.copy()

    def load_gradient(self, name: str) -> float:
        """``−λ · ∂R/∂s`` for the factor ``s`` of the external load ``name`` (force, traction, pressure, cable).

        Every such load is linear in its factor, so ``∂R/∂s`` is its term at factor 1: a UFL form with the test
        function replaced by ``λ`` (assembled), or a cable's nodal forces at tension factor 1.
        """
        problem = self.problem
        load = problem.external.get(name)
        if load is None or hasattr(load, "bind_stress"):
            actuating = sorted(n for n, lo in problem.external.items() if not hasattr(lo, "bind_stress"))
            raise InputError(f"{name!r} is not an actuating load of the problem (loads: {actuating}); a contact's "
                             "factor places its obstacle and is not differentiated")
        comm = problem.V.mesh.comm
        if hasattr(load, "add_residual"):  # a cable: T ∂L/∂u at factor 1
            b = problem.u.vector.duplicate()
            b.set(0.0)
            load.add_residual(b, problem.u, 1.0, problem.model.finite_strain)
            n = problem.V.dofmap.index_map.size_local * problem.V.dofmap.index_map_bs
            local = float(np.dot(self._lam.x.array[:n], b.array[:n]))
            b.destroy()
            return -comm.allreduce(local)
        if name not in self._load_forms:
            if self._one is None:
                self._one = fem.Constant(problem.V.mesh, 1.0)
            term = load.residual(problem.u, self._lam, self._one, problem.model.finite_strain)
            self._load_forms[name] = fem.form(term)
        return -comm.allreduce(fem.assemble_scalar(self._load_forms[name]))

    def motion_gradient(self, name: str, dJdu: np.ndarray) -> float:
        """``j · w − λ · (J w)`` with ``w = ∂g/∂θ`` of the motion ``name`` at its current angle (per radian)."""
        problem = self.problem
        if any(hasattr(load, "add_jacobian") for load in problem.external.values()):
            raise InputError("motion gradients do not cover cable loads (a cable's tangent on prescribed nodes is "
                             "left out of the solver's matrix): remove the scene's cables, or differentiate with "
                             "respect to load factors only")
        motion = problem.motions[name]
        V = problem.V
        bs = V.dofmap.index_map_bs
        X = V.tabulate_dof_coordinates()[motion.dofs]
        self._w.x.array[:] = 0.0
        # only the components the motion prescribes move with its angle (a motion may leave some free)
        self._w.x.array.reshape(-1, bs)[motion.dofs] = (motion_direction(motion.motion, X, problem.loads.angles[name])
                                                        * motion.constrained())
        if self._action is None:
            self._action = fem.form(ufl.action(problem.jacobian_form, self._w))
        b = assemble_vector(self._action)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        n = V.dofmap.index_map.size_local * bs
        local = float(np.dot(dJdu, self._w.x.array[:n]) - np.dot(self._lam.x.array[:n], b.array[:n]))
        b.destroy()
        return V.mesh.comm.allreduce(local)

    # ----------------------------------------------------------------------------------------------
    def gradient(self, probe, fields: Mapping[str, fem.Function] | None = None,
                 motions: Sequence[str] = (), loads: Sequence[str] = ()) -> ProbeGradient:
        """Value and derivatives of ``probe`` with respect to DG0 coefficients and motion angles.

        Parameters
        ----------
        probe
            A probe with ``__call__(u)`` and ``gradient(u)`` (:mod:`fenicsfoam.probes`).
        fields
            ``{name: DG0 coefficient of the residual}``, e.g. the moduli and ``rho`` of the
            :class:`~fenicsfoam.constitutive.MaterialField` and the orientation field.
        motions
            Names of motions whose angle derivative is wanted.
        loads
            Names of external loads whose factor derivative is wanted (:meth:`load_gradient`).

        """
        u = self.problem.u
        if not hasattr(probe, "gradient"):
            raise InputError(f"probe {probe!r} has no gradient(u): its sensitivities are not available")
        dJdu = probe.gradient(u)
        self.solve(dJdu)
        result = ProbeGradient(float(probe(u)))
        for name, coefficient in (fields or {}).items():
            result.fields[name] = self.field_gradient(coefficient)
        for name in motions:
            if name not in self.problem.motions:
                raise InputError(f"{name!r} is not a motion of the problem (motions: {sorted(self.problem.motions)})")
            result.motions[name] = self.motion_gradient(name, dJdu)
        for name in loads:
            result.loads[name] = self.load_gradient(name)
        return result

    def destroy(self) -> None:
        """Free the PETSc objects."""
        for obj in (self._ksp, self._A, self._rhs, self._solution):
            if obj is not None:
                obj.destroy()


def material_coefficients(problem) -> dict[str, Any]:
    """The DG0 coefficients of a problem's residual: its moduli by name, ``rho`` and (if any) ``orientation``."""
    coefficients: dict[str, Any] = dict(problem.material.moduli)
    coefficients["rho"] = problem.material.rho
    if problem.orientation is not None:
        coefficients["orientation"] = problem.orientation
    return coefficients
