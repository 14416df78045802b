"""Quasi-static elasticity solved by PETSc SNES Newton, with load stepping and automatic cut-back.

The problem: find the displacement ``u`` with prescribed rigid motions on tagged regions such that

    ∫ P(u) : ∇v dX - ∫ ρ s g · v dX - Σ_l s_l ⟨f_l(u), v⟩ = 0   for all admissible v,

``P`` the first Piola–Kirchhoff stress of the model (:mod:`fenicsfoam.constitutive`), ``ρ`` the reference
density, ``g`` the gravity vector and ``s`` its load factor, ``f_l`` the external loads of
:mod:`fenicsfoam.loads` (tractions, follower pressures, cables), each with its own factor ``s_l``. Loads (the
gravity factor, the load factors, the angle and translation of every :class:`~fenicsfoam.bcs.RigidMotion`)
change from one :class:`LoadStep` to the next linearly in equal increments; a failed increment (SNES not
converged, or an inverted element) is halved, up to ``max_cutbacks`` times, and then :class:`ConvergenceError`
is raised with the last converged state kept in ``u``.

Residual and Jacobian are assembled from the UFL forms with ``dolfinx.fem.petsc``; Dirichlet conditions
enter the Newton correction by lifting (rows of constrained dofs read ``k (x - g)`` with the Jacobian
diagonal ``k``, the mean diagonal stiffness, so that residual norms are forces). All PETSc options live
under the problem's own prefix: :meth:`ElasticityProblem.default_options`, overridden by ``options=``,
overridden in turn by options already in the PETSc database (the command line).
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import basix
import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import (
    apply_lifting,
    assemble_matrix,
    assemble_vector,
    create_matrix,
    create_vector,
    set_bc,
)
from dolfinx.mesh import Mesh
from mpi4py import MPI
from petsc4py import PETSc

from fenicsfoam.bcs import MotionBC, RigidMotion
from fenicsfoam.constitutive import MaterialField, Model, as_model, deformation_gradient
from fenicsfoam.loads import Load
from fenicsfoam.stability import EllipticityCheck, ellipticity_margin
from foambase.errors import InputError, NotConvergedError
from foambase.nullspace import rigid_body_modes
from foambase.petsc_options import option_used

__all__ = ["ConvergenceError", "ElasticityProblem", "LoadState", "LoadStep", "StepStats", "rigid_body_modes"]

logger = logging.getLogger(__name__)

_SNES_REASONS = {getattr(PETSc.SNES.ConvergedReason, name): name for name in dir(PETSc.SNES.ConvergedReason)
                 if name.isupper() and name != "ITERATING"}


class ConvergenceError(NotConvergedError):
    """A load step failed after the maximum number of cut-backs; ``u`` keeps the last converged state.

    Attributes
    ----------
    step
        Label of the failed :class:`LoadStep`.
    load_factor
        Fraction of the step reached by the last converged increment, in [0, 1).
    reason
        Why the last attempt failed: the SNES converged reason (e.g. ``DIVERGED_LINE_SEARCH``) or
        ``inverted element (min det F = ...)``.
    ellipticity
        The strong-ellipticity check of the last converged state
        (:class:`fenicsfoam.stability.EllipticityCheck`), or ``None``. When ``ellipticity.lost``, the
        failure is a material instability (shear or kink bands, a mesh-dependent limit point), which no
        solver setting removes; the message says so.

    """

    def __init__(self, step: str, load_factor: float, reason: str, cutbacks: int,
                 ellipticity: EllipticityCheck | None = None):
        self.step, self.load_factor, self.reason, self.cutbacks = step, load_factor, reason, cutbacks
        self.ellipticity = ellipticity
        message = (f"load step {step!r} failed at load factor {load_factor:.6g} of the step after "
                   f"{cutbacks} cut-backs: {reason}; the last converged state is kept")
        if ellipticity is not None:
            message += f"; at that state: {ellipticity}"
            if ellipticity.lost:
                message += " (a material instability of the constitutive model, not a solver failure)"
        super().__init__(message)


@dataclass(frozen=True)
class LoadStep:
    """A labelled target load state, reached from the previous one in ``increments`` equal increments.

    Parameters
    ----------
    label
        Name of the step in statistics and errors (e.g. ``"rest"``, ``"middle"``).
    gravity
        Factor of the full gravity vector at the end of the step; ``None`` keeps the current factor.
    angles
        ``{motion name: angle}`` in radians at the end of the step; motions not listed keep theirs.
    translations
        ``{motion name: (tx, ty, tz)}`` in metres at the end of the step; motions not listed keep theirs.
    factors
        ``{load name: factor}`` of the external loads (:mod:`fenicsfoam.loads`) at the end of the step; loads not
        listed keep theirs.
    increments
        Initial number of equal increments (halved automatically on failure).

    """

    label: str
    gravity: float | None = None
    angles: Mapping[str, float] = field(default_factory=dict)
    translations: Mapping[str, Sequence[float]] = field(default_factory=dict)
    increments: int = 1
    factors: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self):
        if not (isinstance(self.increments, int) and self.increments >= 1):
            raise InputError(f"step {self.label!r}: increments must be an integer >= 1, got {self.increments!r}")


@dataclass
class StepStats:
    """What one load step cost and reached."""

    label: str
    newton_iterations: int = 0           #: summed over the converged increments
    increments: int = 0                  #: converged increments
    cutbacks: int = 0                    #: failed increments (each halved the increment)
    residuals: list[list[float]] = field(default_factory=list)  #: SNES residual norms, per converged increment
    reasons: list[str] = field(default_factory=list)            #: SNES converged reason, per converged increment
    min_det_F: float = float("nan")      #: smallest det F at quadrature points and vertices at the end
    wall_s: float = 0.0
    cpu_s: float = 0.0                   #: CPU time of this process (all its threads) during the step

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {"label": self.label, "newton_iterations": self.newton_iterations, "increments": self.increments,
                "cutbacks": self.cutbacks, "residuals": self.residuals, "reasons": self.reasons,
                "min_det_F": self.min_det_F, "wall_s": self.wall_s, "cpu_s": self.cpu_s}


@dataclass(frozen=True)
class LoadState:
    """Current load parameters: gravity factor, angle (rad) and translation (m) per motion, factor per load."""

    gravity: float
    angles: Mapping[str, float]
    translations: Mapping[str, np.ndarray]
    factors: Mapping[str, float] = field(default_factory=dict)

    def target(self, step: LoadStep) -> LoadState:
        """The state at the end of ``step``: its values where it gives them, the current ones elsewhere."""
        for name in (*step.angles, *step.translations):
            if name not in self.angles:
                raise InputError(f"step {step.label!r} moves {name!r}, which is not a motion of the problem "
                                 f"(motions: {sorted(self.angles)})")
        for name in step.factors:
            if name not in self.factors:
                raise InputError(f"step {step.label!r} sets the factor of {name!r}, which is not a load of the "
                                 f"problem (loads: {sorted(self.factors)})")
        return LoadState(gravity=self.gravity if step.gravity is None else float(step.gravity),
                      angles={**self.angles, **{k: float(v) for k, v in step.angles.items()}},
                      translations={**self.translations,
                                    **{k: np.asarray(v, dtype=float).reshape(3) for k, v in step.translations.items()}},
                      factors={**self.factors, **{k: float(v) for k, v in step.factors.items()}})

    def towards(self, other: LoadState, s: float) -> LoadState:
        """``(1 - s) self + s other``."""
        return LoadState(gravity=(1 - s) * self.gravity + s * other.gravity,
                      angles={k: (1 - s) * a + s * other.angles[k] for k, a in self.angles.items()},
                      translations={k: (1 - s) * t + s * other.translations[k] for k, t in self.translations.items()},
                      factors={k: (1 - s) * f + s * other.factors[k] for k, f in self.factors.items()})

    def __eq__(self, other) -> bool:
        return (self.gravity == other.gravity and self.angles == other.angles and self.factors == other.factors
                and all(np.array_equal(t, other.translations[k]) for k, t in self.translations.items()))


class ElasticityProblem:
    """Quasi-static (hyper)elasticity with gravity and prescribed rigid motions, solved by SNES Newton.

    Parameters
    ----------
    mesh
        The mesh (reference configuration, SI units).
    material
        Piecewise-constant material data (:class:`~fenicsfoam.constitutive.MaterialField`).
    orientation
        DG0 unit *l* axis per cell (:mod:`fenicsfoam.orientation`); required if some region is transversely
        isotropic, refused if all are isotropic (the isotropic form is used and no orientation is needed).
    model
        A :class:`~fenicsfoam.constitutive.Model` or its name in :data:`~fenicsfoam.constitutive.MODELS`
        (``"linear"``, ``"svk"``, ``"corotational"``, ``"bonet_burton"`` or ``"corotational_sofa"``); ``self.model`` is
        the model object.
    degree
        Lagrange degree of the displacement, 1 or 2.
    gravity
        Full gravity vector (m/s²); its factor starts at 0 and is set by :class:`LoadStep`.
    motions
        Prescribed rigid motions (clamps, servo horns), with distinct names; all start at rest.
    loads
        External loads (:mod:`fenicsfoam.loads`: tractions, forces, follower pressures, cables), with distinct
        names; every factor starts at 0. None: no load term is built.
    prefix
        PETSc options prefix of this problem's SNES (and its KSP, PC); must be non-empty and end with ``_``.
    options
        Overrides of :meth:`default_options` (keys without the prefix, e.g. ``{"snes_linesearch_type": "l2"}``).
    quadrature_degree
        Degree of the quadrature of the stress integral; default ``2 (degree - 1)`` (exact for the linear
        model; the corotational rotation field lives on these points).
    max_cutbacks
        How many times an increment may be halved below the step's initial increment before
        :class:`ConvergenceError`.

    """

    #: Default options added for a model whose assembled tangent is approximate (``Model.exact_tangent`` false:
    #: ``corotational_sofa``'s frozen-R tangent). Newton with that tangent alone converges linearly, at a rate that
    #: tends to 1 where the neglected rotation terms (of the order of the stress) outweigh a soft modulus (measured on
    #: the as-built Tripod: 0.93 per iteration, the rest pose not reached in 200 iterations per increment). So the
    #: Newton system is the exact Jacobian, applied matrix-free by finite differences of the residual
    #: (``snes_mf_operator``), solved by GMRES preconditioned by the LU factors of the assembled approximate tangent.
    APPROXIMATE_TANGENT_OPTIONS = {"snes_mf_operator": True, "ksp_type": "gmres", "ksp_rtol": 1e-6,
                                   "ksp_max_it": 200, "ksp_gmres_restart": 100, "snes_max_it": 60}

    #: Residual norms below this fraction of ``k ‖x‖`` count as converged (see ``_convergence_test``).
    _ROUNDOFF_FLOOR = 1e-13
    #: Seconds between two progress lines of one Krylov solve (:attr:`progress`).
    KRYLOV_REPORT_S = 2.0

    def __init__(self, mesh: Mesh, material: MaterialField, *, orientation: fem.Function | None = None,
                 model: str | Model = "corotational", degree: int = 1, gravity: Sequence[float] = (0.0, 0.0, -9.81),
                 motions: Sequence[RigidMotion] = (), loads: Sequence[Load] = (), prefix: str = "elasticity_",
                 options: Mapping[str, Any] | None = None, quadrature_degree: int | None = None,
                 max_cutbacks: int = 6):
        model = as_model(model)
        if degree not in (1, 2):
            raise InputError(f"degree must be 1 or 2, got {degree!r}")
        if material.isotropic and orientation is not None:
            raise InputError("every region is isotropic: pass orientation=None (no orientation field is needed)")
        if not material.isotropic and orientation is None:
            raise InputError("some region is transversely isotropic: an orientation field is required")
        names = [m.name for m in motions]
        if len(set(names)) != len(names):
            raise InputError(f"motion names must be distinct, got {names}")
        load_names = [load.name for load in loads]
        if len(set(load_names)) != len(load_names):
            raise InputError(f"load names must be distinct, got {load_names}")
        if not prefix or not prefix.endswith("_"):
            raise InputError(f"the options prefix must be non-empty and end with '_', got {prefix!r}")
        self.model, self.degree, self.max_cutbacks = model, degree, max_cutbacks
        self.material, self.orientation = material, orientation
        self.quadrature_degree = 2 * (degree - 1) if quadrature_degree is None else quadrature_degree
        self.V = fem.VectorFunctionSpace(mesh, ("CG", degree))
        self.u = fem.Function(self.V, name="displacement")
        self.rotation = model.rotation_field(self.u, self.quadrature_degree) if model.needs_rotation else None

        # Forms: one residual and its Jacobian; heterogeneity and loads are coefficient data.
        self._gravity = np.asarray(gravity, dtype=float).reshape(3)
        self._body_acceleration = fem.Constant(mesh, np.zeros(3))
        v, du = ufl.TestFunction(self.V), ufl.TrialFunction(self.V)
        #: first Piola–Kirchhoff stress of the model (UFL), e.g. for output
        self.stress = P = model.first_piola_kirchhoff(self.u, material, orientation, self.rotation)
        dx_stress = ufl.dx(metadata={"quadrature_degree": self.quadrature_degree})
        residual = (ufl.inner(P, ufl.grad(v)) * dx_stress
                    - material.rho * ufl.inner(self._body_acceleration, v) * ufl.dx)
        #: the external loads by name, and their current factors (UFL loads: a Constant each)
        self.external = {load.name: load for load in loads}
        self._factors = {}
        for load in loads:
            load.setup(self.V)
            if hasattr(load, "bind_stress"):  # contact (Nitsche): the body's traction on its facets
                load.bind_stress(model, material, orientation)
            self._factors[load.name] = factor = fem.Constant(mesh, 0.0)
            term = load.residual(self.u, v, factor, model.finite_strain)
            if term is not None:
                residual += term
        self._cables = [load for load in loads if hasattr(load, "add_jacobian")]
        self._residual = fem.form(residual)
        jacobian = ufl.derivative(residual, self.u, du)
        dP = model.rotation_tangent(self.u, du, material, orientation, self.rotation)
        if dP is not None:  # exact tangent: add the change of R with u
            jacobian += ufl.inner(dP, ufl.grad(v)) * dx_stress
        self._jacobian = fem.form(jacobian)
        #: the UFL residual form (test function ``v``) and its exact Jacobian (trial function ``du``; with the
        #: rotation term of the corotational model), unconstrained: what sensitivities differentiate
        self.residual_form, self.jacobian_form = residual, jacobian
        self._det_F = fem.Expression(ufl.det(deformation_gradient(self.u)), self._inversion_points(mesh))

        self.motions = {m.name: MotionBC(self.V, m) for m in motions}
        self._bcs = [bc for m in self.motions.values() for bc in m.bcs]
        #: the current load state (gravity factor, motion angles and translations); all zero at the start
        self.loads = LoadState(gravity=0.0, angles=dict.fromkeys(names, 0.0),
                               translations={n: np.zeros(3) for n in names}, factors=dict.fromkeys(load_names, 0.0))

        self._b = create_vector(self._residual)
        self._x = self.u.vector.duplicate()  # SNES iterate: never u's own storage, which trial points overwrite
        self._synced = (None, None)  # (handle, state) of the vector last copied into u
        self._given_options = [prefix + key for key in (options or {}) if key != "mat_type"]
        self._used_options: set[str] = set()
        defaults = self.default_options()
        if not model.exact_tangent:
            defaults.update(self.APPROXIMATE_TANGENT_OPTIONS)
        options = {**defaults, **(options or {})}
        db = PETSc.Options()
        # Options already in the database (the command line) win over ours.
        self._options = {prefix + key: value for key, value in options.items() if not db.hasName(prefix + key)}
        if self._cables:  # a cable couples the nodes of its via points: entries outside the form's pattern
            nodes, components = self._constrained_global_nodes()
            for cable in self._cables:
                cable.set_constrained(nodes, components)
            self._A = self._create_matrix_with_cables(self._matrix_type(prefix))
        else:
            self._A = create_matrix(self._jacobian, self._matrix_type(prefix))
        self._A.setNearNullSpace(rigid_body_modes(self.V))
        self._bc_scale = self._mean_diagonal_stiffness()
        #: called with a line of progress at every Newton iteration (and every few seconds of a Krylov solve), e.g.
        #: ``step gravity, load factor 0.5: Newton iteration 2, residual 1.234e-05``; None: silent
        self.progress: Callable[[str], None] | None = None
        self._where: tuple[str, float, int] = ("", 0.0, 0)  # step label, load factor tried, Newton iteration
        self._krylov_reported = 0.0
        self._snes = self._create_snes(prefix)
        #: accumulated wall time (s) of residual and Jacobian evaluations (assembly + rotation updates)
        self.timings = {"residual": 0.0, "jacobian": 0.0}

    # ----------------------------------------------------------------------------------------------
    @staticmethod
    def default_options() -> dict[str, Any]:
        """Default PETSc options (keys without the prefix): full Newton steps, MUMPS LU.

        * ``snes_linesearch_type basic``: full Newton steps, globalised by the load-step cut-back. Measured on
          large rotations of a slender beam (README): ``bt`` fails (a good Newton step raises the residual
          norm by orders of magnitude through transient membrane forces, and backtracking on that norm then
          stalls), ``l2`` converges with 1.5–4× more iterations, ``cp`` is slower still.
        * ``snes_rtol`` is relative to the residual at the start of each increment; an increment also
          converges once the residual is at the round-off floor (``1e-13 k ‖x‖``, see ``_convergence_test``)
          or the Newton correction is below ``snes_stol`` of the solution.
        * ``mat_type`` (read by this class, not by PETSc): ``None`` picks ``baij`` (3×3 blocks, half the
          assembly time of ``aij``) for direct solvers and ``aij`` otherwise (GAMG needs it).
        * The iterative alternative: ``{"ksp_type": "cg", "pc_type": "gamg", "ksp_rtol": 1e-8}`` (``gmres`` for
          the corotational model, whose exact tangent is not symmetric); the rigid-body near-nullspace is always
          attached to the Jacobian. Measured, it is slower than LU at every size but needs far less memory: scenes
          take it when LU would not fit (:mod:`fenicsfoam.sizing`, ``bench/bench_large_runs.py``).
        """
        return {
            "snes_type": "newtonls",
            "snes_linesearch_type": "basic",
            "snes_rtol": 1e-10,
            "snes_stol": 1e-12,
            "snes_max_it": 25,
            "ksp_type": "preonly",
            "pc_type": "lu",
            "pc_factor_mat_solver_type": "mumps",
            "mat_type": None,
        }

    def _option(self, prefix: str, key: str) -> str | None:
        """The effective value of an option (the database first), as a string; ``None`` if unset."""
        db = PETSc.Options()
        if db.hasName(prefix + key):
            return db.getString(prefix + key)
        value = self._options.get(prefix + key)
        return None if value is None else str(value)

    def _matrix_type(self, prefix: str) -> str:
        """``mat_type`` (ours, not a PETSc option of the SNES), else baij for direct solvers, aij otherwise."""
        matrix_type = self._option(prefix, "mat_type")
        self._options.pop(prefix + "mat_type", None)  # never passed to PETSc
        if matrix_type is None:
            matrix_type = "baij" if self._option(prefix, "pc_type") in ("lu", "cholesky") else "aij"
        return matrix_type

    def _create_snes(self, prefix: str) -> PETSc.SNES:
        snes = PETSc.SNES().create(self.V.mesh.comm)
        snes.setOptionsPrefix(prefix)
        snes.setFunction(self._residual_callback, self._b)
        snes.setJacobian(self._jacobian_callback, self._A)
        with self._options_set():
            snes.setFromOptions()
        snes.setConvergenceHistory(reset=True)
        snes.setConvergenceTest(self._convergence_test)
        # Python monitors: progress, and a point where Python runs (and a SIGINT/SIGTERM handler with it) at every
        # Newton and Krylov iteration, so that an interruption stops a long iterative solve within one iteration.
        snes.setMonitor(self._newton_monitor)
        snes.getKSP().setMonitor(self._krylov_monitor)
        return snes

    def _newton_monitor(self, snes: PETSc.SNES, iteration: int, fnorm: float) -> None:
        label, s, _ = self._where
        self._where = (label, s, iteration)
        self._krylov_reported = time.monotonic()
        if self.progress is not None:
            self.progress(f"step {label}, load factor {s:.4g}: Newton iteration {iteration}, residual {fnorm:.4e}")

    def _krylov_monitor(self, ksp: PETSc.KSP, iteration: int, rnorm: float) -> None:
        now = time.monotonic()
        if self.progress is not None and iteration > 0 and now - self._krylov_reported >= self.KRYLOV_REPORT_S:
            self._krylov_reported = now
            label, s, newton = self._where
            self.progress(f"step {label}, load factor {s:.4g}: Newton iteration {newton}, linear iteration "
                          f"{iteration}, linear residual {rnorm:.3e}")

    def _convergence_test(self, snes: PETSc.SNES, it: int, norms: tuple[float, float, float]) -> int:
        """PETSc's default test, with a round-off floor: converged when ``‖F‖ <= 1e-13 k ‖x‖``.

        ``k ‖x‖`` (mean diagonal stiffness × norm of the iterate) is the scale of the internal forces, whose
        assembly round-off (~1e-16 of it) no Newton iteration can go below; without this floor a small load
        increment would never meet ``snes_rtol`` relative to its small initial residual.
        """
        xnorm, snorm, fnorm = norms
        reasons = PETSc.SNES.ConvergedReason
        rtol, atol, stol, max_it = snes.getTolerances()
        if it == 0:
            self._initial_fnorm = fnorm
        if not np.isfinite(fnorm):
            return reasons.DIVERGED_FNORM_NAN
        if fnorm <= max(atol, self._ROUNDOFF_FLOOR * self._bc_scale * xnorm):
            return reasons.CONVERGED_FNORM_ABS
        if it > 0 and fnorm <= rtol * self._initial_fnorm:
            return reasons.CONVERGED_FNORM_RELATIVE
        if it > 0 and snorm <= stol * xnorm:
            return reasons.CONVERGED_SNORM_RELATIVE
        if it >= max_it:
            return reasons.DIVERGED_MAX_IT
        return reasons.CONVERGED_ITERATING

    @contextlib.contextmanager
    def _options_set(self):
        """Our options in the PETSc database while PETSc reads them, removed afterwards.

        They stay during solves too: some are only read when first used (MUMPS ``mat_mumps_*`` at the first
        factorization, GAMG level smoothers at set-up).
        """
        db = PETSc.Options()
        for key, value in self._options.items():
            db[key] = value
        try:
            yield
        finally:
            for key in self._options:
                if option_used(key):
                    self._used_options.add(key)
                db.delValue(key)

    def unused_options(self) -> list[str]:
        """The ``options=`` given to this problem (keys without prefix) that PETSc has not read so far.

        Options of the solver itself are read when it is configured; some only when it is set up or a solve ends
        (:func:`foambase.petsc_options.deferred`), so ask after a solve. Options given on the command line
        override ours and are not ours to report.
        """
        command_line = PETSc.Options().getAll()  # (hasName would mark them used)
        return [key[len(self._snes.getOptionsPrefix()):] for key in self._given_options
                if key not in self._used_options and key not in command_line]

    @staticmethod
    def _inversion_points(mesh: Mesh) -> np.ndarray:
        """Reference points where det F is checked: the quadrature points of degree 2 and the vertices."""
        cell = basix.cell.string_to_type(mesh.topology.cell_name())
        return np.vstack([basix.make_quadrature(cell, 2)[0], basix.geometry(cell)])

    def _mean_diagonal_stiffness(self) -> float:
        """Mean diagonal of the unconstrained Jacobian at rest: the diagonal of constrained rows."""
        self._assemble_jacobian(self._A, [], 1.0)
        diagonal = self._A.getDiagonal()
        return diagonal.norm(PETSc.NormType.NORM_1) / diagonal.getSize()

    # ----------------------------------------------------------------------------------------------
    def _sync(self, x: PETSc.Vec) -> None:
        """Copy the SNES iterate into ``u`` (with ghosts) and update what depends on it.

        Skipped when ``x`` is the SNES solution vector, unchanged since it was last copied (the Jacobian
        is evaluated at the point of the last residual).
        """
        synced = (x.handle, x.stateGet())
        if x.handle == self._x.handle and synced == self._synced:
            return
        self._synced = synced
        x.copy(self.u.vector)
        self.u.vector.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        if self.rotation is not None:
            self.rotation.update()

    def _constrained_global_nodes(self) -> tuple[np.ndarray, np.ndarray]:
        """Global numbers of the nodes a motion prescribes and which of their components (on every rank)."""
        index_map = self.V.dofmap.index_map
        n_owned = index_map.size_local
        masks: dict[int, np.ndarray] = {}
        for motion in self.motions.values():
            owned = motion.dofs < n_owned
            numbers = index_map.local_to_global(motion.dofs[owned].astype(np.int32))
            for number, mask in zip(numbers.tolist(), motion.constrained()[owned]):
                masks[number] = masks.get(number, np.zeros(3, dtype=bool)) | mask
        gathered = {k: v for part in self.V.mesh.comm.allgather(masks) for k, v in part.items()}
        nodes = np.array(sorted(gathered), dtype=np.int64)
        return nodes, np.array([gathered[n] for n in nodes.tolist()], dtype=bool).reshape(-1, 3)

    def _create_matrix_with_cables(self, matrix_type: str) -> PETSc.Mat:
        """The Jacobian's matrix, preallocated for the form's sparsity pattern and the cables' couplings.

        As ``dolfinx.fem.petsc.create_matrix`` (block size 3, the dofmap's local-to-global map), with every row of a
        cable's via nodes also holding the nodes it couples to (possibly on other ranks), so that no insertion
        reallocates the matrix.
        """
        index_map = self.V.dofmap.index_map
        n_owned, bs = index_map.size_local, self.V.dofmap.index_map_bs
        pattern = fem.create_sparsity_pattern(self._jacobian)
        pattern.assemble()
        graph = pattern.graph
        offsets, columns = graph.offsets, graph.array
        column_map = pattern.column_index_map()  # the dofmap's ghosts and the pattern's extra ones
        column_to_global = column_map.local_to_global(np.arange(column_map.size_local + column_map.num_ghosts,
                                                                dtype=np.int32))
        local_to_global = index_map.local_to_global(np.arange(n_owned + index_map.num_ghosts, dtype=np.int32))
        columns_of = {}  # owned row → the global columns of the form's pattern, for rows the cables touch
        extra: dict[int, set] = {}
        for cable in self._cables:
            for row, cols in cable.coupling().items():
                extra.setdefault(row, set()).update(cols.tolist())
        lo = index_map.local_range[0]
        d_nnz = np.diff(offsets)[:n_owned].astype(PETSc.IntType)
        in_diag = (columns < n_owned).astype(np.int64)
        d_counts = np.add.reduceat(in_diag, offsets[:-1])[:n_owned] if columns.size else np.zeros(n_owned, int)
        o_nnz = (d_nnz - d_counts).astype(PETSc.IntType)
        d_nnz = d_counts.astype(PETSc.IntType)
        hi = lo + n_owned
        for row, cols in extra.items():
            local = row - lo
            columns_of[local] = set(column_to_global[columns[offsets[local]:offsets[local + 1]]].tolist())
            new = np.array(sorted(cols - columns_of[local]), dtype=np.int64)
            d_nnz[local] += int(np.count_nonzero((new >= lo) & (new < hi)))
            o_nnz[local] += int(np.count_nonzero((new < lo) | (new >= hi)))
        A = PETSc.Mat().create(self.V.mesh.comm)
        A.setSizes(((n_owned * bs, index_map.size_global * bs),) * 2, bsize=bs)
        A.setType(matrix_type)
        if matrix_type.endswith("baij"):
            A.setPreallocationNNZ((d_nnz, o_nnz))
        else:
            A.setPreallocationNNZ((np.repeat(bs * d_nnz, bs), np.repeat(bs * o_nnz, bs)))
        lgmap = PETSc.LGMap().create(local_to_global.astype(PETSc.IntType), bsize=bs, comm=self.V.mesh.comm)
        A.setLGMap(lgmap, lgmap)
        A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        return A

    def _add_cables(self, b: PETSc.Vec) -> None:
        for cable in self._cables:
            cable.add_residual(b, self.u, self.loads_now[cable.name], self.model.finite_strain)

    def _residual_callback(self, snes: PETSc.SNES, x: PETSc.Vec, b: PETSc.Vec) -> None:
        t0 = time.perf_counter()
        self._sync(x)
        with b.localForm() as b_local:
            b_local.set(0.0)
        assemble_vector(b, self._residual)
        # Lifting reads the iterate's ghost entries: use u's vector, whose ghosts _sync updated (x's are stale).
        apply_lifting(b, [self._jacobian], bcs=[self._bcs], x0=[self.u.vector], scale=-1.0)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self._add_cables(b)
        set_bc(b, self._bcs, self.u.vector, -self._bc_scale)
        self.timings["residual"] += time.perf_counter() - t0

    def _jacobian_callback(self, snes: PETSc.SNES, x: PETSc.Vec, A: PETSc.Mat, P: PETSc.Mat) -> None:
        t0 = time.perf_counter()
        self._sync(x)
        self._assemble_jacobian(P, self._bcs, self._bc_scale)
        if A.handle != P.handle:  # a matrix-free operator (snes_mf_operator): the assembled tangent preconditions it
            A.assemble()
        self.timings["jacobian"] += time.perf_counter() - t0

    def _assemble_jacobian(self, A: PETSc.Mat, bcs, diagonal: float) -> None:
        A.zeroEntries()
        assemble_matrix(A, self._jacobian, bcs=bcs, diagonal=diagonal)
        if self._cables:
            A.assemblyBegin(PETSc.Mat.AssemblyType.FLUSH)
            A.assemblyEnd(PETSc.Mat.AssemblyType.FLUSH)
            for cable in self._cables:
                cable.add_jacobian(A, self.u, self.loads_now[cable.name], self.model.finite_strain)
        A.assemble()

    def internal_minus_external(self) -> PETSc.Vec:
        """The assembled ``R(u)`` = internal − external nodal forces at the current ``u`` and loads, no Dirichlet rows.

        At a converged state its entries at prescribed nodes are the reactions (the forces the supports exert on
        the body); elsewhere they vanish to the solver's tolerance. Owned entries are valid (collective).
        """
        b = create_vector(self._residual)
        with b.localForm() as b_local:
            b_local.set(0.0)
        assemble_vector(b, self._residual)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        self._add_cables(b)
        return b

    # ----------------------------------------------------------------------------------------------
    @property
    def snes(self) -> PETSc.SNES:
        """The SNES solver (options prefix as given to the constructor)."""
        return self._snes

    @property
    def bcs(self) -> list[fem.DirichletBCMetaClass]:
        """The Dirichlet conditions of the motions, at their current values."""
        return list(self._bcs)

    def assemble_tangent(self, A: PETSc.Mat | None = None) -> PETSc.Mat:
        """The exact Jacobian of the residual at the current ``u``, constrained rows and columns made identity.

        ``[[J_ff, 0], [0, I]]`` (``f``: free dofs): the matrix of the Newton correction at a state that meets
        the Dirichlet conditions, and of the adjoint equations (:mod:`fenicsfoam.sensitivity`). The rotation
        field is updated from ``u`` first. ``A`` is reused if given (the pattern of :meth:`snes`'s matrix).
        """
        if A is None:  # the solver's pattern (a cable's couplings included)
            A = self._A.duplicate()
        self.u.x.scatter_forward()
        if self.rotation is not None:
            self.rotation.update()
        self._assemble_jacobian(A, self._bcs, 1.0)
        return A

    def snapshot(self) -> tuple[np.ndarray, LoadState]:
        """The current state: a copy of ``u``'s local values (owned and ghost) and the load state."""
        return self.u.x.array.copy(), self.loads

    def restore(self, state: tuple[np.ndarray, LoadState]) -> None:
        """Go back to a state of :meth:`snapshot` (of this problem, on this rank)."""
        values, loads = state
        self.u.x.array[:] = values
        self.loads = loads
        self._apply_loads(loads)
        self._synced = (None, None)
        if self.rotation is not None:
            self.rotation.update()

    def reset(self) -> None:
        """Back to the reference state: ``u = 0``, every load zero (gravity, angles, translations, load factors)."""
        self.u.x.array[:] = 0.0
        self.loads = LoadState(gravity=0.0, angles=dict.fromkeys(self.motions, 0.0),
                               translations={n: np.zeros(3) for n in self.motions},
                               factors=dict.fromkeys(self.external, 0.0))
        self._apply_loads(self.loads)
        self._synced = (None, None)
        if self.rotation is not None:
            self.rotation.update()

    def min_det_F(self) -> float:
        """Smallest ``det F`` over quadrature points and vertices of all cells (collective)."""
        mesh = self.V.mesh
        cells = np.arange(mesh.topology.index_map(mesh.topology.dim).size_local, dtype=np.int32)
        local = np.array([self._det_F.eval(cells).min(initial=np.inf)])
        result = np.empty(1)
        mesh.comm.Allreduce(local, result, op=MPI.MIN)
        return float(result[0])

    @property
    def loads_now(self) -> Mapping[str, float]:
        """The factor of every external load as applied now (during a solve: the increment being tried)."""
        return {name: float(c.value) for name, c in self._factors.items()}

    def _apply_loads(self, loads: LoadState) -> None:
        self._body_acceleration.value[:] = loads.gravity * self._gravity
        for name, motion in self.motions.items():
            motion.set(loads.angles[name], loads.translations[name])
        for name, factor in self._factors.items():
            factor.value = loads.factors[name]

    def _newton(self) -> tuple[bool, str, int, np.ndarray]:
        """One SNES solve from the current ``u``: (success, reason, iterations, residual history)."""
        snes = self._snes
        self.u.vector.copy(self._x)
        with self._options_set():
            snes.solve(None, self._x)
        self._sync(self._x)
        reason = snes.getConvergedReason()
        if snes.getKSP().getConvergedReason() == PETSc.KSP.ConvergedReason.DIVERGED_PCSETUP_FAILED:
            # A failed factorization (e.g. MUMPS out of workspace on a wild iterate) would be kept and fail every
            # later solve, the cut-back's smaller increments included: the next attempt factors afresh.
            snes.getKSP().reset()
        history = snes.getConvergenceHistory()[0].copy()
        name = _SNES_REASONS.get(reason, str(reason))
        if reason > 0 and self.model.finite_strain:
            det = self.min_det_F()
            if not det > 0.0:
                return False, f"inverted element (min det F = {det:.3g})", snes.getIterationNumber(), history
        return reason > 0, name, snes.getIterationNumber(), history

    def solve_step(self, step: LoadStep) -> StepStats:
        """Move the loads from their current values to those of ``step`` by increments, with cut-back.

        Raises
        ------
        ConvergenceError
            When an increment fails after ``max_cutbacks`` halvings; ``u`` and the loads are left at the
            last converged state.

        """
        t0, cpu0 = time.perf_counter(), time.process_time()
        stats = StepStats(step.label)
        start = self.loads
        target = start.target(step)
        ds_initial = 1.0 / step.increments
        ds_min = ds_initial / 2**self.max_cutbacks
        s, ds = 0.0, ds_initial
        converged_u = self.u.vector.copy()
        while target != start and s < 1.0:
            s_try = 1.0 if s + ds > 1.0 - 1e-12 else s + ds
            self._where = (step.label, s_try, 0)
            self._apply_loads(start.towards(target, s_try))
            ok, reason, iterations, history = self._newton()
            logger.info("step %s, load factor %.4g: %s after %d Newton iterations",
                        step.label, s_try, reason, iterations)
            if ok:
                s = s_try
                self.u.vector.copy(converged_u)
                stats.newton_iterations += iterations
                stats.increments += 1
                stats.residuals.append(history.tolist())
                stats.reasons.append(reason)
                ds = min(2.0 * ds, ds_initial)
                continue
            converged_u.copy(self.u.vector)
            self.u.x.scatter_forward()
            stats.cutbacks += 1
            ds *= 0.5
            if ds < ds_min * (1 - 1e-12):
                self.loads = start.towards(target, s)
                self._apply_loads(self.loads)
                raise ConvergenceError(step.label, s, reason, stats.cutbacks, self.ellipticity_margin())
        self.loads = target
        self._apply_loads(target)
        if self.rotation is not None:
            self.rotation.update()
        stats.min_det_F = self.min_det_F()
        stats.wall_s = time.perf_counter() - t0
        stats.cpu_s = time.process_time() - cpu0
        return stats

    def ellipticity_margin(self, directions: int = 256, refinements: int = 10) -> EllipticityCheck:
        """Strong-ellipticity check of the current displacement (:func:`fenicsfoam.stability.ellipticity_margin`).

        Evaluated by the solver only when a step fails (at the last converged state); collective.
        """
        return ellipticity_margin(self.u, self.model, self.material, self.orientation, rotation=self.rotation,
                                  quadrature_degree=self.quadrature_degree, directions=directions,
                                  refinements=refinements)

    def run(self, steps: Sequence[LoadStep]) -> list[StepStats]:
        """Solve the load steps in order; returns the statistics of each."""
        return [self.solve_step(step) for step in steps]
