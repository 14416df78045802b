"""Inverse actuation: the servo angles or load factors of the last step that bring probes to target values.

Any scene: the unknowns are servo angles (deg) and the factors of named forces, tractions, pressures and cables at
the scene's last step, each within bounds; the targets are scalar probes or components of vector probes
(``tip_deflection``, ``displacement:GROUP[i]`` in m, ``contact_force:NAME[i]`` in N, and the Tripod's below), at
most as many as unknowns. The method below is written for the Tripod's servos θ, its default unknowns; with other
unknowns θ stands for their values (servo angles in deg, load factors dimensionless) and the weights ``W`` are 1/mm,
1/deg and 1/mN by the target's unit. ``control.json`` names the unknowns and their bounds (``unknowns``,
``bounds``, ``initial``).

Tripod:

Given targets for up to three of the centre's probes (``center_height`` in m, ``center_rotation``,
``center_tilt_x``, ``center_tilt_y`` in degrees), :func:`control_servos` finds the servo angles θ of the scene's
last step (earlier steps applied as written; the last step's angles are the initial guess θ⁰) within the servos'
range ``[lo, hi]``:

* with as many targets as servos, the solution of ``f(θ) = t``;
* with fewer, the solution of least servo motion, ``min |θ − θ⁰|² subject to f(θ) = t``;
* if no angle in the range reaches the target, :class:`UnreachableTargetError` (exit status 3) carrying the
  closest reachable pose, the minimiser of ``|W (f(θ) − t)|²`` over the range (``W`` = 1/mm for heights, 1/deg for
  angles).

Method, with exact derivatives ``G = ∂f/∂θ`` of the targets (one adjoint solve per target,
:mod:`fenicsfoam.sensitivity`) and ``W`` the weights above:

1. *Restoration* (Newton onto the targets): from θ the least-norm step ``min |δ|² subject to
   f + G δ = t, lo ≤ θ + δ ≤ hi`` (an exact small QP: every face of the box is solved as an equality-constrained
   problem, :func:`qp_step`), backtracked (halved) until ``½ |W (f − t)|²`` decreases and the forward solve
   converges. Quadratic convergence near a solution; with three targets this is the whole method. If the
   linearised targets are out of the box, the step goes to the bounded least-squares point
   (``scipy.optimize.lsq_linear``) instead (Gauss–Newton towards the closest pose); where that is stationary
   (projected gradient zero) or no step decreases the misfit, the targets are out of reach:
   :class:`UnreachableTargetError`.
2. *Least motion* (fewer targets than servos): at a point that meets the targets, the KKT residual — the step
   ``argmin ½|δ|² + (θ − θ⁰)ᵀδ`` subject to ``G δ = 0`` and the box, i.e. ``−Z Zᵀ(θ − θ⁰)`` (``Z`` an orthonormal
   basis of the null space of ``G``, the level set's tangent) where no bound is active — vanishes at the
   least-motion solution. Otherwise a quasi-Newton step along the tangent within the box (the same QP with the
   metric ``Z H Zᵀ + Y Yᵀ``, i.e. ``−Z H⁻¹ Zᵀ(θ − θ⁰)`` where no bound is active; ``H`` the reduced Hessian of
   ``½|θ − θ⁰|²`` on the level set by damped BFGS from successive reduced gradients, lengthened while the level
   set shows no positive curvature, at most 10°), then restoration; accepted if the motion decreased, else
   halved. The motion compared is that of the nearest point of the linearised level set,
   ``|θ − G⁺W(f − t) − θ⁰|``: θ meets the targets only within their tolerance, up to ``|G⁺ W tol|`` off the level
   set, which changes ``|θ − θ⁰|`` to first order by more than a short tangent step gains (the comparison would
   then reject good steps at random), while the corrected motion is off by its square. Converged when the KKT
   residual is below ``max(1e-5, |G⁺ W tol|_∞)`` (in the unknowns' units: the targets' tolerance resolves the
   tangent no finer); a step that finds no shorter motion before that is :class:`NotConvergedError`, as is
   running out of iterations (``max_iterations``). ``ControlResult.kkt_residual`` is the residual at the result.
3. *Symmetric poses*: at equal angles of a D3-symmetric plate the targets' gradients can be parallel (height and
   twist of case B), so no first-order step meets both; the iteration then steps 1° along a fixed direction
   (``(1, 0, −1)`` made orthogonal to the gradients; fixed, so that serial and MPI runs take the same path) and
   goes on (at most three times).

Targets are met within their tolerance (default 1e-9 m, 1e-7 deg). ``iterations`` counts the steps taken (each a
forward solve), ``scene_solves`` every forward solve, backtracked ones included.

Each forward solve moves the last step's angles from the previous equilibrium (:meth:`SceneDesign.solve_last`);
``scene_solves`` counts them, the first being the whole schedule.
"""

from __future__ import annotations

import argparse
import itertools
import logging
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from foambase import cli
from foambase.errors import InputError, NotConvergedError

__all__ = ["CONTROL", "TARGET_PROBES", "ControlResult", "InverseController", "UnreachableTargetError",
           "control_servos", "parse_targets", "parse_unknowns", "target_unit"]

logger = logging.getLogger(__name__)

#: The probes a target may name, with their units (and the scale of the misfit weight W, in those units).
TARGET_PROBES: dict[str, tuple[str, float]] = {
    "center_height": ("m", 1e-3),
    "center_rotation": ("deg", 1.0),
    "center_tilt_x": ("deg", 1.0),
    "center_tilt_y": ("deg", 1.0),
}
#: Default tolerance of a target, by unit.
TOLERANCES: dict[str, float] = {"m": 1e-9, "deg": 1e-7, "N": 1e-9}
#: The scale of a target's misfit weight W by unit (1 mm, 1 degree, 1 mN).
UNIT_SCALES: dict[str, float] = {"m": 1e-3, "deg": 1.0, "N": 1e-3}
#: Scalar probes of any scene that a target may name (besides the Tripod's and ``KIND:GROUP[i]`` components).
SCALAR_TARGETS: dict[str, str] = {"tip_deflection": "m"}
#: Units of the components ``KIND:GROUP[i]`` a target may name.
COMPONENT_UNITS: dict[str, str] = {"displacement": "m", "contact_force": "N"}
#: Default servo range (deg): the paper's poses are 0° (rest), 19° (middle), 38° (top); a modelling choice with margin.
SERVO_RANGE: tuple[float, float] = (-20.0, 60.0)
_MOTION_TOL = 1e-5   # deg: the least-motion KKT residual's tolerance (or the targets' resolution, if coarser)
_STALL_TOL = 1e-9    # deg: a step this small with the targets unmet means the iteration is stationary
_RANK_TOL = 1e-7     # the targets' gradients are rank deficient when σ_min <= _RANK_TOL σ_max
_ESCAPE_DEG = 1.0    # deg: the step that leaves a rank-deficient (symmetric) pose
_MAX_ESCAPES = 3
_MAX_TANGENT_DEG = 10.0  # deg: the longest least-motion step
#: Fixed directions that leave a symmetric pose (the first not parallel to the gradients' row space is used).
_ESCAPE_DIRECTIONS = (np.array([1.0, 0.0, -1.0]), np.array([0.0, 1.0, -1.0]), np.array([1.0, -1.0, 0.0]))


@dataclass
class ControlResult:
    """What :func:`control_servos` found (``control.json``)."""

    servo_deg: list[float]
    target: dict[str, float]
    achieved: dict[str, float]
    iterations: int
    scene_solves: int
    reached: bool = True
    servo_range: tuple[float, float] = SERVO_RANGE
    initial_deg: list[float] = field(default_factory=list)
    history: list[dict[str, Any]] = field(default_factory=list)
    #: the unknowns solved for and their values (servo angles in deg, load factors), their bounds and initial values
    unknowns: dict[str, float] = field(default_factory=dict)
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    initial: dict[str, float] = field(default_factory=dict)
    #: with fewer targets than unknowns, the least-motion KKT residual at the result (unknowns' units; None otherwise)
    kkt_residual: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict: ``servo_deg, target, achieved, iterations, scene_solves`` first."""
        return asdict(self)

    def write(self, out_dir: str | os.PathLike, comm=None) -> Path:
        """``out_dir/control.json``, written atomically on rank 0; returns its path."""
        from mpi4py import MPI

        from foambase.files import write_json_atomic
        comm = MPI.COMM_WORLD if comm is None else comm
        path = Path(out_dir) / "control.json"
        if comm.rank == 0:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_json_atomic(path, self.to_dict())
        comm.Barrier()
        return path


class UnreachableTargetError(NotConvergedError):
    """No servo angles within the range reach the target; ``closest`` is the closest reachable pose.

    Attributes
    ----------
    closest
        A :class:`ControlResult` with ``reached = False``: the angles and probes of the closest pose found.

    """

    def __init__(self, message: str, closest: ControlResult):
        self.closest = closest
        super().__init__(message)


def parse_targets(items: Sequence[str]) -> dict[str, float]:
    """``["center_height=0.02", ...]`` → ``{"center_height": 0.02}``; :class:`InputError` naming a bad item."""
    targets: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep:
            raise InputError(f"target {item!r}: expected NAME=VALUE, e.g. center_height=0.02")
        try:
            number = float(value)
        except ValueError:
            raise InputError(f"target {item!r}: {value!r} is not a number") from None
        if name in targets:
            raise InputError(f"target {name!r} is given twice")
        targets[name] = number
    return targets


def target_unit(name: str) -> str | None:
    """The unit of a target probe name (``center_height``, ``tip_deflection``, ``KIND:GROUP[i]``), or None."""
    if name in TARGET_PROBES:
        return TARGET_PROBES[name][0]
    if name in SCALAR_TARGETS:
        return SCALAR_TARGETS[name]
    kind, _, rest = name.partition(":")
    group, bracket, index = rest.partition("[")
    if kind in COMPONENT_UNITS and group and bracket and index in ("0]", "1]", "2]"):
        return COMPONENT_UNITS[kind]
    return None


def _check_targets(targets: Mapping[str, float], n_unknowns: int, what: str = "servos") -> dict[str, float]:
    valid = (f"{', '.join([*TARGET_PROBES, *SCALAR_TARGETS])}, or a component KIND:GROUP[i] with KIND in "
             f"{', '.join(COMPONENT_UNITS)} (e.g. displacement:tip[2], contact_force:ball[2])")
    if not targets:
        raise InputError(f"give at least one target ({valid})")
    for name, value in targets.items():
        if target_unit(name) is None:
            raise InputError(f"unknown target {name!r}; valid: {valid} (lengths in m, angles in degrees, forces "
                             "in N)")
        if not math.isfinite(value):
            raise InputError(f"target {name} = {value!r}: expected a finite number")
    if len(targets) > n_unknowns:
        raise InputError(f"{len(targets)} targets for {n_unknowns} {what}: give at most {n_unknowns}")
    return {k: float(v) for k, v in targets.items()}


def _check_target_groups(targets: Mapping[str, float], scene) -> None:
    """Refuse a target whose probe the scene cannot build (before anything is built)."""
    for name in targets:
        if name in TARGET_PROBES and scene.builder != "tripod":
            raise InputError(f"target {name!r} needs the tripod builder, the scene uses {scene.builder!r}")
        if name == "tip_deflection" and ("tip" not in scene.facets or scene.gravity is None):
            raise InputError("target 'tip_deflection' needs a facet group named 'tip' and loads.gravity")
        kind, _, rest = name.partition(":")
        group = rest.partition("[")[0]
        if kind == "displacement" and group not in scene.facets:
            raise InputError(f"target {name!r}: unknown facet group {group!r}; facet groups: "
                             f"{', '.join(sorted(scene.facets)) or 'none'}")
        if kind == "contact_force" and group not in (scene.loads.get("contact") or {}):
            raise InputError(f"target {name!r}: no contact named {group!r}; declared contacts: "
                             f"{', '.join(sorted(scene.loads.get('contact') or {})) or 'none'}")


def _check_unknowns(unknowns: Mapping[str, Sequence[float] | None], scene,
                    servo_range: tuple[float, float]) -> dict[str, tuple[float, float]]:
    """``{name: (lo, hi)}`` of the unknowns, checked.

    Servo angles (deg; default the servo range) and the factors of named forces, tractions, pressures and cables
    (bounds required; a cable's ≥ 0).
    """
    from fenicsfoam.design import ACTUATOR_KINDS
    loads = {name: kind for kind in ACTUATOR_KINDS for name in (scene.loads.get(kind) or {})}
    servos = tuple(scene.servos)
    valid = ", ".join([*servos, *loads]) or "none (the scene has no servos and no named force, traction, pressure " \
        "or cable)"
    if not unknowns:
        raise InputError(f"give at least one unknown; this scene's: {valid}")
    bounds = {}
    for name, bound in unknowns.items():
        if name not in servos and name not in loads:
            raise InputError(f"unknown {name!r} is not a servo or a named actuating load of the scene; valid: {valid}")
        if bound is None:
            if name in loads:
                raise InputError(f"unknown {name!r}: give the bounds of its factor (e.g. {name}=0:2)")
            bound = servo_range
        lo, hi = (float(v) for v in bound)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise InputError(f"unknown {name!r}: bounds [{lo!r}, {hi!r}] must be finite with lo < hi")
        if name in servos and not (-180.0 < lo and hi < 180.0):
            raise InputError(f"unknown {name!r}: servo bounds [{lo:g}, {hi:g}] deg must lie in (-180, 180)")
        if name in loads and loads[name] == "cable" and lo < 0:
            raise InputError(f"unknown {name!r}: a cable's factor must stay >= 0 (it cannot push), got lo = {lo:g}")
        bounds[name] = (lo, hi)
    return bounds


def parse_unknowns(items: Sequence[str]) -> dict[str, tuple[float, float] | None]:
    """``["chamber=0:2", "servo0"]`` → ``{"chamber": (0.0, 2.0), "servo0": None}``; :class:`InputError` if bad."""
    unknowns: dict[str, tuple[float, float] | None] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not name:
            raise InputError(f"unknown {item!r}: expected NAME or NAME=LO:HI, e.g. chamber=0:2")
        bound = None
        if sep:
            lo, colon, hi = value.partition(":")
            try:
                bound = (float(lo), float(hi))
            except ValueError:
                raise InputError(f"unknown {item!r}: expected NAME=LO:HI with numbers, e.g. chamber=0:2") from None
            if not colon:
                raise InputError(f"unknown {item!r}: expected NAME=LO:HI, e.g. chamber=0:2")
        if name in unknowns:
            raise InputError(f"unknown {name!r} is given twice")
        unknowns[name] = bound
    return unknowns


def _check_range(servo_range: Sequence[float]) -> tuple[float, float]:
    lo, hi = (float(v) for v in servo_range)
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi and -180.0 < lo and hi < 180.0):
        raise InputError(f"servo range [{lo!r}, {hi!r}] deg: expected -180 < lo < hi < 180")
    return lo, hi


# --------------------------------------------------------------------------------------------------
# The QP of a step
# --------------------------------------------------------------------------------------------------
def qp_step(B: np.ndarray, g: np.ndarray, A: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray,
            rtol: float = 1e-10) -> tuple[np.ndarray, np.ndarray] | None:
    """``argmin ½ δᵀBδ + gᵀδ`` subject to ``A δ = b`` and ``lo ≤ δ ≤ hi`` (B positive definite), with multipliers.

    Returns ``(δ, λ)``, ``λ`` the multipliers of the equalities (``Bδ + g + Aᵀλ = 0`` on the free unknowns), or
    ``None`` if the constraints are infeasible.

    Exact for a few unknowns: every face of the box (each unknown free, at ``lo`` or at ``hi``) is solved as an
    equality-constrained QP (its KKT system, by least squares); the best feasible candidate is the minimiser
    (a convex QP's minimiser is the KKT point of the face whose relative interior holds it).
    """
    n, m = B.shape[0], A.shape[0]
    scale = np.abs(A) @ np.maximum(np.abs(lo), np.abs(hi)) + np.abs(b) + 1e-300
    best, best_value = None, np.inf
    for status in itertools.product((0, 1, 2), repeat=n):
        d = np.zeros(n)
        fixed = [i for i in range(n) if status[i]]
        free = [i for i in range(n) if not status[i]]
        for i in fixed:
            d[i] = lo[i] if status[i] == 1 else hi[i]
        lam = np.zeros(m)
        if free:
            k = len(free)
            K = np.zeros((k + m, k + m))
            K[:k, :k] = B[np.ix_(free, free)]
            K[:k, k:] = A[:, free].T
            K[k:, :k] = A[:, free]
            rhs = np.concatenate([-g[free] - B[np.ix_(free, fixed)] @ d[fixed], b - A[:, fixed] @ d[fixed]])
            solution = np.linalg.lstsq(K, rhs, rcond=None)[0]
            d[free], lam = solution[:k], solution[k:]
        if np.any(np.abs(A @ d - b) > rtol * scale):
            continue
        if np.any(d < lo - 1e-12) or np.any(d > hi + 1e-12):
            continue
        value = float(0.5 * d @ B @ d + g @ d)
        if value < best_value:
            best, best_value = (np.clip(d, lo, hi), lam), value
    return best


def least_motion(G: np.ndarray, c: np.ndarray, theta0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 rtol: float = 1e-10) -> np.ndarray | None:
    """``argmin |x − θ⁰|²`` subject to ``G x = c`` and ``lo ≤ x ≤ hi``; ``None`` if infeasible (:func:`qp_step`)."""
    theta0 = np.asarray(theta0, dtype=float)
    step = qp_step(np.eye(theta0.size), np.zeros(theta0.size), G, c - G @ theta0, lo - theta0, hi - theta0, rtol)
    return None if step is None else theta0 + step[0]


def _closest_step(G, c, theta0, lo, hi):
    """The bounded least-squares point of ``|G x − c|`` (rows already weighted), then its least-motion point."""
    from scipy.optimize import lsq_linear
    x = lsq_linear(G, c, bounds=(lo, hi), method="bvls", tol=1e-14).x
    closest = least_motion(G, G @ x, theta0, lo, hi, rtol=1e-8)
    return x if closest is None else closest


def _projected_gradient(gradient: np.ndarray, x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The gradient with the components that push ``x`` out of the box (at a bound) removed."""
    p = gradient.copy()
    p[(x <= lo + 1e-12) & (p > 0)] = 0.0
    p[(x >= hi - 1e-12) & (p < 0)] = 0.0
    return p


def _escape_direction(G: np.ndarray) -> np.ndarray:
    """A unit step off a rank-deficient pose: a fixed direction projected off the row space of ``G``.

    Fixed (not a singular vector, which round-off would pick differently on different partitions), so the
    iteration is the same serially and under MPI.
    """
    _, sv, Vt = np.linalg.svd(G)
    basis = Vt[: int(np.sum(sv > _RANK_TOL * sv[0]))]
    for d in _ESCAPE_DIRECTIONS:
        d = d - basis.T @ (basis @ d)
        if np.linalg.norm(d) > 0.1:
            return d / np.linalg.norm(d)
    return _ESCAPE_DIRECTIONS[0] / np.linalg.norm(_ESCAPE_DIRECTIONS[0])


def _damped_bfgs(B: np.ndarray, s: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Powell's damped BFGS update of a positive definite ``B`` with the step ``s`` and gradient change ``y``."""
    Bs = B @ s
    sBs = float(s @ Bs)
    if sBs <= 1e-300:
        return B
    sy = float(s @ y)
    if sy < 0.2 * sBs:
        t = 0.8 * sBs / (sBs - sy)
        y = t * y + (1.0 - t) * Bs
        sy = float(s @ y)
    return B - np.outer(Bs, Bs) / sBs + np.outer(y, y) / sy


# --------------------------------------------------------------------------------------------------
# The controller
# --------------------------------------------------------------------------------------------------
class InverseController:
    """Inverse actuation of a scene, keeping its :class:`~fenicsfoam.design.SceneDesign` between calls.

    The unknowns are the Tripod's servo angles (the default, for a Tripod scene with servos) or any of the scene's
    servo angles (deg) and factors of named forces, tractions, pressures and cables at its last step, each within
    bounds (``unknowns = {name: (lo, hi)}``; a servo's default bounds are ``servo_range``). Successive :meth:`solve`
    calls start from the previous solution's equilibrium (warm start), e.g. along a trajectory of poses.
    """

    def __init__(self, source, comm=None, servo_range: Sequence[float] = SERVO_RANGE,
                 tolerances: Mapping[str, float] | None = None, max_iterations: int = 60,
                 unknowns: Mapping[str, Sequence[float] | None] | Sequence[str] | None = None):
        from fenicsfoam.design import SceneDesign
        from fenicsfoam.scene import Scene, load_scene

        scene = source if isinstance(source, Scene) else load_scene(source)
        self.servo_range = _check_range(servo_range)
        if unknowns is None:
            _check_default_unknowns(scene)
            unknowns = dict.fromkeys(scene.servos)
        elif not isinstance(unknowns, Mapping):
            unknowns = dict.fromkeys(unknowns)
        self.bounds = _check_unknowns(unknowns, scene, self.servo_range)
        self.names = list(self.bounds)
        self.lo = np.array([self.bounds[n][0] for n in self.names])
        self.hi = np.array([self.bounds[n][1] for n in self.names])
        self.tolerances = {**TOLERANCES, **(tolerances or {})}
        if not (isinstance(max_iterations, int) and max_iterations >= 1):
            raise InputError(f"max_iterations must be an integer >= 1, got {max_iterations!r}")
        self.max_iterations = max_iterations
        self.scene = scene
        self.initial = np.array([_scene_value(scene, n) for n in self.names], dtype=float)
        self._check_initial(self.initial)  # before anything is built
        self.design = SceneDesign(scene, comm, probes=tuple(TARGET_PROBES) if scene.builder == "tripod" else ())
        self._solved = False

    @property
    def initial_deg(self) -> np.ndarray:
        """The initial guess (the unknowns' values in their order; for the Tripod's default, the servo angles)."""
        return self.initial

    @initial_deg.setter
    def initial_deg(self, values) -> None:
        self.initial = np.asarray(values, dtype=float)

    def _check_initial(self, initial: np.ndarray) -> None:
        if np.any(initial < self.lo) or np.any(initial > self.hi):
            if self.names == list(self.scene.servos):
                lo, hi = self.servo_range
                raise InputError(f"initial servo angles {initial.tolist()} deg (the last step's servo_deg) lie "
                                 f"outside the servo range [{lo:g}, {hi:g}] deg")
            raise InputError(f"initial values {dict(zip(self.names, initial.tolist()))} (the scene's last step) lie "
                             f"outside the bounds {self.bounds}")

    def _set(self, x: np.ndarray) -> None:
        self.design.set(dict(zip(self.names, (float(v) for v in x))))

    def _solve_at(self, x: np.ndarray) -> dict[str, float]:
        """Move the unknowns to ``x`` from the current equilibrium (one scene solve)."""
        self._set(x)
        return self.design.solve_last_step()

    def solve(self, targets: Mapping[str, float], initial_deg: Sequence[float] | None = None) -> ControlResult:
        """Servo angles that meet ``targets`` (module docstring); the first call runs the whole schedule.

        ``initial_deg`` (default: the last step's angles at the first call, then the previous solution) is the
        initial guess and the origin of the least motion.

        Raises
        ------
        InputError
            Bad targets or initial angles (before any solve).
        UnreachableTargetError
            The targets are out of reach within the servo range; ``closest`` holds the closest pose.
        foambase.errors.NotConvergedError
            The iteration did not converge in ``max_iterations`` (or a forward solve kept failing).

        """
        design = self.design
        targets = _check_targets(targets, len(self.names), "unknowns")
        _check_target_groups(targets, self.scene)
        theta0 = np.array(self.initial if initial_deg is None else initial_deg, dtype=float)
        if theta0.shape != (len(self.names),) or not np.all(np.isfinite(theta0)):
            raise InputError(f"initial values must be {len(self.names)} finite numbers ({', '.join(self.names)}), "
                             f"got {theta0.tolist()}")
        self._check_initial(theta0)
        for name in targets:
            design.add_probe(name)
        run = _Run(self, targets, theta0)
        if not self._solved:
            self._set(theta0)
            run.values = design.solve()
            self._solved = True
        else:
            run.values = self._solve_at(theta0)
        run.record(np.inf)
        result = run.iterate()
        self.initial = np.array([result.unknowns[n] for n in self.names])
        return result

    def _unreachable(self, closest: ControlResult) -> None:
        values = {n: round(v, 6) for n, v in closest.unknowns.items()}
        raise UnreachableTargetError(
            f"the target {closest.target} is outside the reachable set for {', '.join(self.names)} within "
            f"{self.bounds}; closest reachable state: {closest.achieved} at {values}", closest)


def _check_default_unknowns(scene) -> None:
    if scene.builder != "tripod" or len(scene.servos) != 3:
        raise InputError(f"scene {scene.name!r}: inverse control needs the tripod builder with three servos "
                         "(loads.servos = true, or three [loads.servo.NAME]) for its default unknowns, or unknowns: "
                         "named loads' factors, servo angles")


def _scene_value(scene, name: str) -> float:
    """An unknown's value at the scene's last step: a servo angle from rest (deg) or a load factor (0 if none)."""
    value = 0.0
    for step in scene.steps:
        if name in step.servos:
            value = float(step.servos[name])
        elif name in step.loads:
            value = float(step.loads[name])
    return value


class _Run:
    """One inverse-control solve: restoration (Newton onto the targets) and least-motion tangent steps."""

    def __init__(self, controller: InverseController, targets: dict[str, float], theta0: np.ndarray):
        self.controller, self.design = controller, controller.design
        self.targets, self.theta0 = targets, theta0
        self.names = list(targets)
        self.unknowns = controller.names
        self.n = len(self.unknowns)
        self.t = np.array([targets[n] for n in self.names])
        self.w = np.array([1.0 / UNIT_SCALES[target_unit(n)] for n in self.names])
        self.tol = np.array([controller.tolerances[target_unit(n)] for n in self.names])
        self.lo, self.hi = controller.lo.copy(), controller.hi.copy()
        self.theta = theta0.copy()
        self.values: dict[str, float] = {}
        self.solves0 = self.design.solves
        self.history: list[dict[str, Any]] = []
        self.iterations = 0
        self.escapes = 0
        self.kkt: float | None = None

    # -- bookkeeping ------------------------------------------------------------------------------
    @property
    def misfit(self) -> np.ndarray:
        return np.array([self.values[n] for n in self.names]) - self.t

    @property
    def met(self) -> bool:
        return bool(np.all(np.abs(self.misfit) <= self.tol))

    def record(self, step: float) -> None:
        self.history.append({"iteration": self.iterations,
                             "unknowns": dict(zip(self.unknowns, self.theta.tolist())),
                             "achieved": {n: self.values[n] for n in self.names}, "step": float(step)})
        logger.info("control iteration %d: %s, misfit %s", self.iterations,
                    dict(zip(self.unknowns, np.round(self.theta, 6).tolist())), self.misfit.tolist())

    def result(self, reached: bool) -> ControlResult:
        servos = [i for i, n in enumerate(self.unknowns) if n in self.controller.scene.servos]
        return ControlResult(servo_deg=self.theta[servos].tolist(), target=dict(self.targets),
                             achieved={n: self.values[n] for n in self.names}, iterations=self.iterations,
                             scene_solves=self.design.solves - self.solves0, reached=reached,
                             servo_range=self.controller.servo_range, initial_deg=self.theta0[servos].tolist(),
                             history=self.history, unknowns=dict(zip(self.unknowns, self.theta.tolist())),
                             bounds=dict(self.controller.bounds),
                             initial=dict(zip(self.unknowns, self.theta0.tolist())), kkt_residual=self.kkt)

    def _count(self) -> None:
        self.iterations += 1
        if self.iterations > self.controller.max_iterations:
            closest = self.result(False)
            misfit = dict(zip(self.names, self.misfit.tolist()))
            raise _NotConverged(f"inverse control did not converge in {self.controller.max_iterations} iterations: "
                                f"misfit {misfit} at {self._where()}", closest)

    def _where(self) -> str:
        return str(dict(zip(self.unknowns, np.round(self.theta, 6).tolist())))

    def _gradients(self) -> np.ndarray:
        """``W ∂f/∂x`` (targets × unknowns) at the current equilibrium."""
        g = self.design.gradient(self.names, self.unknowns)
        return self.w[:, None] * np.array([[g[n][s] for s in self.unknowns] for n in self.names])

    def _move(self, trial: np.ndarray) -> bool:
        """Solve at ``trial``; on a failed forward solve go back to the current state and return False."""
        from fenicsfoam.solver import ConvergenceError

        state = self.design.problem.snapshot()
        try:
            self.values_trial = self.controller._solve_at(trial)
        except ConvergenceError as exc:
            logger.info("control: forward solve at %s failed (%s)", trial.tolist(), exc)
            self.design.problem.restore(state)
            self.controller._set(self.theta)
            return False
        self._state = state
        return True

    def _undo(self) -> None:
        self.design.problem.restore(self._state)
        self.controller._set(self.theta)

    # -- restoration: Newton (least-norm steps) onto f(θ) = t, Gauss-Newton to the closest pose if out of reach --
    def restore(self) -> np.ndarray:
        """Meet the targets from the current θ; returns ``W ∂f/∂θ`` at the result."""
        lo, hi, w = self.lo, self.hi, self.w
        while True:
            Gw = self._gradients()
            if self.met:
                return Gw
            rw = w * self.misfit
            singular = np.linalg.svd(Gw, compute_uv=False)
            if singular[-1] <= _RANK_TOL * singular[0] and self.escapes < _MAX_ESCAPES:
                # A symmetric pose: the targets' gradients are parallel (e.g. height and twist of case B at equal
                # angles), so no first-order step meets them; leave the symmetry along a fixed direction.
                self.escapes += 1
                direction = _escape_direction(Gw) if self.n == 3 else _escape_direction_n(Gw)
                logger.info("control: rank-deficient target gradients at %s; a %g deg step along %s",
                            self.theta.tolist(), _ESCAPE_DEG, np.round(direction, 6).tolist())
                self._count()
                if self._move(np.clip(self.theta + _ESCAPE_DEG * direction, lo, hi)):
                    self.theta, self.values = np.clip(self.theta + _ESCAPE_DEG * direction, lo, hi), self.values_trial
                self.record(_ESCAPE_DEG)
                continue
            qp = qp_step(np.eye(self.n), np.zeros(self.n), Gw, -rw, lo - self.theta, hi - self.theta)
            if qp is not None:
                step = qp[0]
            else:  # the linearised target is out of the box: towards the closest pose
                gradient = Gw.T @ rw
                stationary = np.max(np.abs(_projected_gradient(gradient, self.theta, lo, hi) * (hi - lo))) \
                    <= 1e-10 * float(rw @ rw)
                if stationary:
                    self.controller._unreachable(self.result(False))
                step = _closest_step(Gw, Gw @ self.theta - rw, self.theta, lo, hi) - self.theta
            merit = 0.5 * float(rw @ rw)
            alpha, accepted = 1.0, False
            for _ in range(10):
                trial = np.clip(self.theta + alpha * step, lo, hi)
                if self._move(trial):
                    trial_rw = w * (np.array([self.values_trial[n] for n in self.names]) - self.t)
                    if 0.5 * float(trial_rw @ trial_rw) <= merit * (1.0 - 1e-4 * alpha):
                        accepted = True
                        break
                    self._undo()
                alpha *= 0.5
            self._count()
            if not accepted:
                if qp is None:
                    self.controller._unreachable(self.result(False))
                raise _NotConverged(f"inverse control: no step from {self._where()} reduces the misfit "
                                    f"{self.misfit.tolist()} (a forward solve failing?)", self.result(False))
            self.theta, self.values = trial, self.values_trial
            self.record(float(np.max(np.abs(alpha * step))))

    # -- the least-motion iteration ---------------------------------------------------------------
    def _motion(self, Gw: np.ndarray) -> float:
        """``|θ_c − θ⁰|²``, ``θ_c = θ − G⁺ W (f − t)`` the nearest point of the linearised level set.

        The targets are met within their tolerance, so θ lies up to ``|G⁺ W tol|`` off the level set; that offset
        changes ``|θ − θ⁰|²`` to first order (by ``2 |θ − θ⁰| |G⁺ W tol|``, more than a short tangent step gains),
        while the corrected motion is off by its square only.
        """
        correction = -np.linalg.pinv(Gw) @ (self.w * self.misfit)
        return float(np.sum((self.theta + correction - self.theta0) ** 2))

    def kkt_residual(self, Gw: np.ndarray) -> float:
        """The least-motion KKT residual, in the unknowns' units.

        The longest component of the step ``argmin ½|δ|² + (θ − θ⁰)ᵀδ`` subject to ``G δ = 0`` and the bounds,
        i.e. ``−Z Zᵀ(θ − θ⁰)`` (the projected gradient of ``½|θ − θ⁰|²`` onto the level set's tangent) where no
        bound is active.
        """
        step = qp_step(np.eye(self.n), self.theta - self.theta0, Gw, np.zeros(len(self.names)),
                       self.lo - self.theta, self.hi - self.theta)
        return float(np.max(np.abs(step[0]))) if step is not None else math.inf

    def kkt_tolerance(self, Gw: np.ndarray) -> float:
        """The tolerance of the KKT residual, ``max(1e-5, |G⁺ W tol|_∞)``.

        The residual is resolved no finer than the targets' tolerance places θ on the level set: a point off it by
        ε turns the tangent by about ε times the level set's curvature κ, which changes the residual by about
        ε |θ − θ⁰| κ, of order ε where the reduced Hessian is of order one.
        """
        return max(_MOTION_TOL, float(np.max(np.abs(np.linalg.pinv(Gw)) @ (self.w * self.tol))))

    def iterate(self) -> ControlResult:
        """Restoration, then (fewer targets than servos) quasi-Newton steps along the targets' level set."""
        Gw = self.restore()
        if len(self.names) == self.n:
            return self.result(True)
        previous = None          # (reduced gradient, tangent basis, θ) of the last feasible point
        H = None                 # reduced Hessian of ½|θ − θ⁰|² on the level set (secant updates)
        stretch = 1.0            # step length factor while no positive curvature is known
        while True:
            Z = _tangent_basis(Gw)
            g = Z.T @ (self.theta - self.theta0)
            self.kkt = self.kkt_residual(Gw)
            tolerance = self.kkt_tolerance(Gw)
            motion = self._motion(Gw)
            if self.kkt <= tolerance:
                logger.info("control: least motion converged, KKT residual %.3g <= %.3g, |θ − θ⁰| = %.9g",
                            self.kkt, tolerance, math.sqrt(motion))
                return self.result(True)
            if previous is not None:
                g_prev, Z_prev, theta_prev = previous
                s_z = Z.T @ (self.theta - theta_prev)
                y_z = g - Z.T @ Z_prev @ g_prev
                if float(s_z @ y_z) > 1e-12 * float(s_z @ s_z):
                    H = _damped_bfgs(np.eye(len(g)) if H is None else H, s_z, y_z)
                else:  # no positive curvature along the level set (yet): lengthen the steps
                    H, stretch = None, min(2.0 * stretch, 1e3)
            reduced = np.eye(len(g)) / stretch if H is None else H
            # the quasi-Newton step on the tangent within the bounds: the QP with the metric Z H Zᵀ + Y Yᵀ (Y the
            # targets' row space), which is -Z H⁻¹ g where no bound is active
            Y = _row_basis(Gw)
            metric = Z @ reduced @ Z.T + Y @ Y.T
            qp = qp_step(metric, self.theta - self.theta0, Gw, np.zeros(len(self.names)), self.lo - self.theta,
                         self.hi - self.theta)
            step = qp[0] if qp is not None else np.zeros(self.n)
            step *= min(1.0, _MAX_TANGENT_DEG / max(float(np.max(np.abs(step))), 1e-300))
            logger.info("control: least motion at %s: |θ − θ⁰| = %.12g, reduced gradient %s, KKT residual %.3g "
                        "(tolerance %.3g), reduced Hessian %s, tangent step %.3g", self._where(), math.sqrt(motion),
                        np.round(g, 9).tolist(), self.kkt, tolerance, np.round(reduced, 6).tolist(),
                        float(np.max(np.abs(step))))
            state = self.design.problem.snapshot()
            saved = (self.theta.copy(), dict(self.values))
            accepted = False
            for _ in range(6):
                trial = np.clip(self.theta + step, self.lo, self.hi)
                self._count()
                if self._move(trial):
                    self.theta, self.values = trial, self.values_trial
                    self.record(float(np.max(np.abs(step))))
                    try:
                        Gw_new = self.restore()
                    except UnreachableTargetError:
                        Gw_new = None
                    if Gw_new is not None and self._motion(Gw_new) < motion:
                        accepted = True
                        break
                # back to the last feasible point, half the step
                self.design.problem.restore(state)
                self.theta, self.values = saved[0].copy(), dict(saved[1])
                self.controller._set(self.theta)
                step *= 0.5
                stretch = max(0.5 * stretch, 1.0)
            if not accepted:
                raise _NotConverged(f"inverse control: no shorter motion found near {self._where()} (KKT residual "
                                    f"{self.kkt:.3g} > {tolerance:.3g}, reduced gradient {g.tolist()})",
                                    self.result(False))
            previous = (g, Z, saved[0])
            Gw = Gw_new


def _escape_direction_n(G: np.ndarray) -> np.ndarray:
    """:func:`_escape_direction` for any number of unknowns: the first unit vector off the row space of ``G``."""
    _, sv, Vt = np.linalg.svd(G)
    basis = Vt[: int(np.sum(sv > _RANK_TOL * sv[0]))]
    for d in np.eye(G.shape[1]):
        d = d - basis.T @ (basis @ d)
        if np.linalg.norm(d) > 0.1:
            return d / np.linalg.norm(d)
    return np.eye(G.shape[1])[0]


def _row_basis(G: np.ndarray) -> np.ndarray:
    """An orthonormal basis (n, m) of the row space of ``G`` (the level set's normal space)."""
    _, _, Vt = np.linalg.svd(G)
    return Vt[: G.shape[0]].T


def _tangent_basis(G: np.ndarray) -> np.ndarray:
    """An orthonormal basis (n, k) of the null space of ``G``, each column's sign fixed (largest entry positive)."""
    _, _, Vt = np.linalg.svd(G)
    Z = Vt[G.shape[0]:].T
    for j in range(Z.shape[1]):
        i = int(np.argmax(np.abs(Z[:, j])))
        if Z[i, j] < 0:
            Z[:, j] = -Z[:, j]
    return Z


class _NotConverged(NotConvergedError):
    def __init__(self, message: str, closest: ControlResult):
        self.closest = closest
        super().__init__(message)


def control_servos(source, targets: Mapping[str, float], *, comm=None, servo_range: Sequence[float] = SERVO_RANGE,
                   tolerances: Mapping[str, float] | None = None, max_iterations: int = 60,
                   out_dir: str | os.PathLike | None = None,
                   unknowns: Mapping[str, Sequence[float] | None] | Sequence[str] | None = None) -> ControlResult:
    """Servo angles or load factors of the scene's last step that meet ``targets`` (module docstring).

    Parameters
    ----------
    source
        A scene (TOML path, dict or parsed scene); without ``unknowns``, a Tripod scene with servos.
    targets
        ``{probe: value}``: ``center_height`` (m), ``center_rotation``, ``center_tilt_x``, ``center_tilt_y``
        (deg), ``tip_deflection`` (m), or a component ``KIND:GROUP[i]`` of ``displacement`` (m) or
        ``contact_force`` (N); at most as many as unknowns.
    unknowns
        ``{name: (lo, hi) or None}`` (or a list of names): servo angles ``servo0..2`` (deg; default bounds
        ``servo_range``) and named forces, tractions, pressures, cables (their factor; bounds required). Default:
        the Tripod's three servos.
    comm
        MPI communicator (default ``MPI.COMM_WORLD``).
    servo_range
        ``(lo, hi)`` in degrees, the bounds of every servo.
    tolerances
        ``{"m": ..., "deg": ...}``, the tolerance of the targets by unit (default 1e-9 m, 1e-7 deg).
    max_iterations
        Steps (each a forward solve) before :class:`~foambase.errors.NotConvergedError`.
    out_dir
        Writes ``out_dir/control.json`` (also when unreachable, with ``reached = false`` and the closest pose).

    """
    targets = dict(targets)
    _check_targets(targets, 3 if unknowns is None else len(unknowns), "unknowns")
    if out_dir is not None:  # before any work: a directory that can take control.json
        from mpi4py import MPI

        from foambase.files import check_output_dir
        from foambase.mpi import on_rank0
        on_rank0(MPI.COMM_WORLD if comm is None else comm, lambda: check_output_dir(out_dir, "out_dir"),
                 f"the output directory {out_dir} cannot be used")
    from fenicsfoam.scene import Scene, load_scene
    scene = source if isinstance(source, Scene) else load_scene(source)
    if unknowns is None:
        _check_default_unknowns(scene)
    _check_target_groups(targets, scene)  # before anything is built
    controller = InverseController(scene, comm, servo_range, tolerances, max_iterations, unknowns)
    try:
        result = controller.solve(targets)
    except (UnreachableTargetError, _NotConverged) as exc:
        if out_dir is not None:
            exc.closest.write(out_dir, controller.design.comm)
        raise
    if out_dir is not None:
        result.write(out_dir, controller.design.comm)
    return result


# --------------------------------------------------------------------------------------------------
# The command
# --------------------------------------------------------------------------------------------------
def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", type=cli.nonempty_path, help="a scene file (TOML)")
    parser.add_argument("--target", action="append", default=[], metavar="NAME=VALUE", required=True,
                        help="a target: center_height (m), center_rotation, center_tilt_x, center_tilt_y (deg), "
                             "tip_deflection (m), or a component KIND:GROUP[i] of displacement (m) or contact_force "
                             "(N), e.g. 'displacement:tip[2]=-0.01'; repeat for up to as many as unknowns")
    parser.add_argument("--unknown", action="append", default=[], metavar="NAME[=LO:HI]",
                        help="an unknown: a servo (servo0..2, deg; default bounds --servo-range) or a named force, "
                             "traction, pressure or cable of the scene (its factor at the last step; bounds required, "
                             "e.g. chamber=0:2); repeat; default: the Tripod's three servos")
    parser.add_argument("--out", type=cli.nonempty_path, required=True,
                        help="output directory (control.json; created if needed, other files in it stay)")
    parser.add_argument("--servo-range", type=float, nargs=2, default=list(SERVO_RANGE), metavar=("LO", "HI"),
                        help="bounds of every servo angle (deg)")
    parser.add_argument("--tol-m", type=float, default=TOLERANCES["m"], help="tolerance of a height target (m)")
    parser.add_argument("--tol-deg", type=float, default=TOLERANCES["deg"],
                        help="tolerance of an angle target (deg)")
    parser.add_argument("--tol-n", type=float, default=TOLERANCES["N"], help="tolerance of a force target (N)")
    parser.add_argument("--max-iterations", type=int, default=60, help="steps (each a forward solve) at most")


def _check(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    try:
        unknowns = parse_unknowns(args.unknown)
        _check_targets(parse_targets(args.target), len(unknowns) or 3, "unknowns")
        _check_range(args.servo_range)
    except InputError as exc:
        parser.error(str(exc))
    for name in ("tol_m", "tol_deg", "tol_n"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):
            parser.error(f"--{name.replace('_', '-')} must be > 0, got {value!r}")
    if args.max_iterations < 1:
        parser.error(f"--max-iterations must be >= 1, got {args.max_iterations}")


def _run(args: argparse.Namespace) -> int:
    from mpi4py import MPI

    from foambase.files import check_output_dir
    from foambase.mpi import on_rank0
    from foambase.petsc_options import command_line_options

    comm = MPI.COMM_WORLD
    on_rank0(comm, lambda: check_output_dir(args.out, "--out"), f"--out {args.out} cannot be used")
    with command_line_options(args.passthrough):
        try:
            result = control_servos(args.scene, parse_targets(args.target), comm=comm,
                                    servo_range=args.servo_range,
                                    tolerances={"m": args.tol_m, "deg": args.tol_deg, "N": args.tol_n},
                                    max_iterations=args.max_iterations, out_dir=args.out,
                                    unknowns=parse_unknowns(args.unknown) or None)
        except (UnreachableTargetError, _NotConverged):
            if comm.rank == 0:
                print(f"closest pose written to {args.out / 'control.json'} (reached = false)")
            raise
    if comm.rank == 0:
        print("unknowns (servo angles in deg, load factors): "
              + ", ".join(f"{name} = {value:.6f}" for name, value in result.unknowns.items()))
        for name, value in result.target.items():
            unit = target_unit(name)
            print(f"{name}: target {value:.9g} {unit}, achieved {result.achieved[name]:.9g} {unit}")
        print(f"{result.iterations} iterations, {result.scene_solves} scene solves; {args.out / 'control.json'}")
    return 0


CONTROL = cli.Command(
    "control", "inverse actuation: the servo angles or load factors that reach target probe values", _arguments,
    _run,
    description="Find the unknowns (--unknown: servo angles, factors of named forces, tractions, pressures, cables; "
                "default the Tripod's servos) of the scene's last step (earlier steps as written; its values are the "
                "initial guess) that bring the targeted probes to their values (Gauss-Newton with adjoint "
                "sensitivities, within the bounds); fewer targets than unknowns: the least change. "
                "Writes OUT/control.json. Exit 3 (with control.json, reached = false, and the closest reachable pose) "
                "when the target is out of reach or the iteration does not converge. PETSc options after '--' "
                "apply to the scene's solver (prefix 'scene_'). Works under mpirun.",
    check=_check, passthrough=True)
