"""Calibrate the printed solid's modulus ``E_solid`` on one measurement: a scalar root find over scene runs.

The datasheet modulus of a filament is not the modulus of its printed strands. :func:`calibrate_E_solid` finds
the one scalar ``E_solid``, shared by every foam region of a scene, for which a probe at a load step matches a
measured value (e.g. the Fig. 6 isotropic beam's tip deflection, −48 mm). Every other quantity is then a
prediction. The result is written as ``calibration.json``::

    {"E_solid": 3.1e7, "probe": "tip_deflection", "target": -0.048, "achieved": -0.048, "runs": 3, ...,
     "foam_tables": [{"table": "cube", "sha256": "9f2c…", "regions": ["beam"]}]}

and a scene takes it with ``E_solid = {calibration = "calibration.json"}`` in a foam region (path relative to the
scene file), read by :func:`read_calibration`.

Foam tables. The calibrated ``E_solid`` absorbs the bias of the foam table its scene's foam regions read (the same
measurement gives another modulus through another table), so ``foam_tables`` records those tables (the label, a
shipped name or a CSV path, and the SHA-256 of the table file; :func:`foam_table_records`), and a region that takes
the calibration must read one of them (compared by content, :func:`check_calibration_table`): otherwise the scene is
refused with an error naming the region, both tables and what to do, calibrate through the region's table. A file
without ``foam_tables`` (written before the record existed) is taken as calibrated through the default table
:data:`LEGACY_TABLE`, ``"cube"``.

Method. A foam's moduli are proportional to ``E_solid`` (its mass is not), so with the linear model the
displacement is exactly ``u = u_D + u_f / E_solid`` (``u_D``: the response to prescribed motions, ``u_f``: to
gravity at unit modulus), and a probe that is affine in ``u`` (``tip_deflection``, ``center_height``,
``displacement:GROUP``) is ``p = a + b / E_solid``. Two runs give ``a`` and ``b``, hence
``E_solid = b / (target − a)`` and the reachable range (``a`` excluded, on the side of ``b``), and a third run
checks it. That affine model is also the initial guess otherwise (nonlinear models, ``center_rotation``, reactions
and volumes): the root is then bracketed from the guess by steps of a factor 2 in ``E_solid`` and found by
Brent's method on ``log E_solid`` (``scipy.optimize.brentq``) to a relative tolerance ``rtol`` of ``E_solid``.
Runs are memoised, so a value is never computed twice.

A group probe (``"KIND:GROUP"``) may be matched too; a vector probe needs the component to match
(``component = "x"``, ``"y"`` or ``"z"``). A reaction depends on ``E_solid`` where a displacement is prescribed
against the foam's stiffness (e.g. the force to push a group 5 mm in); a clamp's reaction to gravity alone does not
(it carries the weight whatever the modulus) and is refused: a probe that changes by less than 1e-9 of its value
when ``E_solid`` doubles is round-off of the solves, not a dependence.

Command line: ``fenicsfoam calibrate SCENE.toml --probe NAME [--component x|y|z] --step LABEL --target VALUE
[--relative-to LABEL] --out DIR`` (:data:`CALIBRATE`).

Errors (:class:`CalibrationError`, raised before any run where possible): an unknown probe or step, a vector
probe without a component (or a component of a number), a non-finite target, a scene without foam regions or
whose foam regions disagree on ``E_solid``, a probe that does not depend on ``E_solid`` (e.g. the reaction to
gravity and forces alone), a target outside the reachable range (wrong sign, or beyond the asymptote of an
infinitely stiff solid), a target not bracketed within ``E_range`` or needing a solid so soft that the scene no
longer converges.
"""

from __future__ import annotations

import copy
import logging
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fenicsfoam.material import MATERIAL_KINDS, MAX_MODULUS, tabulated_regions
from fenicsfoam.scene.calibration import (
    LEGACY_TABLE,
    CalibrationError,
    calibration_tables,
    check_calibration_table,
    foam_table_records,
    read_calibration,
)
from foambase.files import write_json_atomic

__all__ = [
    "AFFINE_GROUP_KINDS",
    "AFFINE_PROBES",
    "COMPONENTS",
    "CALIBRATE",
    "Calibration",
    "CalibrationError",
    "LEGACY_TABLE",
    "calibrate_E_solid",
    "calibration_tables",
    "check_calibration_table",
    "foam_table_records",
    "read_calibration",
    "scene_with_E_solid",
    "write_calibration",
]

logger = logging.getLogger(__name__)

#: Probes that are affine functions of the displacement (integrals of u): exact in two runs with the linear model
#: (with the group probe kind ``displacement:GROUP``, :data:`AFFINE_GROUP_KINDS`).
AFFINE_PROBES = frozenset({"tip_deflection", "center_height"})
#: Group probe kinds (``"KIND:GROUP"``) that are affine functions of the displacement.
AFFINE_GROUP_KINDS = frozenset({"displacement"})
#: The components a vector probe's ``component`` may name.
COMPONENTS = ("x", "y", "z")
#: Name of the file :func:`calibrate_E_solid` writes in ``out_dir``.
CALIBRATION_JSON = "calibration.json"


@dataclass(frozen=True)
class Calibration:
    """The calibrated modulus and how it was found (``to_dict()`` is ``calibration.json``)."""

    E_solid: float                    #: Pa
    probe: str
    step: str
    target: float                     #: the measured value (SI, angles in degrees)
    achieved: float                   #: the probe at ``E_solid``
    runs: int                         #: scene runs done
    relative_to: str | None = None    #: the probe is a change from this step, if given
    method: str = ""
    scene: str = ""
    E_solid_initial: float = math.nan  #: the scene's own E_solid (Pa), the search's starting point
    history: tuple[tuple[float, float], ...] = field(default_factory=tuple)  #: (E_solid, probe) of every run
    component: str | None = None      #: the component matched of a vector probe (``"x"``, ``"y"``, ``"z"``)
    #: the foam tables the scene's foam regions read: ``{"table": label, "sha256": digest, "regions": [names]}``
    foam_tables: tuple[dict[str, Any], ...] = field(default_factory=tuple)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict: ``E_solid``, ``probe``, ``target``, ``achieved``, ``runs`` and the details."""
        return {"E_solid": self.E_solid, "probe": self.probe, "component": self.component, "target": self.target,
                "achieved": self.achieved, "runs": self.runs, "step": self.step, "relative_to": self.relative_to,
                "method": self.method, "scene": self.scene, "E_solid_initial": self.E_solid_initial,
                "history": [list(h) for h in self.history], "foam_tables": [dict(t) for t in self.foam_tables]}


def _load_raw(source) -> tuple[dict[str, Any], Path | None]:
    """The scene as a dict and the directory relative paths refer to."""
    if isinstance(source, Mapping):
        return copy.deepcopy(dict(source)), None
    import tomllib

    from fenicsfoam.scene import SceneError
    path = Path(source)
    try:
        with path.open("rb") as f:
            return tomllib.load(f), path.parent
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise SceneError(f"cannot read scene {path}: {exc}") from exc


def scene_with_E_solid(data: Mapping[str, Any], E_solid: float) -> dict[str, Any]:
    """A copy of a scene dict with ``E_solid`` set in every foam region (the only change).

    For a scene as ``tomllib`` reads it; a parsed scene is varied with :func:`fenicsfoam.scene.vary_scene`.
    """
    out = copy.deepcopy(dict(data))
    for region in out.get("regions", {}).values():
        material = region.get("material") if isinstance(region, dict) else None
        kind = MATERIAL_KINDS.get(material) if isinstance(material, str) else None
        if kind is not None and kind.key("E_solid") is not None:
            region["E_solid"] = float(E_solid)
    return out


def _check_probe(probe: str, component: str | None) -> None:
    """A known probe name (or ``KIND:GROUP``), with a component exactly when it is a vector."""
    from fenicsfoam.scene import PROBES
    from fenicsfoam.scene.kinds import GROUP_PROBE_KINDS, probe_size

    kind, colon, group = probe.partition(":") if isinstance(probe, str) else ("", "", "")
    if not (probe in PROBES or (colon and kind in GROUP_PROBE_KINDS and group)):
        raise CalibrationError(f"probe {probe!r} is unknown; valid: {', '.join(PROBES)}, or KIND:GROUP with KIND "
                               f"one of {', '.join(GROUP_PROBE_KINDS)}")
    if probe_size(probe) > 1 and component not in COMPONENTS:
        given = "" if component is None else f" ({component!r} is not one)"
        raise CalibrationError(f"probe {probe!r} is a vector (x, y, z): give the component to match, 'x', 'y' or "
                               f"'z' (--component){given}")
    if probe_size(probe) == 1 and component is not None:
        raise CalibrationError(f"probe {probe!r} is a number, not a vector: give no component (got {component!r})")


def _validate(data: dict[str, Any], base: Path | None, probe: str, step: str, relative_to: str | None,
              target: float, component: str | None = None) -> tuple[Any, float]:
    """Check the request against the scene (before any run); returns the parsed scene and the initial E_solid."""
    from fenicsfoam.scene import parse_scene

    _check_probe(probe, component)
    if isinstance(target, bool) or not isinstance(target, int | float) or not math.isfinite(target):
        raise CalibrationError(f"target {target!r} must be a finite number (SI units, angles in degrees)")
    probes = list(data.get("probes", []))
    if probe not in probes:
        data["probes"] = probes + [probe]
    data["outputs"] = {"xdmf": False, "png": False}
    scene = parse_scene(data, base)
    labels = [s.label for s in scene.steps]
    for name, label in (("step", step), ("relative_to", relative_to)):
        if label is not None and label not in labels:
            raise CalibrationError(f"{name} {label!r} is not a step of scene {scene.name!r}; its steps: {labels}")
    if relative_to == step:
        raise CalibrationError(f"relative_to {relative_to!r} is the calibrated step itself: the change is always 0")
    foams = {r.name: r.parameters["E_solid"] for r in tabulated_regions(scene.regions)}
    if not foams:
        raise CalibrationError(f"scene {scene.name!r} has no foam region: E_solid calibrates the foams' solid; "
                               "its regions are " + ", ".join(f"{r.name} ({r.material})" for r in scene.regions))
    if len(set(foams.values())) > 1:
        raise CalibrationError(f"the foam regions of scene {scene.name!r} have different E_solid ({foams}); a "
                               "calibration finds one E_solid shared by every foam region: make them equal first")
    return scene, next(iter(foams.values()))


def _check_variations(scene, E0: float, lo: float, hi: float, E_range) -> None:
    """Every E_solid the calibration may run (the two first runs, the ends of the search) is one the scene takes.

    The root find stays in ``[lo, hi]`` and a foam region's other constants do not change, so the ends stand for
    every value between them: a refusal is named before any run, not after the first ones.
    """
    from fenicsfoam.scene import vary_scene

    for what, E in (("the second run (2 × the initial E_solid)", 2.0 * E0),
                    (f"the {'default search range' if E_range is None else 'E_range'}'s lower end", lo),
                    (f"the {'default search range' if E_range is None else 'E_range'}'s upper end", hi)):
        try:
            vary_scene(scene, {"E_solid": E})
        except ValueError as exc:  # SceneError, InadmissibleMaterialError
            raise CalibrationError(f"E_solid = {E:.6g} Pa, {what}, is refused by scene {scene.name!r} before any "
                                   f"run: {exc}") from exc


class _Runs:
    """Memoised probe values ``p(E_solid)`` from runs of the scene varied in ``E_solid`` (:func:`vary_scene`)."""

    def __init__(self, scene, probe, step, relative_to, comm, component=None):
        self.scene, self.probe, self.step, self.relative_to, self.comm = scene, probe, step, relative_to, comm
        self.index = None if component is None else COMPONENTS.index(component)
        self.values: dict[float, float] = {}

    def __call__(self, E: float) -> float:
        from fenicsfoam.scene import run_scene, vary_scene
        if E not in self.values:
            result = run_scene(vary_scene(self.scene, {"E_solid": E}), comm=self.comm)
            values = result.probe(self.probe, relative_to=self.relative_to)
            value = values[self.step]
            self.values[E] = float(value if self.index is None else value[self.index])
            logger.info("calibration run %d: E_solid = %.10g Pa -> %s = %.10g", len(self.values), E, self.probe,
                        self.values[E])
        return self.values[E]

    @property
    def history(self) -> tuple[tuple[float, float], ...]:
        return tuple(self.values.items())


def calibrate_E_solid(source, probe: str, step: str, target: float, *, relative_to: str | None = None,
                      component: str | None = None, rtol: float = 1e-10, E_range: tuple[float, float] | None = None,
                      max_runs: int = 60, out_dir: str | os.PathLike | None = None, comm=None) -> Calibration:
    """Find the ``E_solid`` of every foam region for which ``probe`` at ``step`` equals ``target``.

    Parameters
    ----------
    source
        A scene file (TOML) or a dict as ``tomllib`` reads one; its foam regions must share one ``E_solid``,
        the initial guess.
    probe, step
        The probe (e.g. ``"tip_deflection"``; added to the scene's probes if absent) and the label of the step.
    target
        The measured value, in the probe's SI unit (m, or degrees for ``center_rotation``).
    relative_to
        Calibrate the change of the probe from this step (e.g. ``"rest"`` for Table I's changes).
    component
        For a vector probe (``reaction_force:GROUP``, ``displacement:GROUP``, ``rotation:GROUP``): the component
        matched, ``"x"``, ``"y"`` or ``"z"``; ``None`` (required) for a number.
    rtol
        Relative tolerance on ``E_solid`` of the root find.
    E_range
        ``(lowest, highest)`` E_solid searched (Pa); default 1e-3 to 1e3 times the initial value.
    max_runs
        Most scene runs allowed.
    out_dir
        If given, ``out_dir/calibration.json`` is written (atomically, on rank 0); the directory is checked before
        any run (created if needed; other files in it stay).
    comm
        MPI communicator of the runs (default ``MPI.COMM_WORLD``).

    Raises
    ------
    CalibrationError
        Bad input (before any run) or an unreachable target, naming the value.
    fenicsfoam.scene.SceneError
        The scene itself is invalid.

    """
    from mpi4py import MPI
    from scipy.optimize import brentq

    from fenicsfoam.solver import ConvergenceError
    comm = MPI.COMM_WORLD if comm is None else comm
    if out_dir is not None:  # before any work: a directory that can take calibration.json
        from foambase.files import check_output_dir
        from foambase.mpi import on_rank0
        on_rank0(comm, lambda: check_output_dir(out_dir, "out_dir"), f"the output directory {out_dir} cannot be used")
    data, base = _load_raw(source)
    scene, E0 = _validate(data, base, probe, step, relative_to, target, component)
    target = float(target)
    lo, hi = ((E0 * 1e-3, min(E0 * 1e3, MAX_MODULUS)) if E_range is None
              else (float(E_range[0]), float(E_range[1])))
    if not (0 < lo < hi and math.isfinite(hi)):
        raise CalibrationError(f"E_range {E_range!r} must be two increasing positive moduli (Pa)")
    _check_variations(scene, E0, lo, hi, E_range)
    runs = _Runs(scene, probe, step, relative_to, comm, component)
    what = (f"{probe}" + (f" ({component})" if component else "") + f" at step {step!r}"
            + (f" relative to {relative_to!r}" if relative_to else ""))

    def value(E: float) -> float:
        if len(runs.values) >= max_runs and E not in runs.values:
            raise CalibrationError(f"calibration of {what} to {target!r} did not converge in {max_runs} runs; "
                                   f"runs (E_solid, value): {runs.history}")
        try:
            return runs(E)
        except ConvergenceError as exc:
            raise CalibrationError(f"target {target!r} for {what} needs E_solid near {E:.6g} Pa, where scene "
                                   f"{scene.name!r} does not converge ({exc}); runs (E_solid, value): "
                                   f"{runs.history}") from exc

    # Two runs: the affine model p = a + b / E (exact for the linear model and affine probes).
    E1 = 2.0 * E0
    p0, p1 = value(E0), value(E1)
    b = (p0 - p1) / (1.0 / E0 - 1.0 / E1)
    a = p0 - b / E0
    if b == 0.0 or abs(b / E0) <= 1e-9 * max(abs(p0), abs(p1)):  # round-off of a solve, not a dependence
        raise CalibrationError(f"{what} does not depend on E_solid ({p0!r} at {E0:.6g} Pa, {p1!r} at {E1:.6g} "
                               f"Pa): target {target!r} cannot be reached by calibrating E_solid")
    exact = scene.model == "linear" and (probe in AFFINE_PROBES or probe.partition(":")[0] in AFFINE_GROUP_KINDS)
    if (target - a) * b <= 0.0:
        side = "above" if b > 0 else "below"
        message = (f"target {target!r} is not reachable: {what} is {p0:.6g} at E_solid = {E0:.6g} Pa and tends "
                   f"to {a:.6g} for an infinitely stiff solid, so only values {side} {a:.6g} can be reached"
                   + (" (wrong sign?)" if target * p0 < 0 else ""))
        if exact:
            raise CalibrationError(message)
        logger.warning("%s (affine estimate; searching E_range anyway for this nonlinear case)", message)
    guess = b / (target - a) if (target - a) * b > 0 else (lo if b * (target - p0) > 0 else hi)
    guess = min(max(guess, lo), hi)
    if exact:
        method = "affine in 1/E_solid (linear model): two runs, then a check"
        E = guess
        achieved = value(E)
        if abs(achieved - target) > 1e-8 * max(abs(target), abs(a)):
            raise CalibrationError(f"the linear-model calibration of {what} missed: {achieved!r} at E_solid = "
                                   f"{E!r} Pa instead of {target!r} (is the probe affine in u?)")
    else:
        method = "Brent's method on log E_solid from the affine guess"
        f = {}

        def residual(logE: float) -> float:
            if logE not in f:
                f[logE] = value(math.exp(logE)) - target
            return f[logE]

        # bracket: from the guess, step by a factor 2 towards the sign change
        x0 = math.log(guess)
        r0 = residual(x0)
        if r0 == 0.0:
            E = guess
        else:
            # the probe moves by b / E: decreasing E moves it along sign(b)
            direction = -1.0 if r0 * b < 0 else 1.0  # residual < 0 with b > 0: need a larger value: softer (−)
            x1, r1 = x0, r0
            while r1 * r0 > 0:
                x_next = x1 + direction * math.log(2.0)
                if not (math.log(lo) - 1e-12 <= x_next <= math.log(hi) + 1e-12):
                    values = [v for _, v in runs.history]
                    raise CalibrationError(
                        f"target {target!r} is not reachable for {what} with E_solid in [{lo:.6g}, {hi:.6g}] Pa: "
                        f"the runs span [{min(values):.6g}, {max(values):.6g}] (runs (E_solid, value): "
                        f"{runs.history})" + (" (wrong sign?)" if target * p0 < 0 else ""))
                x1, r1 = x_next, residual(x_next)
            a_, b_ = sorted((x0, x1))
            E = math.exp(brentq(residual, a_, b_, xtol=rtol, maxiter=max_runs))
        achieved = value(E)
    calibration = Calibration(E_solid=float(E), probe=probe, step=step, target=target, achieved=float(achieved),
                              runs=len(runs.values), relative_to=relative_to, method=method, scene=scene.name,
                              E_solid_initial=float(E0), history=runs.history, component=component,
                              foam_tables=tuple(foam_table_records((r.name, r.parameters.get("table"))
                                                                   for r in tabulated_regions(scene.regions))))
    logger.info("calibrated E_solid = %.10g Pa (%s = %.10g, target %.10g) in %d runs", calibration.E_solid, probe,
                calibration.achieved, target, calibration.runs)
    if out_dir is not None:
        write_calibration(calibration, Path(out_dir) / CALIBRATION_JSON, comm=comm)
    return calibration


def write_calibration(calibration: Calibration, path: str | os.PathLike, comm=None) -> Path:
    """Write ``calibration.json`` atomically (:func:`foambase.files.write_json_atomic`) on rank 0 (collective)."""
    from mpi4py import MPI
    comm = MPI.COMM_WORLD if comm is None else comm
    path = Path(path)
    if comm.rank == 0:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(path, calibration.to_dict())
    comm.Barrier()
    return path


# --------------------------------------------------------------------------------------------------
# Command line: fenicsfoam calibrate
# --------------------------------------------------------------------------------------------------
def _calibrate_arguments(parser) -> None:
    from foambase.cli import nonempty_path

    parser.add_argument("scene", type=nonempty_path, help="the scene file (TOML); its foam regions share one E_solid")
    parser.add_argument("--probe", required=True,
                        help="the probe matched (e.g. tip_deflection, or KIND:GROUP such as reaction_force:pad)")
    parser.add_argument("--component", choices=COMPONENTS, default=None,
                        help="the component matched of a vector probe (KIND:GROUP other than volume)")
    parser.add_argument("--step", required=True, help="label of the load step at which it is matched")
    parser.add_argument("--target", type=float, required=True,
                        help="the measured value in the probe's SI unit (m; degrees for center_rotation)")
    parser.add_argument("--relative-to", default=None, metavar="LABEL",
                        help="match the change of the probe from this step (e.g. rest)")
    parser.add_argument("--out", type=nonempty_path, required=True, help="output directory: DIR/calibration.json")
    parser.add_argument("--rtol", type=float, default=1e-10, help="relative tolerance on E_solid (nonlinear cases)")
    parser.add_argument("--E-range", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
                        help="E_solid searched (Pa); default 1e-3 to 1e3 times the scene's E_solid")
    parser.add_argument("--max-runs", type=int, default=60, help="most scene runs allowed")


def _calibrate_check(parser, args) -> None:
    """Usage errors before any work: the target, the tolerance, the range, the run budget."""
    if not math.isfinite(args.target):
        parser.error(f"--target must be a finite number (the probe's SI unit), got {args.target!r}")
    if not 0 < args.rtol < 1:
        parser.error(f"--rtol must be in (0, 1), got {args.rtol!r}")
    if args.E_range is not None and not (0 < args.E_range[0] < args.E_range[1] and math.isfinite(args.E_range[1])):
        parser.error(f"--E-range must be two increasing positive moduli (Pa), got {args.E_range}")
    if args.max_runs < 3:
        parser.error(f"--max-runs must be at least 3 (two runs and a check), got {args.max_runs}")


def _calibrate_run(args) -> int:
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    calibration = calibrate_E_solid(args.scene, args.probe, args.step, args.target, relative_to=args.relative_to,
                                    component=args.component, rtol=args.rtol,
                                    E_range=None if args.E_range is None else tuple(args.E_range),
                                    max_runs=args.max_runs, out_dir=args.out, comm=comm)
    if comm.rank == 0:
        what = f"{calibration.probe}" + (f" ({calibration.component})" if calibration.component else "") + (
            f" at {calibration.step}") + (
            f" relative to {calibration.relative_to}" if calibration.relative_to else "")
        print(f"E_solid = {calibration.E_solid:.10g} Pa: {what} = {calibration.achieved:.10g} "
              f"(target {calibration.target:.10g}) in {calibration.runs} runs ({calibration.method})")
        print("through foam table " + " and ".join(repr(t["table"]) for t in calibration.foam_tables)
              + " (a scene's foam region takes it only if it reads that table)")
        print(f"written: {Path(args.out) / CALIBRATION_JSON}")
    return 0


def _command():
    from foambase.cli import Command

    return Command(
        "calibrate", "find the E_solid of a scene's foams for which a probe matches a measurement",
        _calibrate_arguments, _calibrate_run, check=_calibrate_check,
        description="Find the one E_solid shared by every foam region of a scene for which PROBE at step STEP "
                    "(or its change from --relative-to) equals --target; writes DIR/calibration.json, which a "
                    "scene takes with E_solid = {calibration = \"...\"}. Works under mpirun. Exit 2: a bad "
                    "request or an unreachable target, named.")


#: The ``fenicsfoam calibrate`` sub-command (registered in :data:`fenicsfoam.cli.COMMANDS`).
CALIBRATE = _command()
