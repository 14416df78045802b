"""Connectivity of a periodic voxel solid: edge- and corner-only contacts (hinges) and islands.

In any voxel discretization two solid voxels that touch only along an edge or at a corner share one line or one
point of nodes: a hinge, about which the two can rotate at zero energy (fully integrated voxels) or, with
one-point voxels, also deform in hourglass patterns. A solid piece not connected face-wise to the rest is an
island: with a zero-stiffness void its rigid-body motions are zero-energy modes (harmless for the
Green-preconditioned CG, whose right-hand side is orthogonal to them, but load-free material in the image).
Stair-stepped walls two to four voxels thick make both likely. The checks are local patterns and periodic
connected-component labelling (:func:`scipy.ndimage.label` on the image padded by one periodic layer, the labels
of the copies merged).

- an **edge contact** is an edge of the voxel grid whose four voxels are solid on one diagonal and void on the
  other (``[[1, 0], [0, 1]]`` in the plane normal to the edge);
- a **corner contact** is a grid node whose 2×2×2 voxels hold two solid voxels on a body diagonal that are not
  connected face-wise through the other six;
- the **main solid** is the largest face-connected (6-connected, periodic) component; every other component is an
  **island**; a *hinged* island touches the main solid through an edge or a corner (it is in the main solid's
  26-connected component), a *floating* island does not touch it at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from foambase.errors import InputError

__all__ = ["ConnectivityReport", "connectivity", "periodic_label", "remove_floating_islands"]


def _check_image(image) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 3 or min(image.shape) < 1:
        raise InputError(f"image must be a 3-D (N1, N2, N3) array of voxels, got shape {image.shape}")
    if image.dtype != bool and not np.issubdtype(image.dtype, np.integer):
        raise InputError(f"image must hold 0/1 (or bool) voxels, got dtype {image.dtype}")
    return image != 0


def periodic_label(solid: np.ndarray, connectivity: int = 1) -> tuple[np.ndarray, int]:
    """Labels ``1 … n`` of the connected components of ``solid`` on the periodic grid (0 on void), and ``n``.

    ``connectivity`` 1: face neighbours (6); 3: face, edge and corner neighbours (26).
    """
    solid = np.asarray(solid, dtype=bool)
    structure = ndimage.generate_binary_structure(3, connectivity)
    padded = np.pad(solid, 1, mode="wrap")
    labels, n = ndimage.label(padded, structure=structure)
    if n == 0:
        return np.zeros(solid.shape, dtype=np.int64), 0
    # every padded voxel is a copy of the interior voxel at the wrapped index: merge their labels
    shape = np.array(solid.shape)
    idx = np.indices(padded.shape).reshape(3, -1)
    orig = ((idx - 1) % shape[:, None]) + 1
    a = labels.ravel()
    b = labels[orig[0], orig[1], orig[2]]
    pairs = np.unique(np.stack([a, b], axis=1)[(a > 0) & (a != b)], axis=0)
    parent = np.arange(n + 1)

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for x, y in pairs:
        rx, ry = find(x), find(y)
        if rx != ry:
            parent[max(rx, ry)] = min(rx, ry)
    roots = np.array([find(x) for x in range(n + 1)])
    interior = roots[labels[1:-1, 1:-1, 1:-1]]
    uniq, inverse = np.unique(interior, return_inverse=True)  # 0 (void) first if present
    relabel = inverse.reshape(interior.shape)
    if uniq[0] != 0:
        relabel = relabel + 1
    return relabel.astype(np.int64), int(np.count_nonzero(uniq))


def _corner_table() -> np.ndarray:
    """For each of the 256 patterns of a 2×2×2 block (bit ``4 da + 2 db + dc``): does it hold a corner contact?"""
    table = np.zeros(256, dtype=bool)
    neighbours = [[n ^ 1, n ^ 2, n ^ 4] for n in range(8)]
    for code in range(256):
        solid = [(code >> n) & 1 for n in range(8)]
        for n in range(4):
            m = 7 - n
            if not (solid[n] and solid[m]):
                continue
            seen, stack = {n}, [n]
            while stack:
                x = stack.pop()
                for y in neighbours[x]:
                    if solid[y] and y not in seen:
                        seen.add(y)
                        stack.append(y)
            if m not in seen:
                table[code] = True
    return table


_CORNER = _corner_table()


def edge_contacts(solid: np.ndarray) -> np.ndarray:
    """Per axis of the edge (0, 1, 2), the number of periodic grid edges that are edge-only contacts."""
    counts = []
    for axis in range(3):
        a, b = [d for d in range(3) if d != axis]
        s00 = solid
        s10 = np.roll(solid, -1, a)
        s01 = np.roll(solid, -1, b)
        s11 = np.roll(s10, -1, b)
        hinge = (s00 & s11 & ~s10 & ~s01) | (s10 & s01 & ~s00 & ~s11)
        counts.append(int(np.count_nonzero(hinge)))
    return np.array(counts)


def corner_contacts(solid: np.ndarray) -> int:
    """Number of periodic grid nodes that are corner-only contacts (a body diagonal not joined through the block)."""
    code = np.zeros(solid.shape, dtype=np.uint8)
    for n in range(8):
        shift = (-((n >> 2) & 1), -((n >> 1) & 1), -(n & 1))
        code |= np.roll(solid, shift, axis=(0, 1, 2)).astype(np.uint8) << n
    return int(np.count_nonzero(_CORNER[code]))


@dataclass(frozen=True)
class ConnectivityReport:
    """What :func:`connectivity` found in one image."""

    solid_voxels: int
    edge_contacts: tuple[int, int, int]  #: edge-only contacts per edge direction (x, y, z)
    corner_contacts: int  #: corner-only contacts
    components: int  #: face-connected (periodic) solid components
    main_voxels: int  #: voxels of the largest one (the main solid)
    hinged_islands: int  #: other components touching the main solid through an edge or a corner only
    hinged_island_voxels: int
    floating_islands: int  #: other components not touching the main solid at all
    floating_island_voxels: int

    @property
    def hinges(self) -> int:
        """Edge- and corner-only contacts together."""
        return int(sum(self.edge_contacts) + self.corner_contacts)

    def as_dict(self) -> dict:
        out = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["edge_contacts"] = list(self.edge_contacts)
        out["hinges"] = self.hinges
        return out


def connectivity(image) -> ConnectivityReport:
    """Hinges (edge- and corner-only contacts) and islands of the solid (non-zero voxels) of a periodic image."""
    solid = _check_image(image)
    faces, n = periodic_label(solid, 1)
    if n == 0:
        return ConnectivityReport(0, (0, 0, 0), 0, 0, 0, 0, 0, 0, 0)
    sizes = np.bincount(faces.ravel(), minlength=n + 1)
    sizes[0] = 0
    main = int(np.argmax(sizes))
    touching, _ = periodic_label(solid, 3)
    main_26 = touching[faces == main].flat[0]
    hinged = floating = hinged_v = floating_v = 0
    for label in range(1, n + 1):
        if label == main:
            continue
        member = faces == label
        if touching[member].flat[0] == main_26:
            hinged, hinged_v = hinged + 1, hinged_v + int(sizes[label])
        else:
            floating, floating_v = floating + 1, floating_v + int(sizes[label])
    return ConnectivityReport(int(solid.sum()), tuple(int(c) for c in edge_contacts(solid)), corner_contacts(solid),
                              n, int(sizes[main]), hinged, hinged_v, floating, floating_v)


def remove_floating_islands(image) -> np.ndarray:
    """The image with every solid component that touches the main solid nowhere (not even at an edge or a corner)
    set to 0. Such islands carry no load with a zero-stiffness void, so ``C`` does not change; the rigid-body
    modes they add to the stiffness disappear. Hinged islands are kept (they may carry load through the hinge)."""
    solid = _check_image(image)
    touching, n = periodic_label(solid, 3)
    out = np.array(image, copy=True)
    if n <= 1:
        return out
    faces, nf = periodic_label(solid, 1)
    sizes = np.bincount(faces.ravel(), minlength=nf + 1)
    sizes[0] = 0
    keep = touching[faces == int(np.argmax(sizes))].flat[0]
    out[(touching != keep) & solid] = 0
    return out
