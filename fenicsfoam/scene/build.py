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

import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from fenicsfoam import orientation as orient
from fenicsfoam.constitutive import MaterialField
from fenicsfoam.material import MATERIAL_KINDS, Isotropic, tabulated_regions
from fenicsfoam.meshcheck import UNITS_RANGE, check_degree, check_units, mesh_extent
from fenicsfoam.scene.kinds import GEOMETRY_KINDS, GROUP_PROBE_KINDS, LOAD_KINDS, PROBE_KINDS, BuildContext
from fenicsfoam.scene.schema import PETSC_PREFIX, Region, Scene
from fenicsfoam.scene.table import SceneError, key_error
from fenicsfoam.solver import ElasticityProblem, LoadStep
from foambase.errors import InputError
from foambase.imports import import_callable
from foambase.mpi import on_every_rank

__all__ = ["Model", "build_model", "check_materials", "load_steps", "resolve_material"]


@dataclass
class Model:
    """What a scene builds: the mesh, the problem, the orientation field, the probes, the load steps."""

    tagged: Any                       #: the mesh with its tags (and the builder's extras, e.g. the Tripod geometry)
    problem: ElasticityProblem
    orientation: Any                  #: the DG0 l-axis field, or None (isotropic scene)
    probes: dict[str, Callable]       #: name → probe, called with the displacement
    steps: list[LoadStep]
    materials: dict[str, dict]        #: region name → the resolved material's record (for summaries)
    #: graded scenes: the per-cell foam data (:class:`fenicsfoam.grading.CellMaterials`), else None
    cell_materials: Any = None


# --------------------------------------------------------------------------------------------------
# Materials and orientation
# --------------------------------------------------------------------------------------------------
def resolve_material(region: Region):
    """The material of a region, by its kind's resolver (:data:`fenicsfoam.material.MATERIAL_KINDS`).

    A value the material refuses is a :class:`SceneError` naming the key (``regions.plate.E_solid``; for a
    condition on several constants the first one the message mentions, with the others).
    """
    try:
        return MATERIAL_KINDS[region.material].resolve(region.parameters)
    except ValueError as exc:  # InadmissibleMaterialError, InputError
        if isinstance(exc, SceneError):
            raise
        raise key_error(f"regions.{region.name}", region.parameters, str(exc)) from exc


def _check_default_tables(scene: Scene, what: str) -> None:
    """Per-cell foam constants (:mod:`fenicsfoam.grading`) read the default foam table only (``DEFAULT_TABLE``)."""
    from homogenization.tables import DEFAULT_TABLE

    for region in scene.regions:
        table = region.parameters.get("table")
        if MATERIAL_KINDS[region.material].tabulated and table not in (None, DEFAULT_TABLE):
            raise SceneError(f"regions.{region.name}.table: {what} read the default foam table {DEFAULT_TABLE!r} "
                             f"only, got {table!r}; remove the key or use numbers without blends")


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
    try:
        function = import_callable(spec)
    except InputError as exc:
        raise SceneError(f"orientation.function: {exc}") from exc

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
def _build_mesh(scene: Scene, comm):
    """The builder's tagged mesh; a parameter the builder refuses is a :class:`SceneError` naming the key."""
    params = dict(scene.geometry)
    try:
        return GEOMETRY_KINDS[scene.builder].mesh(comm, dict(params))
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
    servos = scene.servos
    for index, s in enumerate(scene.steps):
        # a servo's motion: its set-up (translation, horn at setup_deg) from the first step on, turned from there
        turned = {**(dict.fromkeys(servos, 0.0) if index == 0 else {}), **s.servos}
        angles = {name: math.radians(servos[name]["setup_deg"] + a) for name, a in turned.items()}
        translations = {name: servos[name]["setup_translation"] for name in turned} if index == 0 else {}
        angles.update({name: math.radians(m["angle_deg"]) for name, m in s.motions.items() if "angle_deg" in m})
        translations.update({name: m["translation"] for name, m in s.motions.items() if "translation" in m})
        steps.append(LoadStep(s.label, gravity=s.gravity, increments=s.increments, angles=angles,
                              translations=translations, factors=dict(s.loads)))
    return steps


def check_materials(scene: Scene) -> dict[str, Any]:
    """The material of every region, resolved and checked before anything is built (:class:`SceneError`).

    Every region's values (:func:`resolve_material`), the orientation the materials need, and the table graded
    fields read. The first step of :func:`build_model`, and the check of every variation of a scene
    (:func:`fenicsfoam.scene.vary.vary_scene`).
    """
    resolved = {region.name: resolve_material(region) for region in scene.regions}
    _check_orientation(scene, resolved)
    if scene.graded:
        _check_default_tables(scene, "graded foam fields")
    return resolved


def build_model(scene: Scene, comm, before_problem: Callable[[Any], Mapping[str, Any]] | None = None) -> Model:
    """Build the mesh, the problem and the probes of a validated scene (collective).

    ``before_problem(mesh)``, if given, is called once the mesh is built and before anything is assembled (e.g. to
    size the run and refuse it, :mod:`fenicsfoam.sizing`); it returns PETSc options that the scene's own
    ``[fem.petsc]`` options override (e.g. the solver chosen by size).
    """
    # before meshing: fail fast; reads files and imports the user's module, which may fail on one rank only
    resolved = on_every_rank(comm, lambda: check_materials(scene), "checking the scene's materials failed")
    tagged = _build_mesh(scene, comm)
    mesh, cell_tags = tagged.mesh, tagged.cell_tags
    extent = mesh_extent(mesh)
    if extent.size > UNITS_RANGE[1]:  # millimetres: refused here, not left to fail as a "material instability"
        raise SceneError(f"geometry: the mesh is {extent.size:.4g} m across, more than the {UNITS_RANGE[1]:g} m a "
                         "robot may be: fenicsfoam works in metres (SI units); a mesh drawn in millimetres must be "
                         "scaled by 0.001 (gmsh: Mesh.ScalingFactor = 0.001 before writing the .msh file)")
    check_units(mesh, extent)
    check_degree(mesh, scene.degree, extent)
    materials = {tag: resolved[region.name] for region in scene.regions for tag in region.tags}
    records = {region.name: _material_record(resolved[region.name]) for region in scene.regions}
    cells = None
    if scene.graded:  # per-cell density and γ through the table (fenicsfoam.grading)
        from fenicsfoam.grading import CellMaterials
        try:
            cells = CellMaterials.from_regions(mesh, cell_tags, scene.regions, materials=resolved, blends=scene.blends)
            _check_graded_range(cells, comm)
            field = cells.material_field(mesh, materials)
        except InputError as exc:
            raise SceneError(f"regions: {exc}") from exc
        for region in tabulated_regions(scene.regions):
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
    chosen = {} if before_problem is None else dict(before_problem(mesh))
    problem = ElasticityProblem(mesh, field, orientation=a, model=scene.model, degree=scene.degree,
                                gravity=gravity, motions=motions, loads=loads, prefix=PETSC_PREFIX,
                                options={**chosen, **dict(scene.petsc)})
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
    return Model(tagged, problem, a, probes, load_steps(scene), records, cells)
