"""A soft finger: a box with an optional internal chamber (a pneumatic bending actuator), meshed by gmsh.

Geometry (SI units, metres): the box ``0 ≤ x ≤ length``, ``|y| ≤ width/2``, ``|z| ≤ height/2``, its base ``x = 0``
(usually clamped) and its tip ``x = length``. With ``chamber = true`` a box-shaped cavity runs along the finger:
``end_wall ≤ x ≤ length − end_wall``, ``|y| ≤ width/2 − side_wall``, ``−height/2 + bottom_wall ≤ z ≤
height/2 − top_wall``. A thin top wall over a thick bottom wall makes an inflated chamber bend the finger
downwards (towards its thick, strain-limiting side): the pressure on the end walls stretches the finger along a
line above the neutral axis of its hollow section, and the thin top wall stretches more than the thick bottom.
Without a chamber the finger is a plain box, e.g. for a cable-driven finger. With ``pad > 0`` the bottom face is
split at ``x = length − pad`` (the volume too, conformingly): the patch near the tip is the facet group ``pad``, where a
support (a load cell, a table) can touch the finger.

Tags (gmsh physical groups, named, so that scenes and :func:`meshes.msh.physical_groups` see them by name):

=========  =====  ==========================================
group      tag    what
=========  =====  ==========================================
finger     1      the volume (cell tag)
base       11     the face ``x = 0``
tip        12     the face ``x = length``
top        13     the face ``z = height/2``
bottom     14     the face ``z = −height/2`` (without the pad)
sides      15     the faces ``y = ±width/2``
pad        16     the bottom face's last ``pad`` metres, ``x ≥ length − pad`` (with ``pad > 0``)
chamber    20     the cavity's walls (with ``chamber = true``)
=========  =====  ==========================================

:func:`make_finger` builds and distributes the mesh (the scene builder ``"finger"``); :func:`write_finger_msh`
writes the same model to a gmsh ``.msh`` file, as a user's own gmsh script would (``builder = "file"``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

import gmsh
from mpi4py import MPI

from foambase.errors import InputError
from foambase.files import atomic_path
from meshes.beam import TaggedMesh, check_order, generate_tetrahedra, mesh_from_gmsh

__all__ = ["CELL_TAGS", "FACET_TAGS", "FingerGeometry", "FingerMesh", "build_gmsh_finger", "make_finger",
           "write_finger_msh"]

#: Named cell tags.
CELL_TAGS: dict[str, int] = {"finger": 1}
#: Named facet tags.
FACET_TAGS: dict[str, int] = {"base": 11, "tip": 12, "top": 13, "bottom": 14, "sides": 15, "pad": 16,
                              "chamber": 20}


@dataclass(frozen=True)
class FingerGeometry:
    """Sizes of the finger and of its chamber (m); the defaults are a 100 × 20 × 15 mm pneumatic finger."""

    length: float = 0.100
    width: float = 0.020
    height: float = 0.015
    chamber: bool = True         #: an internal cavity (a pneumatic chamber)
    top_wall: float = 0.002      #: wall above the chamber (the thin, extensible side)
    bottom_wall: float = 0.006   #: wall below the chamber (the thick, strain-limiting side)
    side_wall: float = 0.003     #: walls beside the chamber
    end_wall: float = 0.005      #: walls at both ends of the chamber
    pad: float = 0.0             #: length of the bottom face's patch at the tip (facet group ``pad``); 0: none

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name not in ("chamber", "pad") and not (isinstance(value, int | float) and value > 0):
                raise InputError(f"finger {f.name} must be a length > 0 (m), got {value!r}")
        if not (isinstance(self.pad, int | float) and 0 <= self.pad < self.length):
            raise InputError(f"finger pad must be a length in [0, length) (m), got {self.pad!r}")
        if self.chamber:
            for what, walls, size in (("length", 2 * self.end_wall, self.length),
                                      ("width", 2 * self.side_wall, self.width),
                                      ("height", self.top_wall + self.bottom_wall, self.height)):
                if walls >= size:
                    raise InputError(f"finger: the walls across the {what} ({walls:g} m) leave no room for the "
                                     f"chamber in {what} = {size:g} m")

    @property
    def chamber_box(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Lower and upper corners of the chamber (m)."""
        return ((self.end_wall, -self.width / 2 + self.side_wall, -self.height / 2 + self.bottom_wall),
                (self.length - self.end_wall, self.width / 2 - self.side_wall, self.height / 2 - self.top_wall))

    @property
    def chamber_volume(self) -> float:
        """Volume of the undeformed chamber (m³); 0 without a chamber."""
        if not self.chamber:
            return 0.0
        lo, hi = self.chamber_box
        return (hi[0] - lo[0]) * (hi[1] - lo[1]) * (hi[2] - lo[2])

    @property
    def volume(self) -> float:
        """Volume of the material (m³)."""
        return self.length * self.width * self.height - self.chamber_volume


@dataclass(frozen=True, kw_only=True)
class FingerMesh(TaggedMesh):
    """The finger's tagged mesh and its geometry."""

    geometry: FingerGeometry


def build_gmsh_finger(geometry: FingerGeometry) -> None:
    """Create the finger in the current gmsh model, with its physical groups (:data:`CELL_TAGS`, :data:`FACET_TAGS`)."""
    occ = gmsh.model.occ
    g = geometry
    split = g.length - g.pad
    if g.pad > 0:  # two boxes sharing the face x = length − pad
        pieces = [(3, occ.addBox(0.0, -g.width / 2, -g.height / 2, split, g.width, g.height)),
                  (3, occ.addBox(split, -g.width / 2, -g.height / 2, g.pad, g.width, g.height))]
        pieces, _ = occ.fragment(pieces[:1], pieces[1:])
    else:
        pieces = [(3, occ.addBox(0.0, -g.width / 2, -g.height / 2, g.length, g.width, g.height))]
    if g.chamber:
        lo, hi = g.chamber_box
        cavity = occ.addBox(*lo, *(b - a for a, b in zip(lo, hi)))
        pieces, _ = occ.cut(pieces, [(3, cavity)])
        if len(pieces) > 1:
            pieces, _ = occ.fragment(pieces[:1], pieces[1:])  # conforming at the shared face
    occ.synchronize()
    volumes = [tag for _, tag in gmsh.model.getEntities(3)]
    tol = 1e-4 * min(g.length, g.width, g.height)  # gmsh pads bounding boxes by 1e-7
    groups: dict[str, list[int]] = {name: [] for name in FACET_TAGS}
    for _, surface in gmsh.model.getBoundary([(3, v) for v in volumes], combined=True, oriented=False):
        x0, y0, z0, x1, y1, z1 = gmsh.model.getBoundingBox(2, surface)
        if abs(x1) < tol:
            groups["base"].append(surface)
        elif abs(x0 - g.length) < tol:
            groups["tip"].append(surface)
        elif abs(z0 - g.height / 2) < tol:
            groups["top"].append(surface)
        elif abs(z1 + g.height / 2) < tol:
            groups["pad" if g.pad > 0 and x0 > split - tol else "bottom"].append(surface)
        elif abs(abs(y0) - g.width / 2) < tol and abs(y1 - y0) < tol:
            groups["sides"].append(surface)
        else:
            groups["chamber"].append(surface)
    gmsh.model.addPhysicalGroup(3, volumes, CELL_TAGS["finger"])
    gmsh.model.setPhysicalName(3, CELL_TAGS["finger"], "finger")
    for name, surfaces in groups.items():
        if surfaces:
            gmsh.model.addPhysicalGroup(2, surfaces, FACET_TAGS[name])
            gmsh.model.setPhysicalName(2, FACET_TAGS[name], name)


def _check(h: float, geometry: FingerGeometry, order: int) -> None:
    if not (isinstance(h, int | float) and h > 0):
        raise InputError(f"finger element size h must be > 0 (m), got {h!r}")
    thinnest = min(geometry.width, geometry.height)
    if geometry.chamber:
        thinnest = min(thinnest, geometry.top_wall, geometry.bottom_wall, geometry.side_wall, geometry.end_wall)
    if h > 2 * thinnest:
        raise InputError(f"finger element size h = {h:g} m is more than twice its thinnest wall ({thinnest:g} m); "
                         f"use h ≤ {2 * thinnest:g}")
    check_order(order)


def make_finger(comm: MPI.Comm, h: float, geometry: FingerGeometry | None = None, order: int = 1) -> FingerMesh:
    """Mesh the finger with tetrahedra of size ``h`` (m) on rank 0 of ``comm`` and distribute it.

    Raises
    ------
    foambase.errors.InputError
        A non-positive size, walls leaving no room for the chamber, ``h`` more than twice the thinnest wall, or an
        unsupported ``order``.

    """
    geometry = FingerGeometry() if geometry is None else geometry
    _check(h, geometry, order)
    mesh, cell_tags, facet_tags, meshing_s = mesh_from_gmsh(comm, "finger", lambda: build_gmsh_finger(geometry),
                                                            h, order)
    return FingerMesh(mesh, cell_tags, facet_tags, h, order, meshing_s, geometry=geometry)


def write_finger_msh(path: str | Path, h: float, geometry: FingerGeometry | None = None, order: int = 1) -> Path:
    """Write the finger's mesh to a gmsh ``.msh`` file atomically (serial: call it on one rank), as a script would."""
    geometry = FingerGeometry() if geometry is None else geometry
    _check(h, geometry, order)
    path = Path(path)
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("finger")
        build_gmsh_finger(geometry)
        generate_tetrahedra(h, order)
        with atomic_path(path) as tmp:
            gmsh.write(str(tmp))
    finally:
        gmsh.finalize()
    return path
