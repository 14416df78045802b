"""The Tripod robot's soft plate: a parametric Y-shaped plate with a central hole, tagged for scenes and probes.

Geometry (SoftRobots Tripod tutorial, DESIGN.md "Scenes"; SI units, metres). The plate lies in the x–y plane,
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
:data:`ARM` 11–13      centre ≤ r < arm_end     arm i (case A: TI 30 % foam with its l axis along e_i)
:data:`ARM_END` 21–23  r ≥ arm_end              the part of arm i carried rigidly by servo i's horn
=====================  =======================  ======================================================

Defaults: ring 5–10 mm, centre r < 20 mm (just beyond the re-entrant corners, so the centre holds the whole hub
where the arms overlap and each arm region is a plain strip), arm ends r ≥ 45 mm. Named unions of tags are in
:data:`REGIONS` (e.g. ``"centre" = (RING, CENTRE)``, ``"arm1" = (12, 22)``). The plate has no facet tags.

Servos (:meth:`TripodGeometry.servo_frames`): servo i turns about the horizontal axis tangential to the circle of
radius ``servo_radius`` (60 mm) through its pivot ``p_i = servo_radius e_i + pivot_z e_z``; the axis is the
counter-clockwise tangent ``t_i = e_z × e_i = (−sin φ_i, cos φ_i, 0)``. A horn angle θ rotates the arm end
rigidly by θ about ``t_i`` (right-hand rule), so a positive angle lifts the arm end (+z) as the arm end lies
inside the servo circle: ``x = p + R(θ, t)(X − p)``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import dolfinx
import gmsh
import numpy as np
from mpi4py import MPI

from meshes.beam import TaggedMesh, check_order, mesh_from_gmsh

__all__ = [
    "ARM",
    "ARM_ANGLES_DEG",
    "ARM_END",
    "CENTRE",
    "PAPER_H",
    "REGIONS",
    "RING",
    "ServoFrame",
    "TripodGeometry",
    "TripodMesh",
    "make_tripod",
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
#: Element size (m) of the paper-like mesh: with the default geometry it gives 2.7k tetrahedra (paper: 2684).
PAPER_H: float = 0.0046


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
    """Parameters of the Tripod plate and of its servos (m); defaults from DESIGN.md (SoftRobots tutorial, mm → m).

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
        The arm ends ``r ≥ arm_end_radius`` are carried rigidly by the servo horns.
    fillet_radius : float
        Radius of the fillets of the three re-entrant corners; 0 for sharp corners.
    servo_radius : float
        Radius of the circle on which the servo axes lie (tangentially).
    horn_length : float
        Length of a servo horn (for the scene's bookkeeping; the arm end's motion only needs the servo axis).
    pivot_z : float
        Height of the servo axes (0: the plate's mid-plane).

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

    def __post_init__(self) -> None:
        for key in ("thickness", "arm_width", "arm_length", "hole_radius", "ring_radius", "centre_radius",
                    "arm_end_radius", "servo_radius", "horn_length"):
            value = getattr(self, key)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"Tripod {key} must be a positive length in metres, got {value!r}")
        if not (np.isfinite(self.fillet_radius) and self.fillet_radius >= 0):
            raise ValueError(f"Tripod fillet_radius must be ≥ 0 m (0: sharp corners), got {self.fillet_radius!r}")
        if not np.isfinite(self.pivot_z):
            raise ValueError(f"Tripod pivot_z must be a finite height in metres, got {self.pivot_z!r}")
        radii = [("hole_radius", self.hole_radius), ("ring_radius", self.ring_radius),
                 ("re-entrant corner radius arm_width/(2 sin 60°)", self.reentrant_radius),
                 ("centre_radius", self.centre_radius), ("arm_end_radius", self.arm_end_radius),
                 ("arm_length", self.arm_length)]
        for (name_a, a), (name_b, b) in zip(radii[:-1], radii[1:]):
            if not a < b:
                raise ValueError(f"Tripod radii must increase: {name_a} = {a!r} m is not < {name_b} = {b!r} m")
        if not self.fillet_outer_radius < self.centre_radius:
            raise ValueError(
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
        """Exact area of one arm end ``{r ≥ R} ∩ arm`` (m²): ``w L − (w/2) √(R² − w²/4) − R² asin(w/(2R))``."""
        w, L, R = self.arm_width, self.arm_length, self.arm_end_radius
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

    def build_gmsh_model(self) -> None:
        """Create the tagged plate in the current gmsh model (OpenCASCADE kernel); called on rank 0 only.

        The outline is built in the plane ``z = −thickness/2``: fused arm rectangles, fillet patches (kite
        minus disc), minus the hole; it is split by the discs ``r < ring_radius``, ``r < centre_radius`` and
        ``r < arm_end_radius`` (the fragment map tells which discs hold each piece), each piece is extruded by
        ``thickness`` and the volumes are fragmented so that neighbouring regions share their interfaces.
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
        radii = (self.ring_radius, self.centre_radius, self.arm_end_radius)
        discs = [(2, occ.addDisk(0.0, 0.0, z0, r, r)) for r in radii]
        _, piece_map = occ.fragment(plate, discs)
        plate_pieces = {tag for pieces in piece_map[: len(plate)] for _, tag in pieces}
        in_discs = [{tag for _, tag in pieces} for pieces in piece_map[len(plate) :]]
        occ.remove([(2, tag) for tag in set().union(*in_discs) - plate_pieces], recursive=True)

        volumes, tags = [], []
        for piece in sorted(plate_pieces):
            n_discs = sum(piece in disc for disc in in_discs)  # 3: ring, 2: centre, 1: arm, 0: arm end
            if n_discs >= 2:
                tags.append(RING if n_discs == 3 else CENTRE)
            else:
                x, y, _ = occ.getCenterOfMass(2, piece)
                arm = round(math.atan2(y, x) / (2 * math.pi / 3)) % 3
                tags.append(ARM[arm] if n_discs == 1 else ARM_END[arm])
            volumes.append(next(dt for dt in occ.extrude([(2, piece)], 0.0, 0.0, self.thickness) if dt[0] == 3))
        _, volume_map = occ.fragment(volumes[:1], volumes[1:])
        occ.synchronize()
        for tag in sorted(set(tags)):
            members = [vt for t, vols in zip(tags, volume_map) if t == tag for _, vt in vols]
            gmsh.model.addPhysicalGroup(3, members, tag)
        if set(tags) != set(REGIONS["plate"]):
            raise RuntimeError(f"Tripod regions came out as cell tags {sorted(set(tags))}, expected {REGIONS['plate']}")

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
            raise ValueError(f"unknown Tripod region {region!r}; valid regions: {sorted(REGIONS)}")
        return np.unique(np.concatenate([self.cell_tags.find(tag) for tag in REGIONS[region]]))

    def arm_end_dofs(self, V: dolfinx.fem.FunctionSpace, servo: int) -> np.ndarray:
        """Dofs of ``V`` on the arm end carried by ``servo`` (0, 1, 2): every node of the cells r ≥ arm_end_radius.

        Block indices for a vector space, as ``fem.locate_dofs_topological(V, 3, cells)`` returns them; pass them
        with a Function interpolating :meth:`ServoFrame.displacement` to ``fem.dirichletbc``.
        """
        if servo not in (0, 1, 2):
            raise ValueError(f"servo must be 0, 1 or 2, got {servo!r}")
        cells = self.region_cells(f"arm_end{servo}")
        return dolfinx.fem.locate_dofs_topological(V, self.mesh.topology.dim, cells)


def make_tripod(
    comm: MPI.Comm, h: float = PAPER_H, geometry: TripodGeometry | None = None, order: int = 1
) -> TripodMesh:
    """Mesh the Tripod plate with tetrahedra of size ``h`` (m), tagged by region (:data:`REGIONS`).

    Parameters
    ----------
    comm : MPI.Comm
        Communicator of the mesh (gmsh runs on rank 0).
    h : float
        Target tetrahedron size (m), positive and at most ``2 · thickness``. :data:`PAPER_H` (4.6 mm) gives
        2738 tetrahedra, about the paper's 2684.
    geometry : TripodGeometry, optional
        Plate and servo parameters; defaults to ``TripodGeometry()`` (DESIGN.md numbers).
    order : int
        Geometry degree, 1 or 2 (2 curves the arcs: hole, region boundaries, fillets).

    Returns
    -------
    TripodMesh

    """
    geometry = TripodGeometry() if geometry is None else geometry
    if not (np.isfinite(h) and 0 < h <= 2 * geometry.thickness):
        raise ValueError(
            f"Tripod element size h = {h!r} m must be positive and at most twice the thickness "
            f"({2 * geometry.thickness!r} m)"
        )
    check_order(order)
    mesh, cell_tags, facet_tags, meshing_s = mesh_from_gmsh(comm, "tripod", geometry.build_gmsh_model, h, order)
    return TripodMesh(mesh, cell_tags, facet_tags, h, order, meshing_s, geometry=geometry)
