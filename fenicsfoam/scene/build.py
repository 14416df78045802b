"""Building what a validated scene declares, and nothing else: materials, mesh, orientation, motions, problem, probes.

Materials are resolved first (a foam outside the table fails before any meshing), then the mesh is built by its
builder, the DG0 material and orientation fields are laid on it, the load kinds add their rigid motions and the
probe kinds their probes (:mod:`fenicsfoam.scene.kinds`). Modelling choices:

* *Orientation on an isotropic scene* is rejected (:class:`SceneError` naming ``orientation``): every region
  being isotropic, the isotropic energy is used and a direction field would silently do nothing, which is
  more likely a mistake in the scene (e.g. a foam fitted isotropic by accident) than an intention.
* *Servo rest angle*: 0° = the horns horizontal, the arm ends at their reference (flat-plate) position; the
  flat plate is stress-free there and gravity is applied at that rest pose. The paper's positions are
  rest = 0°, middle = 19°, top = 38° (Table I is compared as differences from rest). The real robot's
  absolute horn angle at rest is not given by the paper; 0° is the pose where the mesh is undeformed.
* *Spiral*: :func:`fenicsfoam.orientation.spiral_directions` about the vertical axis through ``center``.
* *Mesh checks* (:mod:`fenicsfoam.meshcheck`), right after meshing: a warning if the mesh is not metre-sized
  (smaller than 1 mm or larger than 100 m across), and one if ``degree = 1`` leaves fewer than 3 elements through
  the thinnest dimension (P1 locks in bending; ``degree = 2`` is the default).
* *Offset*: ``orientation.offset_deg`` turns every cell's l axis about the vertical by that angle after the kind
  has built it (counter-clockwise seen from above); a design parameter.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from fenicsfoam import materials as _materials
from fenicsfoam import orientation as orient
from fenicsfoam.constitutive import MaterialField
from fenicsfoam.materials import Isotropic, TransverseIsotropic
from fenicsfoam.meshcheck import check_degree, check_units, mesh_extent
from fenicsfoam.scene.kinds import GROUP_PROBE_KINDS, LOAD_KINDS, PROBE_KINDS, BuildContext
from fenicsfoam.scene.schema import PETSC_PREFIX, Region, Scene
from fenicsfoam.scene.table import SceneError, key_error
from fenicsfoam.solver import ElasticityProblem, LoadStep
from foambase.errors import InputError
from foambase.mpi import on_every_rank
from homogenization.tensors import InadmissibleMaterialError

__all__ = ["Model", "build_model", "load_steps", "resolve_material"]


@dataclass
class Model:
    """What a scene builds: the mesh, the problem, the orientation field, the probes, the load steps."""

    tagged: Any                       #: the mesh with its tags (and the builder's extras, e.g. the Tripod geometry)
    problem: ElasticityProblem
    orientation: Any                  #: the DG0 l-axis field, or None (isotropic scene)
    probes: dict[str, Callable]       #: name → probe, called with the displacement
    steps: list[LoadStep]
    materials: dict[str, dict]        #: region name → the resolved material's record (for summaries)


# --------------------------------------------------------------------------------------------------
# Materials and orientation
# --------------------------------------------------------------------------------------------------
def resolve_material(region: Region):
    """The :mod:`fenicsfoam.materials` object of a region (foam: through ``foam_material``).

    A value the material refuses is a :class:`SceneError` naming the key (``regions.plate.E_solid``; for a
    condition on several constants the first one the message mentions, with the others).
    """
    path = f"regions.{region.name}"
    try:
        if region.material == "isotropic":
            return Isotropic(**region.parameters)
        if region.material == "transverse_isotropic":
            return TransverseIsotropic(**region.parameters)
        foam_material = getattr(_materials, "foam_material", None)
        if foam_material is None:
            raise SceneError(f"{path}: foam regions need fenicsfoam.materials.foam_material (the homogenized "
                             "tables), which this installation lacks; use explicit constants")
        params = dict(region.parameters)
        density, gamma = (_representative(params.pop(key), key) for key in ("density", "gamma"))
        for key in ("density", "gamma"):  # every per-tag value is checked against the table before meshing
            spec = region.parameters[key]
            for value in spec.get("per_tag", {}).values() if isinstance(spec, dict) else ():
                foam_material(value if key == "density" else density, value if key == "gamma" else gamma,
                              params["E_solid"], params["nu_solid"],
                              **{k: params[k] for k in ("rho_solid", "fit", "table") if k in params})
        return foam_material(density, gamma, params.pop("E_solid"), params.pop("nu_solid"), **params)
    except (InadmissibleMaterialError, ValueError) as exc:
        if isinstance(exc, SceneError):
            raise
        raise key_error(path, region.parameters, str(exc)) from exc


def _representative(spec, key: str) -> float:
    """The value of a foam field that stands for its region before meshing (its material's kind, the summary).

    The number, a per-tag table's first value, or for a function the middle of the foam table's range
    (arithmetic for density, geometric for γ).
    """
    if not isinstance(spec, dict):
        return spec
    if "per_tag" in spec:
        return next(iter(spec["per_tag"].values()))
    from fenicsfoam.grading import FoamTable
    lo, hi = getattr(FoamTable(), f"{key}_range")
    return 0.5 * (lo + hi) if key == "density" else math.sqrt(lo * hi)


def _check_default_tables(scene: Scene, what: str) -> None:
    """Per-cell foam constants (:mod:`fenicsfoam.grading`) read the default (cube) foam table only."""
    for region in scene.regions:
        table = region.parameters.get("table")
        if region.material == "foam" and table not in (None, "cube"):
            raise SceneError(f"regions.{region.name}.table: {what} read the default foam table 'cube' only, got "
                             f"{table!r}; remove the key or use numbers without blends")


def _material_record(material) -> dict[str, Any]:
    return {"type": type(material).__name__, **asdict(material)}


def _graded_record(region: Region, material, cells, comm) -> dict[str, Any]:
    """A graded foam region's summary: its fit, the type of its material, the range of its per-cell density and γ."""
    from mpi4py import MPI

    foam = cells.foams[region.name]
    ranges = {}
    for key in ("density", "gamma"):
        values = getattr(foam, key)
        ranges[f"{key}_range"] = [comm.allreduce(float(values.min(initial=np.inf)), op=MPI.MIN),
                                  comm.allreduce(float(values.max(initial=-np.inf)), op=MPI.MAX)]
    return {"type": "graded " + type(material).__name__, "fit": region.parameters["fit"], **ranges}


def _check_graded_range(cells, comm) -> None:
    """Every graded cell's density and γ inside the foam table, counted over all ranks (collective).

    :class:`InputError` with the total number of cells outside (a rank-local check would stop only the ranks
    whose cells are outside, and count only theirs).
    """
    from fenicsfoam.grading import FoamTable

    table = FoamTable()  # graded fields read the default table (_check_default_tables)
    for name, foam in cells.foams.items():
        for key, (lo, hi) in (("density", table.density_range), ("gamma", table.gamma_range)):
            values = np.asarray(getattr(foam, key), dtype=float)
            bad = ~(np.isfinite(values) & (values >= lo - 1e-12) & (values <= hi + 1e-12))
            total = comm.allreduce(int(bad.sum()))
            if total:
                example = next(v for part in comm.allgather(values[bad][:1].tolist()) for v in part)
                raise InputError(f"region {name!r}: {total} cell(s) have {key} outside the tabulated range "
                                 f"[{lo:g}, {hi:g}] of the foam table (e.g. {example!r}; counted on all ranks)")


def _import_callable(spec: str, comm=None) -> Callable[[np.ndarray], np.ndarray]:
    """The user's ``module:function``; any exception it raises becomes a :class:`SceneError` naming it.

    With ``comm``, a call fails on every rank when it fails on one (collective): the caller's next collective
    call would otherwise wait forever for the failed rank.
    """
    module, _, name = spec.partition(":")
    try:
        function = getattr(importlib.import_module(module), name)
    except Exception as exc:  # ImportError, AttributeError, or whatever the module raises when imported
        raise SceneError(f"orientation.function: cannot import {spec!r}: {type(exc).__name__}: {exc}") from exc
    if not callable(function):
        raise SceneError(f"orientation.function: {spec!r} is a {type(function).__name__}, not a function")

    def call(x: np.ndarray) -> np.ndarray:
        try:
            values = np.asarray(function(x))
        except (Exception, SystemExit) as exc:  # a sys.exit in the user's function is a failure too
            raise SceneError(f"orientation.function: {spec}(x) raised {type(exc).__name__}: {exc}; it must map "
                             "an (n, 3) array of points (m) to an (n, 3) array of directions") from exc
        if np.iscomplexobj(values):
            raise SceneError(f"orientation.function: {spec}(x) returned complex values (e.g. "
                             f"{values.ravel()[:1]}); it must return real directions")
        return values

    def directions(x: np.ndarray) -> np.ndarray:
        return call(x) if comm is None else on_every_rank(comm, lambda: call(x), "orientation.function failed")
    return directions


def _check_orientation(scene: Scene, materials: Mapping[str, Any]) -> None:
    """An orientation is required with a TI region and refused when every region is isotropic."""
    anisotropic = [name for name, m in materials.items() if not isinstance(m, Isotropic)]
    if not anisotropic and scene.orientation is not None:
        raise SceneError("orientation: every region is isotropic, so an orientation field would have no effect; "
                         "remove the [orientation] table (or make a region anisotropic)")
    if anisotropic and scene.orientation is None:
        raise SceneError(f"orientation: missing; the transversely isotropic region(s) {', '.join(anisotropic)} "
                         "need an [orientation] table (kind = uniform, per_tag, spiral or callable)")
    if scene.orientation is not None and scene.orientation["kind"] == "callable":
        _import_callable(scene.orientation["function"])


def _spiral(spec: Mapping[str, Any]) -> Callable[[np.ndarray], np.ndarray]:
    return lambda x: orient.spiral_directions(x, spec["pitch_deg"], spec["handedness"], spec["center"])


#: Orientation kinds: kind → builder(mesh, cell_tags, spec) of the DG0 l-axis field.
ORIENTATIONS: dict[str, Callable] = {
    "uniform": lambda mesh, cell_tags, spec: orient.uniform(mesh, spec["direction"]),
    "per_tag": lambda mesh, cell_tags, spec: orient.per_tag(mesh, cell_tags, spec["directions"],
                                                            default=spec["default"]),
    "spiral": lambda mesh, cell_tags, spec: orient.from_callable(mesh, _spiral(spec)),
    "callable": lambda mesh, cell_tags, spec: orient.from_callable(mesh, _import_callable(spec["function"], mesh.comm)),
}


def _build_orientation(scene: Scene, mesh, cell_tags):
    """The DG0 l-axis field the scene declares (None for an isotropic scene)."""
    spec = scene.orientation
    if spec is None:
        return None
    def build():
        try:
            return ORIENTATIONS[spec["kind"]](mesh, cell_tags, spec)
        except orient.OrientationError as exc:
            raise SceneError(f"orientation: {exc}") from exc
    # a user's function may fail on some ranks' cells only: every rank stops with the same error
    field = on_every_rank(mesh.comm, build, "the orientation field failed")
    offset = math.radians(spec.get("offset_deg", 0.0))
    if offset:
        a = orient.cell_values(field)
        c, s = math.cos(offset), math.sin(offset)
        orient.set_cell_values(field, np.column_stack([c * a[:, 0] - s * a[:, 1], s * a[:, 0] + c * a[:, 1], a[:, 2]]))
    return field


# --------------------------------------------------------------------------------------------------
# Mesh
# --------------------------------------------------------------------------------------------------
def _mesh_file(comm, params: dict[str, Any]):
    from meshes.msh import read_msh
    return read_msh(comm, params["path"])


def _mesh_beam(comm, params: dict[str, Any]):
    from meshes.beam import make_beam
    return make_beam(comm, **params)


def _mesh_finger(comm, params: dict[str, Any]):
    from meshes.finger import FingerGeometry, make_finger
    h, order = params.pop("h"), params.pop("order")
    try:
        geometry = FingerGeometry(**params)
    except ValueError as exc:
        raise SceneError(f"geometry: {exc}") from exc
    return make_finger(comm, h, geometry, order)


def _mesh_tripod(comm, params: dict[str, Any]):
    from meshes.tripod import TripodGeometry, make_tripod
    h, order = params.pop("h"), params.pop("order")
    try:
        geometry = TripodGeometry(**params)
    except ValueError as exc:  # named by _build_mesh
        raise InputError(str(exc)) from exc
    return make_tripod(comm, h, geometry, order)


#: Geometry builders: ``[geometry] builder`` → function(comm, parameters) of the tagged mesh.
MESHERS: dict[str, Callable] = {"file": _mesh_file, "beam": _mesh_beam, "tripod": _mesh_tripod,
                                "finger": _mesh_finger}


def _build_mesh(scene: Scene, comm):
    """The builder's tagged mesh; a parameter the builder refuses is a :class:`SceneError` naming the key."""
    params = dict(scene.geometry)
    try:
        return MESHERS[scene.builder](comm, dict(params))
    except InputError as exc:
        if isinstance(exc, SceneError):
            raise
        raise key_error("geometry", params, str(exc)) from exc


# --------------------------------------------------------------------------------------------------
# The model
# --------------------------------------------------------------------------------------------------
def load_steps(scene: Scene) -> list[LoadStep]:
    """The scene's schedule as solver load steps (angles in radians)."""
    steps = []
    for s in scene.steps:
        angles = {} if s.servo_deg is None else {f"servo{i}": math.radians(a) for i, a in enumerate(s.servo_deg)}
        angles.update({name: math.radians(m["angle_deg"]) for name, m in s.motions.items() if "angle_deg" in m})
        translations = {name: m["translation"] for name, m in s.motions.items() if "translation" in m}
        steps.append(LoadStep(s.label, gravity=s.gravity, increments=s.increments, angles=angles,
                              translations=translations, factors=dict(s.loads)))
    return steps


def build_model(scene: Scene, comm) -> Model:
    """Build the mesh, the problem and the probes of a validated scene (collective)."""
    def resolve():  # before meshing: fail fast; reads files and imports the user's module (may fail on one rank)
        resolved = {region.name: resolve_material(region) for region in scene.regions}
        _check_orientation(scene, resolved)
        return resolved
    resolved = on_every_rank(comm, resolve, "checking the scene's materials and orientation failed")
    tagged = _build_mesh(scene, comm)
    mesh, cell_tags = tagged.mesh, tagged.cell_tags
    extent = mesh_extent(mesh)
    check_units(mesh, extent)
    check_degree(mesh, scene.degree, extent)
    materials = {tag: resolved[region.name] for region in scene.regions for tag in region.tags}
    records = {region.name: _material_record(resolved[region.name]) for region in scene.regions}
    if scene.graded:  # per-cell density and γ through the table (fenicsfoam.grading)
        _check_default_tables(scene, "graded foam fields")
        from fenicsfoam.grading import CellMaterials
        try:
            cells = CellMaterials.from_regions(mesh, cell_tags, scene.regions, materials=resolved, blends=scene.blends)
            _check_graded_range(cells, comm)
            field = cells.material_field(mesh, materials)
        except InputError as exc:
            raise SceneError(f"regions: {exc}") from exc
        for region in scene.regions:
            if region.material == "foam":
                records[region.name] = _graded_record(region, resolved[region.name], cells, comm)
    else:
        field = MaterialField.from_regions(mesh, cell_tags, materials)
    a = _build_orientation(scene, mesh, cell_tags)
    context = BuildContext(scene, tagged)
    motions = [m for key, kind in LOAD_KINDS.items() for m in kind.motions(scene.loads[key], context)]
    try:
        loads = [load for key, kind in LOAD_KINDS.items() for load in kind.external(scene.loads[key], context)]
    except InputError as exc:
        raise SceneError(f"loads: {exc}") from exc
    gravity = (0.0, 0.0, 0.0) if scene.gravity is None else scene.gravity
    problem = ElasticityProblem(mesh, field, orientation=a, model=scene.model, degree=scene.degree,
                                gravity=gravity, motions=motions, loads=loads, prefix=PETSC_PREFIX,
                                options=dict(scene.petsc))
    context = BuildContext(scene, tagged, problem.V, problem)
    probes = {}
    for name in scene.probes:
        try:
            if name in scene.probe_groups:
                kind = GROUP_PROBE_KINDS[name.partition(":")[0]]
                probes[name] = kind.build(context, scene.probe_groups[name])
            else:
                probes[name] = PROBE_KINDS[name].build(context)
        except InputError as exc:
            if isinstance(exc, SceneError):
                raise
            raise SceneError(f"probes: {name!r}: {exc}") from exc
    return Model(tagged, problem, a, probes, load_steps(scene), records)
