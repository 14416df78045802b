"""A scene as a differentiable function of its parameters: set parameters, solve, evaluate probes and their gradients.

:class:`SceneDesign` builds a scene once and then maps named parameters to its probes at the last load step:

=========================  ===================================================================================
parameter                  meaning (unit)
=========================  ===================================================================================
``servo0`` … ``servo2``    the Tripod's horn angles of the *last* step (deg); earlier steps as written
``E_solid``                the solid's Young's modulus of every foam region, changed together (Pa)
``density:REGION``         the relative density of a foam region given as a number (also through a blend)
``gamma:REGION``           the anisotropy γ of such a region
``density``, ``gamma``     per-cell fields over the foam cells (one value per owned cell; NaN elsewhere)
``orientation``            per-cell in-plane angle (deg) added to every cell's *l* axis: ``R_z(φ_c) a_c``
``orientation.offset_deg`` one in-plane angle (deg) added to every *l* axis (the scene's ``offset_deg``; for
                           case A: the arm offset angle of the l axes from the arms)
``orientation.pitch_deg``  the pitch of a spiral orientation (deg)
``NAME`` of a load         the factor of a named force, traction, pressure or cable at the *last* step
                           (dimensionless; 1 is the value the scene gives the load)
=========================  ===================================================================================

The *l* axis of a cell is ``a_c = R_z(offset + φ_c) a⁰_c(pitch)``, ``a⁰`` the scene's field without offset;
``∂a/∂φ = e_z × a`` (per radian) and for the spiral ``∂a⁰/∂p = cos p e_r − h sin p e_θ``
(:func:`fenicsfoam.orientation.spiral_directions`). Material parameters (``E_solid``, ``density:REGION``,
``gamma:REGION``) are first set in the scene itself and checked there (:func:`fenicsfoam.scene.vary_scene`),
then act through the DG0 moduli and mass density of :class:`fenicsfoam.grading.CellMaterials` (the foam table's
exact derivatives); servo angles through the Dirichlet values, load factors through the load's own term
(``∂R/∂s``). :meth:`SceneDesign.gradient` chains the adjoint's
per-cell gradients (:mod:`fenicsfoam.sensitivity`) to the parameters: one factorization and one adjoint solve
per probe, whatever the number of parameters. Per-cell parameters and their gradients are arrays over the owned
cells (their global order: :meth:`SceneDesign.gather`).

Targets may also be one component of a vector probe, ``"KIND:GROUP[i]"`` (``displacement:tip[2]``,
``contact_force:ball[2]``): :meth:`SceneDesign.add_probe` builds them with their gradients.

A *scene solve* (:meth:`SceneDesign.solve`) runs the whole schedule from the reference state;
:meth:`SceneDesign.solve_last` only moves the last step's servo angles from the current equilibrium and
:meth:`SceneDesign.solve_last_step` the last step's angles and load factors (the
equilibrium of the last step does not depend on the path, so warm starting gives the same state as a full run,
up to the solver tolerance). Both count in :attr:`SceneDesign.solves`.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from mpi4py import MPI

from foambase.cells import num_owned_cells
from foambase.errors import InputError

__all__ = ["ACTUATOR_KINDS", "COMPONENT_KINDS", "MISFIT_SCALES", "DesignHistory", "DesignResult", "OrientationDesign",
           "SERVOS", "SceneDesign", "match_probes", "optimize_probe"]

logger = logging.getLogger(__name__)

#: The servo parameters of ``loads.servos = true`` (the Tripod's three horns), in order; a scene with
#: ``[loads.servo.NAME]`` has its own names (:attr:`SceneDesign.servos`).
SERVOS = ("servo0", "servo1", "servo2")
#: The load kinds whose named loads are parameters (their factor at the last step): the actuators.
ACTUATOR_KINDS = ("force", "traction", "pressure", "cable")
#: Vector probes whose components may be targets (``"KIND:GROUP[i]"``).
COMPONENT_KINDS = ("displacement", "contact_force")
_EZ = np.array([0.0, 0.0, 1.0])


def _rotate_z(a: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.column_stack([c * a[:, 0] - s * a[:, 1], s * a[:, 0] + c * a[:, 1], a[:, 2]])


class OrientationDesign:
    """The *l*-axis field of a scene as a function of its offset, its spiral pitch and a per-cell angle field."""

    def __init__(self, spec: Mapping[str, Any], field, mesh):
        from dolfinx.mesh import compute_midpoints

        from fenicsfoam.orientation import cell_values

        self.spec = dict(spec)
        self.field = field
        self.offset_deg = float(self.spec.get("offset_deg", 0.0))
        self.pitch_deg = float(self.spec["pitch_deg"]) if self.spec["kind"] == "spiral" else None
        n = num_owned_cells(mesh)
        self.angle_deg = np.zeros(n)
        self._midpoints = compute_midpoints(mesh, mesh.topology.dim, np.arange(n, dtype=np.int32))
        self._base = _rotate_z(cell_values(field), np.full(n, -math.radians(self.offset_deg)))

    def base(self) -> np.ndarray:
        """``a⁰``: the field without offset and per-cell angles (the spiral at the current pitch)."""
        if self.pitch_deg is None:
            return self._base
        from fenicsfoam.orientation import spiral_directions
        return spiral_directions(self._midpoints, self.pitch_deg, self.spec["handedness"], self.spec["center"])

    def directions(self) -> np.ndarray:
        """The *l* axis per owned cell, ``R_z(offset + φ_c) a⁰_c``."""
        return _rotate_z(self.base(), np.radians(self.offset_deg + self.angle_deg))

    def apply(self) -> None:
        """Write :meth:`directions` into the DG0 orientation field."""
        from fenicsfoam.orientation import set_cell_values
        set_cell_values(self.field, self.directions())

    def d_angle(self) -> np.ndarray:
        """``∂a_c/∂φ_c`` per degree (n, 3): ``e_z × a_c · π/180``."""
        return np.cross(_EZ, self.directions()) * (math.pi / 180.0)

    def d_pitch(self) -> np.ndarray:
        """``∂a_c/∂p`` per degree of spiral pitch (n, 3)."""
        if self.pitch_deg is None:
            raise InputError("orientation.pitch_deg: the scene's orientation is not a spiral")
        from fenicsfoam.orientation import HANDEDNESS
        p, h = math.radians(self.pitch_deg), HANDEDNESS[self.spec["handedness"]]
        r = self._midpoints[:, :2] - np.asarray(self.spec["center"], dtype=float)
        norm = np.linalg.norm(r, axis=1, keepdims=True)
        e_r = np.divide(r, norm, out=np.zeros_like(r), where=norm > 0)
        e_t = np.column_stack([-e_r[:, 1], e_r[:, 0]])
        d = math.cos(p) * e_r - h * math.sin(p) * e_t
        d0 = np.column_stack([d, np.zeros(len(d))])
        return _rotate_z(d0, np.radians(self.offset_deg + self.angle_deg)) * (math.pi / 180.0)


class _Component:
    """A scalar probe from a value and a gradient function of the displacement."""

    def __init__(self, value, gradient):
        self._value, self._gradient = value, gradient

    def __call__(self, u) -> float:
        return float(self._value(u))

    def gradient(self, u) -> np.ndarray:
        return self._gradient(u)


class SceneDesign:
    """A scene built once, whose parameters can be set and whose probes can be solved for and differentiated.

    Parameters
    ----------
    source
        A scene (TOML path, dict or parsed :class:`~fenicsfoam.scene.Scene`).
    comm
        MPI communicator (default ``MPI.COMM_WORLD``).
    probes
        Probe kinds (:data:`fenicsfoam.scene.PROBE_KINDS`) wanted besides the scene's own (e.g. the tilts).

    """

    def __init__(self, source, comm=None, probes: Sequence[str] = ()):
        from fenicsfoam.grading import CellMaterials
        from fenicsfoam.scene import PROBE_KINDS, Scene, load_scene
        from fenicsfoam.scene.build import build_model
        from fenicsfoam.scene.kinds import BuildContext

        self.comm = MPI.COMM_WORLD if comm is None else comm
        scene = source if isinstance(source, Scene) else load_scene(source)
        for name in probes:
            if name not in PROBE_KINDS:
                raise InputError(f"unknown probe {name!r}; valid: {', '.join(PROBE_KINDS)}")
            if PROBE_KINDS[name].needs == "tripod" and scene.builder != "tripod":
                raise InputError(f"probe {name!r} needs the tripod builder, the scene uses {scene.builder!r}")
        from fenicsfoam.scene.build import _check_default_tables
        _check_default_tables(scene, "designs")  # before anything is built
        self.scene = scene
        self.model = build_model(scene, self.comm)
        self.problem = problem = self.model.problem
        tagged = self.model.tagged
        mesh, cell_tags = tagged.mesh, tagged.cell_tags
        context = BuildContext(scene, tagged, problem.V)
        self.probes = dict(self.model.probes)
        for name in probes:
            if name not in self.probes:
                self.probes[name] = PROBE_KINDS[name].build(context)
        self.cells = CellMaterials.from_regions(mesh, cell_tags, scene.regions, blends=getattr(scene, "blends", ()))
        if tuple(problem.material.moduli) != self.cells.names:
            raise InputError(f"the scene's moduli {tuple(problem.material.moduli)} differ from the per-cell ones "
                             f"{self.cells.names}")
        self.cells.update(problem.material)  # the values of the differentiable path (equal up to round-off)
        self.orientation = (OrientationDesign(scene.orientation, problem.orientation, mesh)
                            if problem.orientation is not None else None)
        self.steps = list(self.model.steps)
        self.solves = 0
        self._adjoint = None
        self.n_cells = num_owned_cells(mesh)

    # ----------------------------------------------------------------------------------------------
    # Parameters
    # ----------------------------------------------------------------------------------------------
    @property
    def servos(self) -> tuple[str, ...]:
        """The servo parameters of the scene: its servo actuators' names (``servo0..2`` with ``loads.servos``)."""
        return tuple(self.scene.servos)

    @property
    def actuators(self) -> tuple[str, ...]:
        """The named loads of the scene whose factors are parameters (forces, tractions, pressures, cables)."""
        return tuple(name for kind in ACTUATOR_KINDS for name in (self.scene.loads.get(kind) or {}))

    def parameters(self) -> list[str]:
        """The parameter names this scene has (module docstring)."""
        names = list(self.servos) + list(self.actuators)
        if self.cells.foams:
            names += ["E_solid", "density", "gamma"]
            for region, spec in self.cells.descriptions.items():
                names += [f"{key}:{region}" for key in ("density", "gamma")
                          if isinstance(spec[key], int | float) and not isinstance(spec[key], bool)]
        if self.orientation is not None:
            names += ["orientation", "orientation.offset_deg"]
            if self.orientation.pitch_deg is not None:
                names.append("orientation.pitch_deg")
        return names

    def _check(self, name: str) -> None:
        if name not in self.parameters():
            raise InputError(f"unknown parameter {name!r} for scene {self.scene.name!r}; valid: "
                             f"{', '.join(self.parameters())}")

    def _foam_mask(self) -> np.ndarray:
        mask = np.zeros(self.n_cells, dtype=bool)
        for foam in self.cells.foams.values():
            mask[foam.cells] = True
        return mask

    def get(self, name: str):
        """The current value of a parameter (a float, or an array over the owned cells)."""
        self._check(name)
        if name in self.servos:
            return self.servo_deg()[self.servos.index(name)]
        if name in self.actuators:
            return self.load_factor(name)
        if name == "E_solid":
            values = {f.E_solid for f in self.cells.foams.values()}
            if len(values) != 1:
                raise InputError(f"E_solid: the foam regions have different E_solid {sorted(values)}")
            return values.pop()
        if name in ("density", "gamma"):
            out = np.full(self.n_cells, np.nan)
            for foam in self.cells.foams.values():
                out[foam.cells] = getattr(foam, name)
            return out
        if ":" in name:
            key, region = name.split(":", 1)
            return float(self.cells.descriptions[region][key])
        if name == "orientation":
            return self.orientation.angle_deg.copy()
        return self.orientation.offset_deg if name == "orientation.offset_deg" else self.orientation.pitch_deg

    def set(self, values: Mapping[str, Any]) -> None:
        """Set parameters (``{name: value}``) and update the coefficient data; solve afterwards."""
        for name in values:
            self._check(name)
        scalars = {n: v for n, v in values.items()  # the material numbers: E_solid, density:REGION, gamma:REGION
                   if n not in self.servos and n not in self.actuators and (n == "E_solid" or ":" in n)}
        if scalars:  # the scene's own values, checked as a scene's (fenicsfoam.scene.vary_scene) before any change
            from fenicsfoam.scene import vary_scene
            self.scene = vary_scene(self.scene, {n: float(v) for n, v in scalars.items()})
        material, orientation = False, False
        servo = list(self.servo_deg()) if any(n in self.servos for n in values) else None
        for name, value in values.items():
            if name in self.servos:
                servo[self.servos.index(name)] = float(value)
            elif name in self.actuators:
                self.set_load_factor(name, float(value))
            elif name == "E_solid":
                for foam in self.cells.foams.values():
                    foam.E_solid = float(value)
                material = True
            elif name in ("density", "gamma"):
                value = np.asarray(value, dtype=float)
                for foam in self.cells.foams.values():
                    setattr(foam, name, value[foam.cells].copy())
                material = True
            elif ":" in name:
                key, region = name.split(":", 1)
                self.cells.set_region_value(key, region, float(value))
                material = True
            elif name == "orientation":
                self.orientation.angle_deg = np.asarray(value, dtype=float).reshape(self.n_cells).copy()
                orientation = True
            elif name == "orientation.offset_deg":
                self.orientation.offset_deg = float(value)
                orientation = True
            else:
                self.orientation.pitch_deg = float(value)
                orientation = True
        if servo is not None:
            self.set_servo_deg(servo)
        if material:
            self.cells.update(self.problem.material)
        if orientation:
            self.orientation.apply()

    def _rest_deg(self, name: str) -> float:
        return self.scene.servos[name]["setup_deg"]

    def servo_deg(self) -> tuple[float, ...]:
        """The last step's servo angles from rest (deg), in the order of :attr:`servos`.

        Where the last step gives none, those in force before it.
        """
        if not self.servos:
            raise InputError(f"scene {self.scene.name!r} has no servos (loads.servos = true or [loads.servo.NAME])")
        angles = [0.0] * len(self.servos)
        for step in self.steps:
            for i, name in enumerate(self.servos):
                if name in step.angles:
                    angles[i] = math.degrees(step.angles[name]) - self._rest_deg(name)
        return tuple(angles)

    def set_servo_deg(self, angles: Sequence[float]) -> None:
        """Set the last step's servo angles from rest (deg), in the order of :attr:`servos`."""
        from dataclasses import replace
        last = self.steps[-1]
        self.steps[-1] = replace(last, angles={**last.angles, **{n: math.radians(self._rest_deg(n) + float(a))
                                                                for n, a in zip(self.servos, angles)}})

    def load_factor(self, name: str) -> float:
        """The factor of the named load at the end of the last step (the last one a step gives; 0 if none)."""
        factor = 0.0
        for step in self.steps:
            factor = float(step.factors.get(name, factor))
        return factor

    def set_load_factor(self, name: str, factor: float) -> None:
        """Set the factor of the named load at the end of the last step."""
        from dataclasses import replace
        last = self.steps[-1]
        self.steps[-1] = replace(last, factors={**last.factors, name: float(factor)})

    def add_probe(self, name: str) -> None:
        """Build a differentiable probe (a scalar probe kind, or ``"KIND:GROUP[i]"``, one component of a vector).

        ``KIND`` is ``displacement`` (GROUP a facet group: the mean displacement's component, m) or ``contact_force``
        (GROUP a ``[contacts.NAME]``: the force's component, N). Nothing is done if it exists.
        """
        from fenicsfoam.scene import PROBE_KINDS
        from fenicsfoam.scene.kinds import BuildContext
        if name in self.probes:
            return
        if name in PROBE_KINDS:
            self.probes[name] = PROBE_KINDS[name].build(BuildContext(self.scene, self.model.tagged, self.problem.V))
            return
        kind, _, rest = name.partition(":")
        group, bracket, index = rest.partition("[")
        valid = (f"a probe of {', '.join(PROBE_KINDS)}, or KIND:GROUP[i] with KIND in {', '.join(COMPONENT_KINDS)} "
                 "and i = 0, 1, 2")
        if kind not in COMPONENT_KINDS or not bracket or index not in ("0]", "1]", "2]"):
            raise InputError(f"probe {name!r}: not a differentiable probe; valid: {valid}")
        component = int(index[0])
        if kind == "displacement":
            from fenicsfoam.probes import MeanDisplacement
            if group not in self.scene.facets:
                raise InputError(f"probe {name!r}: unknown facet group {group!r}; facet groups: "
                                 f"{', '.join(sorted(self.scene.facets)) or 'none'}")
            mean = MeanDisplacement(self.problem.V, self.model.tagged.facet_tags, self.scene.facets[group])
            self.probes[name] = _Component(lambda u: mean(u)[component], lambda u: mean.gradient(u, component))
        else:
            contacts = self.scene.loads.get("contact") or {}
            if group not in contacts:
                raise InputError(f"probe {name!r}: no contact named {group!r}; declared contacts: "
                                 f"{', '.join(sorted(contacts)) or 'none'}")
            contact = self.problem.external[group]
            self.probes[name] = _Component(lambda u: contact.force()[component],
                                           lambda u: contact.force_gradient(component))

    # ----------------------------------------------------------------------------------------------
    # Solves
    # ----------------------------------------------------------------------------------------------
    def values(self) -> dict[str, Any]:
        """The probes at the current state (floats; a vector probe ``KIND:GROUP`` as an array)."""
        out = {}
        for name, probe in self.probes.items():
            value = probe(self.problem.u)
            out[name] = float(value) if np.ndim(value) == 0 else np.asarray(value, dtype=float)
        return out

    def solve(self) -> dict[str, float]:
        """Run the whole schedule from the reference state; the probes at the last step (one scene solve)."""
        self.problem.reset()
        self.solves += 1
        for step in self.steps:
            self.problem.solve_step(step)
        return self.values()

    def solve_last(self, angles: Sequence[float], increment_deg: float = 10.0) -> dict[str, float]:
        """Move the last step's servo angles to ``angles`` (deg) from the current equilibrium (one scene solve).

        The current state must be an equilibrium of the last step (after :meth:`solve` or :meth:`solve_last`).
        The move takes ``ceil(max |Δθ| / increment_deg)`` increments (halved on failure by the solver).
        """
        from fenicsfoam.solver import LoadStep
        current = np.degrees([self.problem.loads.angles[n] for n in self.servos]) - [self._rest_deg(n)
                                                                                     for n in self.servos]
        change = float(np.max(np.abs(np.asarray(angles, dtype=float) - current)))
        self.set_servo_deg(angles)
        self.solves += 1
        self.problem.solve_step(LoadStep(self.steps[-1].label, angles=self.steps[-1].angles,
                                         increments=max(1, math.ceil(change / increment_deg - 1e-9))))
        return self.values()

    def solve_last_step(self, increment_deg: float = 10.0) -> dict[str, float]:
        """Move the last step's servo angles and load factors to their set values from the current equilibrium.

        One scene solve; the step's own increments, more if a servo turns by more than ``increment_deg`` per
        increment. The current state must be an equilibrium of the last step.
        """
        from dataclasses import replace
        last = self.steps[-1]
        change = max([abs(math.degrees(a - self.problem.loads.angles[n])) for n, a in last.angles.items()],
                     default=0.0)
        self.solves += 1
        self.problem.solve_step(replace(last, increments=max(last.increments,
                                                             math.ceil(change / increment_deg - 1e-9))))
        return self.values()

    # ----------------------------------------------------------------------------------------------
    # Gradients
    # ----------------------------------------------------------------------------------------------
    @property
    def adjoint(self):
        """The adjoint solver (:class:`fenicsfoam.sensitivity.Adjoint`), built at the first use."""
        if self._adjoint is None:
            from fenicsfoam.sensitivity import Adjoint
            self._adjoint = Adjoint(self.problem, prefix="design_adjoint_")
        return self._adjoint

    def gradient(self, probes: Sequence[str], parameters: Sequence[str]) -> dict[str, dict[str, Any]]:
        """``{probe: {parameter: d probe / d parameter}}`` at the current equilibrium, by the adjoint.

        Scalars for scalar parameters, arrays over the owned cells for per-cell ones (zero where a cell's
        parameter has no effect, e.g. the density of a cell of fixed material). Collective.
        """
        for name in parameters:
            self._check(name)
        for name in probes:
            if name not in self.probes:
                raise InputError(f"probe {name!r} is not built (probes: {sorted(self.probes)})")
            if not hasattr(self.probes[name], "gradient"):
                differentiable = sorted(k for k, p in self.probes.items() if hasattr(p, "gradient"))
                raise InputError(f"probe {name!r} has no gradient; differentiable probes of this scene: "
                                 f"{differentiable}")
        from fenicsfoam.sensitivity import material_coefficients

        actuators = [p for p in parameters if p in self.actuators]
        material = [p for p in parameters if p not in self.servos and p not in actuators
                    and not p.startswith("orientation")]
        oriented = [p for p in parameters if p.startswith("orientation")]
        coefficients = material_coefficients(self.problem)
        fields = {}
        if material:
            fields.update({n: c for n, c in coefficients.items() if n != "orientation"})
            derivatives = self.cells.derivatives()
        if oriented:
            fields["orientation"] = coefficients["orientation"]
        motions = [p for p in parameters if p in self.servos]
        adjoint = self.adjoint
        adjoint.factor()
        result = {}
        comm = self.comm
        for name in probes:
            g = adjoint.gradient(self.probes[name], fields, motions, actuators)
            out: dict[str, Any] = {}
            for p in motions:
                out[p] = g.motions[p] * math.pi / 180.0
            for p in actuators:
                out[p] = g.loads[p]
            if material:
                per_cell = {k: sum(g.fields[n] * derivatives[k][n] for n in derivatives[k])
                            for k in ("density", "gamma", "E_solid")}
                for p in material:
                    if p in ("density", "gamma"):
                        out[p] = per_cell[p]
                    elif p == "E_solid":
                        out[p] = comm.allreduce(float(np.sum(per_cell["E_solid"])))
                    else:
                        key, region = p.split(":", 1)
                        out[p] = comm.allreduce(float(np.sum(per_cell[key] * self.cells.region_derivative(key,
                                                                                                         region))))
            if oriented:
                per_cell = np.einsum("ck,ck->c", g.fields["orientation"], self.orientation.d_angle())
                for p in oriented:
                    if p == "orientation":
                        out[p] = per_cell
                    elif p == "orientation.offset_deg":
                        out[p] = comm.allreduce(float(np.sum(per_cell)))
                    else:
                        out[p] = comm.allreduce(float(np.sum(np.einsum("ck,ck->c", g.fields["orientation"],
                                                                       self.orientation.d_pitch()))))
            result[name] = out
        return result

    # ----------------------------------------------------------------------------------------------
    def gather(self, values: np.ndarray) -> np.ndarray:
        """A per-cell array over the owned cells → the global array (ranks' cells in order) on every rank."""
        return np.concatenate(self.comm.allgather(np.asarray(values)))

    def scatter(self, values: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`gather`: this rank's part of a global per-cell array."""
        counts = self.comm.allgather(self.n_cells)
        start = int(np.sum(counts[:self.comm.rank]))
        return np.asarray(values)[start:start + self.n_cells]

    def write_orientation_picture(self, path: str | os.PathLike, title: str = "") -> None:
        """A top view of the *l* axes (the scene outputs' orientation picture) at ``path`` (rank 0 writes)."""
        from pathlib import Path

        from fenicsfoam.plotting import plot_orientation
        plot_orientation(self.problem.orientation, Path(path), title=title or f"{self.scene.name}: l axis")


# --------------------------------------------------------------------------------------------------
# Optimisation of a probe under a bound on another
# --------------------------------------------------------------------------------------------------
@dataclass
class DesignHistory:
    """What an optimisation did: every evaluation (one scene solve each) and every accepted iterate."""

    evaluations: list[dict[str, Any]] = field(default_factory=list)  #: solves, objective, change, feasible (box, bound)
    iterates: list[dict[str, Any]] = field(default_factory=list)     #: iteration, solves, objective, change

    def solves_to_reach(self, level: float) -> int | None:
        """Scene solves until a feasible evaluation (in the box, within the bound) first reached ``level``."""
        for e in self.evaluations:
            if e["objective"] >= level and e["feasible"]:
                return e["solves"]
        return None


@dataclass
class DesignResult:
    """The outcome of :func:`optimize_probe` or :func:`match_probes`."""

    parameters: dict[str, Any]     #: the best feasible design found (scalars; per-cell arrays global, gathered)
    objective: float               #: its objective (the probe, signed so that larger is better)
    change: float                  #: its change of the bounded probe from the initial design
    initial_objective: float
    solves: int                    #: scene solves used
    history: DesignHistory
    message: str
    achieved: dict[str, float] = field(default_factory=dict)  #: the targeted probes (:func:`match_probes`)


def optimize_probe(design: SceneDesign, probe: str, parameters: Sequence[str], bounds: Mapping[str, tuple],
                   *, maximize: bool = True, bounded: str = "center_height", bound: float = 1e-3,
                   method: str = "SLSQP", maxiter: int = 20, scales: Mapping[str, float] | None = None,
                   penalty: float = 10.0) -> DesignResult:
    """Maximise (or minimise) a probe at the last step, keeping another within a bound of its initial value.

    ``scipy.optimize`` with adjoint gradients, or a gradient-free method for comparison.

    Parameters
    ----------
    design
        The scene (its current parameters are the initial design).
    probe
        The probe to maximise (``maximize``) or minimise; the objective is the probe signed so that larger is
        better.
    parameters, bounds
        Parameter names (:meth:`SceneDesign.parameters`; per-cell ones allowed) and ``{name: (lo, hi)}``.
    maximize
        Maximise (default) or minimise ``probe``.
    bounded, bound
        ``|bounded − bounded₀| <= bound`` (in the probe's units, e.g. m).
    method
        ``"SLSQP"`` (the bound as two inequality constraints, adjoint gradients), ``"L-BFGS-B"`` (the bound as
        a quadratic penalty ``penalty · (excess / bound)²`` in the objective's units, adjoint gradients; for many
        parameters) or ``"COBYLA"`` (gradient-free, the bound and the box as constraints).
    maxiter
        Iterations of the method.
    scales
        Typical size of each parameter (the optimiser sees ``value / scale``); default 1.
    penalty
        Weight of the L-BFGS-B penalty.

    Every evaluation is one scene solve (:meth:`SceneDesign.solve`) plus, for the gradient methods, one adjoint
    factorization and two adjoint solves. If the method's last design exceeds the bound (an SQP method approaches
    an active bound from either side) and beats every feasible evaluation, up to three Newton steps on the bounded
    probe bring it onto the bound (:func:`_restore_bound`). The result is the best feasible evaluation; the design
    is left there.

    """
    from scipy import optimize

    if method not in ("SLSQP", "L-BFGS-B", "COBYLA"):
        raise InputError(f"method must be SLSQP, L-BFGS-B or COBYLA, got {method!r}")
    for name in (probe, bounded):
        if name not in design.probes:
            raise InputError(f"probe {name!r} is not built (probes: {sorted(design.probes)})")
    for name in parameters:
        design._check(name)
        if name not in bounds:
            raise InputError(f"parameter {name!r} has no bounds")
    scales = {n: 1.0 for n in parameters} | dict(scales or {})
    sign = 1.0 if maximize else -1.0
    # the vector of unknowns: scalars, then per-cell arrays gathered in the ranks' order
    layout, start = [], 0
    x0 = []
    for name in parameters:
        value = design.get(name)
        if isinstance(value, np.ndarray):
            glob = np.nan_to_num(design.gather(value))
            layout.append((name, start, glob.size, True))
            x0.append(glob / scales[name])
            start += glob.size
        else:
            layout.append((name, start, 1, False))
            x0.append(np.array([value / scales[name]]))
            start += 1
    x0 = np.concatenate(x0)
    lower = np.concatenate([np.full(n, bounds[name][0] / scales[name]) for name, _, n, _ in layout])
    upper = np.concatenate([np.full(n, bounds[name][1] / scales[name]) for name, _, n, _ in layout])
    if np.any(x0 < lower - 1e-12) or np.any(x0 > upper + 1e-12):
        raise InputError("the initial design lies outside the bounds")

    cache: dict[bytes, dict[str, Any]] = {}
    history = DesignHistory()
    baseline: dict[str, float] = {}
    loaded = {"key": None}  # the design whose equilibrium the problem holds (the same on every rank)

    def unpack(x):
        values = {}
        for name, s0, n, cellwise in layout:
            part = x[s0:s0 + n] * scales[name]
            values[name] = design.scatter(part) if cellwise else float(part[0])
        return values

    def evaluate(x, gradient: bool):
        key = np.asarray(x, dtype=float).tobytes()
        entry = cache.get(key)
        if entry is None:
            design.set(unpack(x))
            values = design.solve()
            loaded["key"] = key
            if not baseline:
                baseline.update(values)
            inside = bool(np.all(x >= lower - 1e-9) and np.all(x <= upper + 1e-9))
            entry = {"objective": sign * values[probe], "change": values[bounded] - baseline[bounded],
                     "feasible": inside and abs(values[bounded] - baseline[bounded]) <= bound * (1 + 1e-9)}
            cache[key] = entry
            history.evaluations.append({"solves": design.solves - solves0, **entry})
            entry["state"] = design.problem.snapshot()
            entry["x"] = np.array(x, dtype=float)
        if gradient and "gradient" not in entry:
            if loaded["key"] != key:  # a decision every rank takes alike: set and restore are collective
                design.set(unpack(x))
                design.problem.restore(entry["state"])
                loaded["key"] = key
            g = design.gradient([probe, bounded], list(parameters))
            flat = {}
            for which in (probe, bounded):
                parts = []
                for name, _, _, cellwise in layout:
                    value = g[which][name]
                    parts.append((design.gather(value) if cellwise else np.array([value])) * scales[name])
                flat[which] = np.concatenate(parts)
            entry["gradient"] = (sign * flat[probe], flat[bounded])
        return entry

    solves0 = design.solves
    initial = evaluate(x0, gradient=False)
    iteration = [0]

    def record(x):
        e = evaluate(x, gradient=False)
        iteration[0] += 1
        history.iterates.append({"iteration": iteration[0], "solves": design.solves - solves0,
                                 "objective": e["objective"], "change": e["change"]})
        logger.info("design iteration %d: objective %.6g, %s change %.3g, %d solves", iteration[0],
                    e["objective"], bounded, e["change"], design.solves - solves0)

    history.iterates.append({"iteration": 0, "solves": 1, "objective": initial["objective"],
                             "change": initial["change"]})
    if method == "SLSQP":
        constraints = [
            {"type": "ineq", "fun": lambda x: (bound - evaluate(x, False)["change"]) / bound,
             "jac": lambda x: -evaluate(x, True)["gradient"][1] / bound},
            {"type": "ineq", "fun": lambda x: (bound + evaluate(x, False)["change"]) / bound,
             "jac": lambda x: evaluate(x, True)["gradient"][1] / bound}]
        out = optimize.minimize(lambda x: -evaluate(x, False)["objective"], x0, method="SLSQP",
                                jac=lambda x: -evaluate(x, True)["gradient"][0], bounds=list(zip(lower, upper)),
                                constraints=constraints, callback=record,
                                options={"maxiter": maxiter, "ftol": 1e-9})
    elif method == "L-BFGS-B":
        def penalised(x):
            e = evaluate(x, True)
            excess = abs(e["change"]) - bound
            value = -e["objective"] + (penalty * (excess / bound) ** 2 if excess > 0 else 0.0)
            grad = -e["gradient"][0]
            if excess > 0:
                grad = grad + 2.0 * penalty * excess / bound**2 * np.sign(e["change"]) * e["gradient"][1]
            e["penalised"] = value
            return value, grad

        def record_penalised(x):
            record(x)
            history.iterates[-1]["penalised"] = evaluate(x, False)["penalised"]

        history.iterates[0]["penalised"] = penalised(x0)[0]
        out = optimize.minimize(penalised, x0, method="L-BFGS-B", jac=True, bounds=list(zip(lower, upper)),
                                callback=record_penalised, options={"maxiter": maxiter})
    else:
        constraints = [{"type": "ineq", "fun": lambda x: (bound - evaluate(x, False)["change"]) / bound},
                       {"type": "ineq", "fun": lambda x: (bound + evaluate(x, False)["change"]) / bound},
                       {"type": "ineq", "fun": lambda x: x - lower}, {"type": "ineq", "fun": lambda x: upper - x}]
        out = optimize.minimize(lambda x: -evaluate(x, False)["objective"], x0, method="COBYLA",
                                constraints=constraints, callback=record,
                                options={"maxiter": maxiter, "rhobeg": 0.25, "tol": 1e-6})
    _restore_bound(evaluate, np.clip(np.asarray(out.x, dtype=float), lower, upper), lower, upper, bound,
                   max((e["objective"] for e in cache.values() if e["feasible"]), default=-np.inf))
    feasible = [e for e in cache.values() if e["feasible"]]
    best = max(feasible, key=lambda e: e["objective"]) if feasible else initial
    design.set(unpack(best["x"]))
    design.problem.restore(best["state"])
    result_parameters = {name: (best["x"][s0:s0 + n] * scales[name] if cellwise else float(best["x"][s0]
                                                                                           * scales[name]))
                         for name, s0, n, cellwise in layout}
    return DesignResult(result_parameters, best["objective"], best["change"], initial["objective"],
                        design.solves - solves0, history, str(out.message))


def _restore_bound(evaluate, x: np.ndarray, lower: np.ndarray, upper: np.ndarray, bound: float,
                   best_feasible: float, steps: int = 3) -> None:
    """Bring the optimiser's last design onto the bound it exceeds, if it beats every feasible evaluation.

    An SQP method's iterates approach an active constraint from either side, so a search stopped by its iteration
    limit may end just beyond the bound (e.g. 1.000015 mm for 1 mm), better than any feasible design it has
    evaluated. Newton steps on the bounded probe, least-norm in the scaled parameters and within the box,
    ``x ← x − (c − c_b) ∇c / |∇c|²`` (``c`` the change, ``c_b = ±bound`` the bound it exceeds), until it is met
    (at most ``steps``); each step is an evaluation of the search (cached, in its history).
    """
    for _ in range(steps):
        entry = evaluate(x, False)
        if entry["feasible"] or entry["objective"] <= best_feasible:
            return
        if np.any(x < lower - 1e-9) or np.any(x > upper + 1e-9) or abs(entry["change"]) <= bound:
            return
        grad = evaluate(x, True)["gradient"][1]
        norm2 = float(grad @ grad)
        if not norm2 > 0:
            return
        excess = entry["change"] - math.copysign(bound, entry["change"])
        logger.info("design: the last design exceeds the bound by %.3g; a Newton step onto it", excess)
        x = np.clip(x - excess * grad / norm2, lower, upper)
    evaluate(x, False)


#: The scale of a probe's misfit in :func:`match_probes` (its units): 1 mm for lengths, 1 degree for angles.
MISFIT_SCALES: dict[str, float] = {"center_height": 1e-3, "tip_deflection": 1e-3, "center_rotation": 1.0,
                                   "center_tilt_x": 1.0, "center_tilt_y": 1.0}


def match_probes(design: SceneDesign, targets: Mapping[str, float], parameters: Sequence[str],
                 bounds: Mapping[str, tuple], *, scales: Mapping[str, float] | None = None, tol: float = 1e-10,
                 max_solves: int = 40) -> DesignResult:
    """Find scalar parameters whose probes at the last step equal ``targets`` (e.g. the offset giving a twist).

    Bounded Gauss–Newton (``scipy.optimize.least_squares``, trust-region reflective) on the misfits
    ``(probe − target) / s`` (``s``: :data:`MISFIT_SCALES`, 1 mm or 1°), with the adjoint gradients as the
    Jacobian: one scene solve and one factorization with one adjoint solve per target per evaluation. As many
    targets as parameters: the solution of the equations; fewer: a solution near the initial design (the method's
    steps are least-norm in the scaled parameters); a target out of reach (beyond the bounds, or beyond the most
    the parameters can give): the bounded least-squares fit, the closest design (compare ``achieved`` with the
    targets; it is not an error).

    Parameters
    ----------
    design
        The scene (its current parameters are the initial design; it is left at the result).
    targets
        ``{probe: value}`` in the probe's units (m, deg).
    parameters, bounds, scales
        Scalar parameter names (:meth:`SceneDesign.parameters`), ``{name: (lo, hi)}``, typical sizes (default 1).
    tol
        Relative tolerance on the scaled parameters and the misfit (``least_squares``' ``xtol``, ``ftol``).
    max_solves
        Scene solves at most.

    Returns
    -------
    DesignResult
        ``objective`` = −|misfit|² / 2 (0 when the targets are met), ``change`` = 0, ``history`` with every
        evaluation (``iterates``: the same, one per solve), ``achieved`` the targeted probes.

    """
    from scipy import optimize

    if not targets:
        raise InputError("match_probes: give at least one target {probe: value}")
    for name, value in targets.items():
        if name not in design.probes:
            raise InputError(f"probe {name!r} is not built (probes: {sorted(design.probes)})")
        if not math.isfinite(float(value)):
            raise InputError(f"target {name} = {value!r} is not a finite number")
    for name in parameters:
        design._check(name)
        if isinstance(design.get(name), np.ndarray):
            raise InputError(f"match_probes takes scalar parameters; {name!r} is per cell (use optimize_probe)")
        if name not in bounds:
            raise InputError(f"parameter {name!r} has no bounds")
    scales = {n: 1.0 for n in parameters} | dict(scales or {})
    names = list(targets)
    s = np.array([MISFIT_SCALES.get(n, 1.0) for n in names])
    t = np.array([float(targets[n]) for n in names])
    x0 = np.array([design.get(n) / scales[n] for n in parameters])
    lower = np.array([bounds[n][0] / scales[n] for n in parameters])
    upper = np.array([bounds[n][1] / scales[n] for n in parameters])
    if np.any(x0 < lower) or np.any(x0 > upper):
        raise InputError(f"the initial design {dict(zip(parameters, x0 * [scales[n] for n in parameters]))} lies "
                         f"outside the bounds {dict(bounds)}")
    history = DesignHistory()
    solves0 = design.solves
    state: dict[str, Any] = {}

    def at(x):
        x = np.asarray(x, dtype=float)
        if state.get("x") is None or not np.array_equal(state["x"], x):
            design.set({n: float(v) * scales[n] for n, v in zip(parameters, x)})
            values = design.solve()
            f = np.array([values[n] for n in names])
            state.update(x=x.copy(), f=f, jac=None)
            misfit = (f - t) / s
            history.evaluations.append({"solves": design.solves - solves0, "objective": -0.5 * float(misfit @ misfit),
                                        "change": 0.0, "feasible": True,
                                        "parameters": {n: float(v) * scales[n] for n, v in zip(parameters, x)},
                                        "probes": dict(zip(names, f.tolist()))})
            logger.info("match_probes: %s -> %s", history.evaluations[-1]["parameters"], dict(zip(names, f)))
        return state

    def residual(x):
        return (at(x)["f"] - t) / s

    def jacobian(x):
        entry = at(x)
        if entry["jac"] is None:
            g = design.gradient(names, list(parameters))
            entry["jac"] = np.array([[g[k][p] * scales[p] for p in parameters] for k in names]) / s[:, None]
        return entry["jac"]

    initial = -0.5 * float(residual(x0) @ residual(x0))
    out = optimize.least_squares(residual, x0, jac=jacobian, bounds=(lower, upper), method="trf", x_scale=1.0,
                                 xtol=tol, ftol=tol, gtol=tol, max_nfev=max_solves)
    best = max(range(len(history.evaluations)), key=lambda i: history.evaluations[i]["objective"])
    x_best = np.array([history.evaluations[best]["parameters"][n] / scales[n] for n in parameters])
    at(x_best)  # the design is left at the best evaluation (a solve only if the last one was not it)
    for i, e in enumerate(history.evaluations):
        history.iterates.append({"iteration": i, "solves": e["solves"], "objective": e["objective"], "change": 0.0})
    return DesignResult(dict(history.evaluations[best]["parameters"]), history.evaluations[best]["objective"], 0.0,
                        initial, design.solves - solves0, history, str(out.message),
                        dict(history.evaluations[best]["probes"]))
