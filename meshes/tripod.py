"""The Tripod robot's soft plate: a parametric Y-shaped plate with a central hole, tagged for scenes and probes.

Geometry (SoftRobots Tripod tutorial; SI units, metres: docs/conventions.md). The plate lies in the x–y plane,
``−thickness/2 ≤ z ≤ thickness/2``, centred at the origin. It is the union of three arms, rectangles of width
``arm_width`` along the unit directions ``e_i = (cos φ_i, sin φ_i, 0)``, ``φ_i = 0°, 120°, 240°`` from +x
(:data:`ARM_ANGLES_DEG`), each reaching from the origin to its flat end at distance ``arm_length`` along ``e_i``,
minus the central hole ``r < hole_radius``. Between two arms the outline has a re-entrant corner at radius
``r* = (arm_width/2) / sin 60°`` (17.3 mm by default), optionally rounded by a fillet of radius ``fillet_radius``.

Regions (cell tags, a partition of the plate; circular cuts are geometric, so each region is exact up to the
chordal error of the arcs):

=====================  =======================  ======================================================
tag                    region                   use
=====================  =======================  ======================================================
:data:`RING` = 1       hole_radius ≤ r < ring   probes (centre height, rotation); part of the centre
:data:`CENTRE` = 2     ring ≤ r < centre        rest of the central region (case A: isotropic 15 % foam)
:data:`ARM` 11–13      centre ≤ r < arm_end     arm i (case A: TI 30 % foam, l axis 30° from e_i)
:data:`ARM_END` 21–23  r ≥ arm_end              the part of arm i carried rigidly by servo i's horn
=====================  =======================  ======================================================

With ``arm_end_cut = "straight"`` the arm ends are ``x · e_i ≥ arm_end`` (a straight cut across each arm) and the arms
reach up to that line. Defaults: ring 5–10 mm, centre r < 20 mm (just beyond the re-entrant corners, so the centre
holds the whole hub where the arms overlap and each arm region is a plain strip), arm ends r ≥ 45 mm. Named unions of
tags are in :data:`REGIONS` (e.g. ``"centre" = (RING, CENTRE)``, ``"arm1" = (12, 22)``). The plate has no facet tags.

Symmetric mesh (:func:`make_tripod`): the plate is invariant under the dihedral group D3 (:func:`symmetry_group`:
rotations by 0°, 120°, 240° about e_z and the mirrors across the vertical planes through the arm axes), and so is
the mesh, node for node and cell for cell, so that a D3-symmetric problem (isotropic plate, three equal servo
angles) has a D3-symmetric discrete solution, e.g. zero torsion of the centre up to round-off. Construction:

1. gmsh (OpenCASCADE, rank 0) meshes the fundamental wedge ``0° ≤ φ ≤ 60°`` (:data:`WEDGE_ANGLE`) with
   tetrahedra (:meth:`TripodGeometry.build_gmsh_wedge`); its two flat sides lie on the mirror planes φ = 0°
   (through arm 0) and φ = 60° (through arm 2, between arms 0 and 1). The wedge holds the regions RING, CENTRE,
   ARM[0], ARM_END[0].
2. numpy maps the wedge mesh by the six group elements; the six images tile the plate. Two neighbouring images
   differ by the mirror of their common side, which fixes that side pointwise, so their triangulations of it are
   the same and the copies conform. Nodes on a mirror side are merged topologically (copy g and copy g∘s of a node
   fixed by the mirror s are one node), not by a coordinate search. The arm tags of each image follow the arm it
   covers.
3. dolfinx builds the mesh from the merged arrays on rank 0 (:func:`meshes.distribute.mesh_from_arrays`:
   ``create_mesh`` distributes it, as ``gmshio.model_to_mesh`` does) with the cell tags carried over.

The wedge's mirror sides constrain gmsh more than the whole plate did, so a given ``h`` gives more tetrahedra than
the former whole-plate mesh (h = 4.6 mm: 3726 instead of 2738); :data:`PAPER_H` = 5.2 mm gives 2694 (paper: 2684).

Servos (:meth:`TripodGeometry.servo_frames`): servo i turns about the horizontal axis tangential to the circle of
radius ``servo_radius`` (60 mm) through its pivot ``p_i = servo_radius e_i + pivot_z e_z``; the axis is the
counter-clockwise tangent ``t_i = e_z × e_i = (−sin φ_i, cos φ_i, 0)``. A horn angle θ rotates the arm end
rigidly by θ about ``t_i`` (right-hand rule), so a positive angle lifts the arm end (+z) as the arm end lies
inside the servo circle: ``x = p + R(θ, t)(X − p)``.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import dolfinx
import dolfinx.io.gmshio
import gmsh
import numpy as np
from mpi4py import MPI

from foambase.errors import ComputationError, InputError
from foambase.mpi import on_rank0
from meshes.beam import TaggedMesh, check_order, generate_tetrahedra
from meshes.distribute import mesh_from_arrays

__all__ = [
    "ARM",
    "ARM_ANGLES_DEG",
    "ARM_END",
    "ARM_END_CUTS",
    "CENTRE",
    "PAPER_H",
    "REGIONS",
    "RING",
    "ServoFrame",
    "TripodGeometry",
    "TripodMesh",
    "WEDGE_ANGLE",
    "make_tripod",
    "symmetry_group",
]

logger = logging.getLogger(__name__)

#: Directions of the three arms (and servos), degrees counter-clockwise from +x seen from above.
ARM_ANGLES_DEG: tuple[float, float, float] = (0.0, 120.0, 240.0)
#: Cell tag of the probe ring ``hole_radius ≤ r < ring_radius``.
RING: int = 1
#: Cell tag of the rest of the central region ``ring_radius ≤ r < centre_radius``.
CENTRE: int = 2
#: Cell tags of the arms ``centre_radius ≤ r < arm_end_radius``, arm i along ``ARM_ANGLES_DEG[i]``.
ARM: tuple[int, int, int] = (11, 12, 13)
#: Cell tags of the arm ends ``r ≥ arm_end_radius`` carried by the servo horns, end i on arm i.
ARM_END: tuple[int, int, int] = (21, 22, 23)
#: Named unions of cell tags.
REGIONS: dict[str, tuple[int, ...]] = {
    "ring": (RING,),
    "centre": (RING, CENTRE),
    **{f"arm{i}": (ARM[i], ARM_END[i]) for i in range(3)},
    **{f"arm_end{i}": (ARM_END[i],) for i in range(3)},
    "arms": ARM + ARM_END,
    "plate": (RING, CENTRE) + ARM + ARM_END,
}
#: Element size (m) of the paper-like mesh: with the default geometry it gives 2694 tetrahedra (paper: 2684).
PAPER_H: float = 0.0052
#: Shapes of the boundary between an arm and its end (:attr:`TripodGeometry.arm_end_cut`).
ARM_END_CUTS: tuple[str, str] = ("arc", "straight")
#: Opening angle (rad) of the fundamental wedge ``0 ≤ φ ≤ 60°`` that gmsh meshes (:func:`make_tripod`).
WEDGE_ANGLE: float = math.pi / 3


@dataclass(frozen=True)
class ServoFrame:
    """Rigid kinematics of one servo horn: rotation by an angle about ``axis`` through ``pivot``.

    Attributes
    ----------
    pivot : numpy.ndarray
        (3,) a point of the servo axis (m).
    axis : numpy.ndarray
        (3,) unit axis; a positive angle turns by the right-hand rule about it.

    """

    pivot: np.ndarray
    axis: np.ndarray

    def rotation(self, angle: float) -> np.ndarray:
        """Rotation matrix (Rodrigues) ``R = I + sin θ K + (1 − cos θ) K²``, ``K = [axis]×``, ``θ = angle`` (rad)."""
        a = self.axis
        K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
        return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)

    def displacement(self, x: np.ndarray, angle: float) -> np.ndarray:
        """Displacement ``u = p + R(θ)(X − p) − X`` of points ``x`` of shape (3, n) (dolfinx ``interpolate`` layout)."""
        d = np.asarray(x, dtype=float) - self.pivot[:, None]
        return self.rotation(angle) @ d - d


@dataclass(frozen=True)
class TripodGeometry:
    """Parameters of the Tripod plate and of its servos (m); defaults from the SoftRobots Tripod tutorial (mm → m).

    Attributes
    ----------
    thickness : float
        Plate thickness; the plate spans ``−thickness/2 ≤ z ≤ thickness/2``.
    arm_width : float
        Width of each arm.
    arm_length : float
        Distance from the centre to the flat end of each arm, along the arm.
    hole_radius : float
        Radius of the central hole.
    ring_radius : float
        Outer radius of the probe ring (inner radius: ``hole_radius``); at most the re-entrant radius ``r*``.
    centre_radius : float
        Outer radius of the central region; beyond the re-entrant corners and their fillets.
    arm_end_radius : float
        Where the arm ends begin: ``r ≥ arm_end_radius`` (``arm_end_cut = "arc"``) or ``x · e_i ≥ arm_end_radius``
        (``"straight"``).
    fillet_radius : float
        Radius of the fillets of the three re-entrant corners; 0 for sharp corners.
    servo_radius : float
        Radius of the circle on which the servo axes lie (tangentially).
    horn_length : float
        Length of a servo horn (for the scene's bookkeeping; the arm end's motion only needs the servo axis).
    pivot_z : float
        Height of the servo axes (0: the plate's mid-plane).
    arm_end_cut : str
        Shape of the boundary between arm i and its end: ``"arc"`` (default), the circle ``r = arm_end_radius``;
        ``"straight"``, the line across the arm at ``arm_end_radius`` along it (``x · e_i = arm_end_radius``), so
        that the edge of a clamp box across the arm there (the SoftRobots Tripod tutorial's box clamps the arm's
        last 10 mm, 45–55 mm out along it) is a line of mesh nodes and faces instead of cutting through cells.

    """

    thickness: float = 5e-3
    arm_width: float = 30e-3
    arm_length: float = 55e-3
    hole_radius: float = 5e-3
    ring_radius: float = 10e-3
    centre_radius: float = 20e-3
    arm_end_radius: float = 45e-3
    fillet_radius: float = 0.0
    servo_radius: float = 60e-3
    horn_length: float = 25e-3
    pivot_z: float = 0.0
    arm_end_cut: str = "arc"

    def __post_init__(self) -> None:
        if self.arm_end_cut not in ARM_END_CUTS:
            raise InputError(f"Tripod arm_end_cut must be one of {', '.join(map(repr, ARM_END_CUTS))}, "
                             f"got {self.arm_end_cut!r}")
        for key in ("thickness", "arm_width", "arm_length", "hole_radius", "ring_radius", "centre_radius",
                    "arm_end_radius", "servo_radius", "horn_length"):
            value = getattr(self, key)
            if not (np.isfinite(value) and value > 0):
                raise InputError(f"Tripod {key} must be a positive length in metres, got {value!r}")
        if not (np.isfinite(self.fillet_radius) and self.fillet_radius >= 0):
            raise InputError(f"Tripod fillet_radius must be ≥ 0 m (0: sharp corners), got {self.fillet_radius!r}")
        if not np.isfinite(self.pivot_z):
            raise InputError(f"Tripod pivot_z must be a finite height in metres, got {self.pivot_z!r}")
        radii = [("hole_radius", self.hole_radius), ("ring_radius", self.ring_radius),
                 ("re-entrant corner radius arm_width/(2 sin 60°)", self.reentrant_radius),
                 ("centre_radius", self.centre_radius), ("arm_end_radius", self.arm_end_radius),
                 ("arm_length", self.arm_length)]
        for (name_a, a), (name_b, b) in zip(radii[:-1], radii[1:]):
            if not a < b:
                raise InputError(f"Tripod radii must increase: {name_a} = {a!r} m is not < {name_b} = {b!r} m")
        if not self.fillet_outer_radius < self.centre_radius:
            raise InputError(
                f"Tripod fillet_radius = {self.fillet_radius!r} m reaches r = {self.fillet_outer_radius!r} m, "
                f"beyond centre_radius = {self.centre_radius!r} m; use a smaller fillet or a larger centre"
            )

    @property
    def arm_angles(self) -> tuple[float, ...]:
        """Arm (and servo) angles ``φ_i`` in radians, from :data:`ARM_ANGLES_DEG`."""
        return tuple(math.radians(a) for a in ARM_ANGLES_DEG)

    @property
    def reentrant_radius(self) -> float:
        """Distance ``r* = (arm_width/2) / sin 60°`` of the (unfilleted) re-entrant corners from the centre."""
        return self.arm_width / 2 / math.sin(math.pi / 3)

    @property
    def fillet_outer_radius(self) -> float:
        """Largest distance from the centre of a fillet arc: at its tangent points, ``ρ/√3`` from the corner."""
        corner_x = self.reentrant_radius * math.cos(math.pi / 3)
        return math.hypot(corner_x + self.fillet_radius / math.sqrt(3), self.arm_width / 2)

    @property
    def area(self) -> float:
        """Exact plate area (m²).

        ``A = (√3/4) w² + 3 w (L − w/(2√3)) + 3 ρ² (1/√3 − π/6) − π r_h²``: the central equilateral triangle of
        side ``w`` (the hub where the arms overlap), three ``w × (L − w/(2√3))`` arm rectangles beyond it, the
        fillet patches (kite minus circular sector, opening 120°), minus the hole.
        """
        w, L, rho = self.arm_width, self.arm_length, self.fillet_radius
        return (math.sqrt(3) / 4 * w**2 + 3 * w * (L - w / (2 * math.sqrt(3)))
                + 3 * rho**2 * (1 / math.sqrt(3) - math.pi / 6) - math.pi * self.hole_radius**2)

    @property
    def volume(self) -> float:
        """Exact plate volume ``area · thickness`` (m³)."""
        return self.area * self.thickness

    @property
    def arm_end_area(self) -> float:
        """Exact area of one arm end (m²).

        ``{r ≥ R} ∩ arm``, ``w L − (w/2) √(R² − w²/4) − R² asin(w/(2R))`` (``arm_end_cut = "arc"``), or the
        rectangle ``w (L − R)`` (``"straight"``).
        """
        w, L, R = self.arm_width, self.arm_length, self.arm_end_radius
        if self.arm_end_cut == "straight":
            return w * (L - R)
        return w * L - w / 2 * math.sqrt(R**2 - w**2 / 4) - R**2 * math.asin(w / (2 * R))

    @property
    def ring_area(self) -> float:
        """Exact area of the probe ring ``π (r_ring² − r_hole²)`` (m²)."""
        return math.pi * (self.ring_radius**2 - self.hole_radius**2)

    def arm_directions(self) -> np.ndarray:
        """(3, 3) unit vectors ``e_i = (cos φ_i, sin φ_i, 0)`` of the arms, one per row."""
        return np.array([[math.cos(phi), math.sin(phi), 0.0] for phi in self.arm_angles])

    def servo_frames(self) -> tuple[ServoFrame, ServoFrame, ServoFrame]:
        """The three servo axes: pivot ``servo_radius e_i + pivot_z e_z``, axis ``t_i = (−sin φ_i, cos φ_i, 0)``.

        A positive horn angle turns the arm end by the right-hand rule about ``t_i`` and lifts it (+z):
        for a point ``X = p − s e_i`` inside the servo circle (s > 0), ``R(θ, t_i)(−s e_i) = s (−cos θ e_i +
        sin θ e_z)``.
        """
        return tuple(
            ServoFrame(pivot=self.servo_radius * e + np.array([0.0, 0.0, self.pivot_z]),
                       axis=np.array([-e[1], e[0], 0.0]))
            for e in self.arm_directions()
        )

    def build_gmsh_wedge(self) -> None:
        """Create the tagged fundamental wedge ``0° ≤ φ ≤ 60°`` of the plate in the current gmsh model (OCC).

        Called on rank 0 only. The outline is built in the plane ``z = −thickness/2`` (:meth:`build_gmsh_wedge_face`),
        each piece is extruded by ``thickness`` and the volumes are fragmented so that neighbouring regions share
        their interfaces. Outside the centre the wedge holds only arm 0, so its regions are tagged ``RING``,
        ``CENTRE``, ``ARM[0]`` and ``ARM_END[0]``.
        """
        occ = gmsh.model.occ
        pieces, tags = self.build_gmsh_wedge_face()
        volumes = [next(dt for dt in occ.extrude([(2, piece)], 0.0, 0.0, self.thickness) if dt[0] == 3)
                   for piece in pieces]
        _, volume_map = occ.fragment(volumes[:1], volumes[1:])
        occ.synchronize()
        for tag in sorted(set(tags)):
            members = [vt for t, vols in zip(tags, volume_map) if t == tag for _, vt in vols]
            gmsh.model.addPhysicalGroup(3, members, tag)

    def build_gmsh_wedge_face(self, physical: bool = False) -> tuple[list[int], list[int]]:
        """Create the tagged outline of the fundamental wedge in the plane ``z = −thickness/2`` (OCC, rank 0 only).

        Fused arm rectangles, fillet patches (kite minus disc), minus the hole, intersected with the wedge (a
        triangle with a vertex at the origin and sides along φ = 0° and φ = 60°, the mirror lines through arm 0 and
        between arms 0 and 1); it is split by the discs ``r < ring_radius``, ``r < centre_radius`` and
        ``r < arm_end_radius`` (or, with ``arm_end_cut = "straight"``, the half-plane ``x < arm_end_radius``, which
        holds the centre disc; the fragment map tells which of them hold each piece). Returns the surface tags of the
        pieces and the cell tag of each; with ``physical`` the model is synchronized and each region is a 2D
        physical group of its cell tag.
        """
        occ = gmsh.model.occ
        z0 = -self.thickness / 2
        w = self.arm_width
        arms = []
        for phi in self.arm_angles:
            rect = occ.addRectangle(0.0, -w / 2, z0, self.arm_length, w)
            occ.rotate([(2, rect)], 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, phi)
            arms.append((2, rect))
        plate, _ = occ.fuse(arms[:1], arms[1:])
        if self.fillet_radius > 0:
            plate, _ = occ.fuse(plate, [self._fillet_patch(i, z0) for i in range(3)])
        plate, _ = occ.cut(plate, [(2, occ.addDisk(0.0, 0.0, z0, self.hole_radius, self.hole_radius))])
        far = 2 * math.hypot(self.arm_length, w / 2)  # the wedge triangle reaches beyond the plate
        corners = [occ.addPoint(0.0, 0.0, z0), occ.addPoint(far, 0.0, z0),
                   occ.addPoint(far * math.cos(WEDGE_ANGLE), far * math.sin(WEDGE_ANGLE), z0)]
        lines = [occ.addLine(corners[k], corners[(k + 1) % 3]) for k in range(3)]
        wedge = occ.addPlaneSurface([occ.addCurveLoop(lines)])
        plate, _ = occ.intersect(plate, [(2, wedge)])
        radii = (self.ring_radius, self.centre_radius) + ((self.arm_end_radius,) if self.arm_end_cut == "arc" else ())
        discs = [(2, occ.addDisk(0.0, 0.0, z0, r, r)) for r in radii]
        if self.arm_end_cut == "straight":  # the half-plane x < arm_end_radius, as far as the wedge reaches
            discs.append((2, occ.addRectangle(-far, -far, z0, far + self.arm_end_radius, 2 * far)))
        _, piece_map = occ.fragment(plate, discs)
        plate_pieces = {tag for pieces in piece_map[: len(plate)] for _, tag in pieces}
        in_discs = [{tag for _, tag in pieces} for pieces in piece_map[len(plate) :]]
        occ.remove([(2, tag) for tag in set().union(*in_discs) - plate_pieces], recursive=True)

        pieces = sorted(plate_pieces)
        # 3 discs hold a piece of the ring, 2 of the centre, 1 of the arm, 0 of the arm end
        tags = [{3: RING, 2: CENTRE, 1: ARM[0], 0: ARM_END[0]}[sum(p in disc for disc in in_discs)] for p in pieces]
        expected = {RING, CENTRE, ARM[0], ARM_END[0]}
        if set(tags) != expected:
            raise ComputationError(f"Tripod wedge regions came out as cell tags {sorted(set(tags))}, "
                                   f"expected {sorted(expected)}")
        if physical:
            occ.synchronize()
            for tag in sorted(set(tags)):
                gmsh.model.addPhysicalGroup(2, [p for p, t in zip(pieces, tags) if t == tag], tag)
        return pieces, tags

    def _fillet_patch(self, i: int, z0: float) -> tuple[int, int]:
        """Fillet between arms i and i+1: the kite (corner, tangent point, fillet centre, tangent point) minus disc."""
        occ = gmsh.model.occ
        rho = self.fillet_radius
        e = self.arm_directions()
        bisector = (e[i] + e[(i + 1) % 3]) / np.linalg.norm(e[i] + e[(i + 1) % 3])
        corner = self.reentrant_radius * bisector
        centre = corner + 2 * rho / math.sqrt(3) * bisector
        kite = [corner, corner + rho / math.sqrt(3) * e[i], centre, corner + rho / math.sqrt(3) * e[(i + 1) % 3]]
        points = [occ.addPoint(p[0], p[1], z0) for p in kite]
        lines = [occ.addLine(points[k], points[(k + 1) % 4]) for k in range(4)]
        face = occ.addPlaneSurface([occ.addCurveLoop(lines)])
        patch, _ = occ.cut([(2, face)], [(2, occ.addDisk(centre[0], centre[1], z0, rho, rho))])
        return patch[0]


@dataclass(frozen=True, kw_only=True)
class TripodMesh(TaggedMesh):
    """A tagged Tripod plate mesh (:func:`make_tripod`) with the geometry it was built from."""

    geometry: TripodGeometry

    def region_cells(self, region: str) -> np.ndarray:
        """Local indices of the cells of a named region of :data:`REGIONS` (e.g. ``"centre"``, ``"arm_end2"``)."""
        if region not in REGIONS:
            raise InputError(f"unknown Tripod region {region!r}; valid regions: {sorted(REGIONS)}")
        return np.unique(np.concatenate([self.cell_tags.find(tag) for tag in REGIONS[region]]))

    def arm_end_dofs(self, V: dolfinx.fem.FunctionSpace, servo: int) -> np.ndarray:
        """Dofs of ``V`` on the arm end carried by ``servo`` (0, 1, 2): every node of the cells of ``arm_end{servo}``.

        Block indices for a vector space, as ``fem.locate_dofs_topological(V, 3, cells)`` returns them; pass them
        with a Function interpolating :meth:`ServoFrame.displacement` to ``fem.dirichletbc``.
        """
        if servo not in (0, 1, 2):
            raise InputError(f"servo must be 0, 1 or 2, got {servo!r}")
        cells = self.region_cells(f"arm_end{servo}")
        return dolfinx.fem.locate_dofs_topological(V, self.mesh.topology.dim, cells)


def symmetry_group() -> np.ndarray:
    """The six elements of the plate's symmetry group D3 as (6, 3, 3) orthogonal matrices.

    Rows 0–2: rotations by α = 0°, 120°, 240° about e_z, ``[[cos α, −sin α, 0], [sin α, cos α, 0], [0, 0, 1]]``;
    rows 3–5: mirrors across the vertical planes containing ``(cos α, sin α, 0)`` for α = 0°, 60°, 120° (the arm
    axes 0°, 240°, 120° seen as lines through the centre), ``[[cos 2α, sin 2α, 0], [sin 2α, −cos 2α, 0], [0, 0, 1]]``.
    Mirrors 3 and 4 bound the fundamental wedge ``0° ≤ φ ≤ 60°`` (:data:`WEDGE_ANGLE`).
    """
    group = np.zeros((6, 3, 3))
    group[:, 2, 2] = 1.0
    for k, alpha in enumerate(np.radians([0.0, 120.0, 240.0])):
        c, s = math.cos(alpha), math.sin(alpha)
        group[k, :2, :2] = [[c, -s], [s, c]]
    for k, alpha in enumerate(np.radians([0.0, 60.0, 120.0])):
        c, s = math.cos(2 * alpha), math.sin(2 * alpha)
        group[3 + k, :2, :2] = [[c, s], [s, -c]]
    return group


def _mesh_wedge(geometry: TripodGeometry, h: float, order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Mesh the fundamental wedge with gmsh (rank 0 only): nodes (n, 3), cells in gmsh order, cell tags, gmsh type."""
    start = time.perf_counter()
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("tripod_wedge")
        geometry.build_gmsh_wedge()
        generate_tetrahedra(h, order)
        x = dolfinx.io.gmshio.extract_geometry(gmsh.model)
        (cell_type, topology), = dolfinx.io.gmshio.extract_topology_and_markers(gmsh.model).items()
    finally:
        gmsh.finalize()
    logger.info("gmsh meshed the Tripod wedge with h = %g m in %.2f s", h, time.perf_counter() - start)
    return x, topology["topology"].astype(np.int64), topology["cell_data"].astype(np.int32), int(cell_type)


#: gmsh's node order of the 10-node tetrahedron's edges (its nodes 4–9 are the midpoints of these vertex pairs).
_TET10_EDGES: tuple[tuple[int, int], ...] = ((0, 1), (1, 2), (2, 0), (3, 0), (3, 2), (3, 1))


def _mesh_wedge_face(geometry: TripodGeometry, h: float, order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mesh the wedge's outline (z = −thickness/2) with triangles of size ``h`` (rank 0 only).

    Returns the nodes (n, 3), the triangles in gmsh's node order (3 or 6 nodes: vertices, then the midpoints of
    edges 0–1, 1–2, 2–0) and their cell tags; every returned node belongs to a triangle.
    """
    start = time.perf_counter()
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("tripod_wedge_face")
        geometry.build_gmsh_wedge_face(physical=True)
        gmsh.model.mesh.setSize(gmsh.model.getEntities(0), h)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.model.mesh.generate(2)
        if order > 1:
            gmsh.model.mesh.setOrder(order)
        x = dolfinx.io.gmshio.extract_geometry(gmsh.model)
        (_, topology), = dolfinx.io.gmshio.extract_topology_and_markers(gmsh.model).items()
    finally:
        gmsh.finalize()
    logger.info("gmsh meshed the Tripod wedge's outline with h = %g m in %.2f s", h, time.perf_counter() - start)
    triangles = topology["topology"].astype(np.int64)
    used, triangles = np.unique(triangles, return_inverse=True)
    return x[used], triangles.reshape(-1, 3 * order), topology["cell_data"].astype(np.int32)


def _extrude_layers(
    x2: np.ndarray, triangles: np.ndarray, tags2: np.ndarray, thickness: float, layers: int, order: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Extrude a triangulated outline (z = −thickness/2) through the thickness in ``layers`` layers of tetrahedra.

    Each layer holds one prism per triangle, split into three tetrahedra (gmsh's node order, positively oriented;
    10 nodes for ``order`` 2).

    The split is conforming: with the triangle's vertices ordered by node index a < b < c, the prism between
    layers k and k+1 is (a b c a'), (b c a' b'), (c a' b' c'), so the diagonal of every side face joins the
    lower-indexed vertex's top to the other's bottom whichever prism it belongs to. The midpoint of an edge of a
    tetrahedron (order 2) is the outline's midpoint node of the edge's footprint (curved arcs stay curved), at the
    mean height of its ends.
    """
    vertices = np.unique(triangles[:, :3])
    n_v = len(vertices)
    index = np.full(len(x2), -1, dtype=np.int64)
    index[vertices] = np.arange(n_v)
    z = -thickness / 2 + thickness * np.arange(layers + 1) / layers
    x_vertices = np.concatenate([np.column_stack([x2[vertices, :2], np.full(n_v, zk)]) for zk in z])
    tri = np.sort(index[triangles[:, :3]], axis=1)  # a < b < c
    a, b, c = tri.T
    tets, tags = [], []
    for k in range(layers):
        lo, hi = k * n_v, (k + 1) * n_v
        tets += [np.column_stack([a + lo, b + lo, c + lo, a + hi]), np.column_stack([b + lo, c + lo, a + hi, b + hi]),
                 np.column_stack([c + lo, a + hi, b + hi, c + hi])]
        tags += [tags2] * 3
    tets, tags = np.concatenate(tets), np.concatenate(tags)
    p = x_vertices[tets]
    negative = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) < 0
    tets[negative] = tets[negative][:, [1, 0, 2, 3]]
    if order == 1:
        return x_vertices, tets, tags
    # Edge midpoints: the outline's midpoint of the footprint (a, b) of each 3D edge, or the vertex for a vertical one.
    footprint_mid = {}
    for local in ((0, 1, 3), (1, 2, 4), (2, 0, 5)):
        for u, v, m in zip(index[triangles[:, local[0]]], index[triangles[:, local[1]]], triangles[:, local[2]]):
            footprint_mid[(min(u, v), max(u, v))] = m
    pairs = np.concatenate([tets[:, list(e)] for e in _TET10_EDGES])  # (6 n_tets, 2), edge by edge
    keys, inverse = np.unique(np.sort(pairs, axis=1), axis=0, return_inverse=True)
    ends = keys % n_v
    mid_xy = np.array([x2[footprint_mid[(min(u, v), max(u, v))], :2] if u != v else x_vertices[u, :2]
                       for u, v in ends])
    mid_z = 0.5 * (x_vertices[keys[:, 0], 2] + x_vertices[keys[:, 1], 2])
    x = np.concatenate([x_vertices, np.column_stack([mid_xy, mid_z])])
    midpoints = (len(x_vertices) + np.reshape(inverse, (len(_TET10_EDGES), -1))).T
    return x, np.concatenate([tets, midpoints], axis=1), tags


def _mesh_wedge_layered(
    geometry: TripodGeometry, h: float, layers: int, order: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The wedge as ``layers`` layers of tetrahedra through the thickness (rank 0 only).

    Under an in-plane triangulation of size ``h``: nodes, cells in gmsh order, cell tags, gmsh cell type (4: tet4,
    11: tet10).
    """
    x2, triangles, tags2 = _mesh_wedge_face(geometry, h, order)
    x, cells, tags = _extrude_layers(x2, triangles, tags2, geometry.thickness, layers, order)
    return x, cells, tags, 4 if order == 1 else 11


def _replicate_wedge(
    x_wedge: np.ndarray, cells_wedge: np.ndarray, tags_wedge: np.ndarray, tol: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map the wedge mesh by the six elements of :func:`symmetry_group` and merge the nodes on the mirror planes.

    Copy g of wedge node j is ``G_g X_j``. A node on the mirror plane of ``G_s`` (s = 3: φ = 0°, s = 4: φ = 60°;
    distance ≤ ``tol``) is fixed by it, so copies g and ``g∘s`` of it are one node: each node keeps the copy of
    smallest index among them. This merge is topological (no coordinate search). Cell tags of copy g: arm 0's
    ``ARM[0]``, ``ARM_END[0]`` become those of the arm ``G_g e_x`` points along; ring and centre stay.

    Returns
    -------
    x, cells, tags
        Merged nodes (N, 3), cells (6 n_cells, nodes per cell) in gmsh's node order, cell tags.

    """
    group = symmetry_group()
    n = len(x_wedge)
    compose = np.array([[np.argmin(np.abs(group - a @ b).sum(axis=(1, 2))) for b in group] for a in group])
    canonical = np.repeat(np.arange(len(group))[:, None], n, axis=1)
    for mirror in (3, 4):
        angle = (mirror - 3) * WEDGE_ANGLE
        on_plane = np.abs(x_wedge[:, :2] @ [-math.sin(angle), math.cos(angle)]) <= tol
        canonical[:, on_plane] = np.minimum(canonical[:, on_plane], compose[:, mirror][:, None])
    keys, node = np.unique(canonical * n + np.arange(n), return_inverse=True)  # key g n + j: copy g of node j
    node = node.reshape(len(group), n)
    x = np.einsum("gij,nj->gni", group, x_wedge).reshape(-1, 3)[keys]
    cells, tags = [], []
    for g, element in enumerate(group):
        arm = round(math.atan2(element[1, 0], element[0, 0]) / (2 * math.pi / 3)) % 3
        cells.append(node[g][cells_wedge])
        tags.append(np.select([tags_wedge == ARM[0], tags_wedge == ARM_END[0]], [ARM[arm], ARM_END[arm]], tags_wedge))
    return x, np.concatenate(cells), np.concatenate(tags).astype(np.int32)


def make_tripod(
    comm: MPI.Comm, h: float = PAPER_H, geometry: TripodGeometry | None = None, order: int = 1, layers: int = 0
) -> TripodMesh:
    """Mesh the Tripod plate with tetrahedra of size ``h`` (m), tagged by region (:data:`REGIONS`), D3-invariant.

    gmsh meshes the fundamental wedge ``0° ≤ φ ≤ 60°`` on rank 0 (:meth:`TripodGeometry.build_gmsh_wedge`);
    the six images of the wedge under :func:`symmetry_group` are merged on the mirror planes and the mesh is
    distributed from rank 0 with ``dolfinx.mesh.create_mesh``, cell tags with it (see the module docstring).

    Parameters
    ----------
    comm : MPI.Comm
        Communicator of the mesh (gmsh runs on rank 0).
    h : float
        Target tetrahedron size (m), positive and at most ``2 · thickness``. :data:`PAPER_H` (5.2 mm) gives
        2694 tetrahedra, about the paper's 2684.
    geometry : TripodGeometry, optional
        Plate and servo parameters; defaults to ``TripodGeometry()`` (the tutorial's numbers).
    order : int
        Geometry degree, 1 or 2 (2 curves the arcs: hole, region boundaries, fillets).
    layers : int
        0 (default): gmsh's unstructured tetrahedra of size ``h`` everywhere, so ``h`` also sets the number of
        elements through the thickness. n ≥ 1: a layered plate, the wedge's outline triangulated with size ``h``
        and extruded through the thickness in n equal layers, each prism split into three tetrahedra
        (:func:`_extrude_layers`): ``6 · 3 n`` tetrahedra per outline triangle of the wedge, n elements through the
        thickness whatever the in-plane size.

    Returns
    -------
    TripodMesh
        Its ``facet_tags`` are empty (the plate has no facet tags).

    """
    geometry = TripodGeometry() if geometry is None else geometry
    if not (np.isfinite(h) and 0 < h <= 2 * geometry.thickness):
        raise InputError(
            f"Tripod element size h = {h!r} m must be positive and at most twice the thickness "
            f"({2 * geometry.thickness!r} m)"
        )
    check_order(order)
    if isinstance(layers, bool) or not isinstance(layers, (int, np.integer)) or layers < 0:
        raise InputError(f"Tripod layers = {layers!r} must be an integer ≥ 0 (0: unstructured tetrahedra, n ≥ 1: "
                         "n element layers through the thickness)")
    start = time.perf_counter()

    def build():
        if layers:
            x_wedge, cells_wedge, tags_wedge, cell_type = _mesh_wedge_layered(geometry, h, int(layers), order)
        else:
            x_wedge, cells_wedge, tags_wedge, cell_type = _mesh_wedge(geometry, h, order)
        return (*_replicate_wedge(x_wedge, cells_wedge, tags_wedge, 1e-9 * geometry.arm_length), cell_type)

    x, cells, tags, cell_type = on_rank0(comm, build, "gmsh failed to mesh the Tripod wedge") or (None,) * 4
    mesh, cell_tags, facet_tags = mesh_from_arrays(comm, x, cells, tags, gmsh_cell_type=cell_type)
    meshing_s = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
    return TripodMesh(mesh, cell_tags, facet_tags, h, order, meshing_s, geometry=geometry)
