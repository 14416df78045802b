"""Hinge (edge- and corner-only contacts) and island detection on constructed periodic voxel images."""

import numpy as np
import pytest

from foambase.errors import InputError
from homogenization.connectivity import connectivity, periodic_label, remove_floating_islands


def image(n=8, voxels=()):
    img = np.zeros((n, n, n), dtype=np.int8)
    for v in voxels:
        img[v] = 1
    return img


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_edge_only_contact_is_one_hinge_along_its_edge(axis):
    a, b = [d for d in range(3) if d != axis]
    second = [2, 2, 2]
    second[a] += 1
    second[b] += 1
    r = connectivity(image(voxels=[(2, 2, 2), tuple(second)]))
    expected = [0, 0, 0]
    expected[axis] = 1
    assert list(r.edge_contacts) == expected and r.corner_contacts == 0
    assert r.components == 2 and r.hinged_islands == 1 and r.floating_islands == 0


def test_corner_only_contact_and_bridged_contacts():
    r = connectivity(image(voxels=[(2, 2, 2), (3, 3, 3)]))
    assert r.corner_contacts == 1 and sum(r.edge_contacts) == 0 and r.hinged_islands == 1
    # a third voxel joining the pair face-wise removes the hinge
    r = connectivity(image(voxels=[(2, 2, 2), (3, 3, 2), (3, 2, 2)]))
    assert r.hinges == 0 and r.components == 1
    # a face-wise path through the 2×2×2 block removes the corner contact (but leaves no edge-only contact)
    r = connectivity(image(voxels=[(2, 2, 2), (3, 3, 3), (3, 2, 2), (3, 3, 2)]))
    assert r.hinges == 0 and r.components == 1
    # the other diagonal of the block: 8 patterns of one body diagonal each
    r = connectivity(image(voxels=[(3, 2, 2), (2, 3, 3)]))
    assert r.corner_contacts == 1


def test_contacts_and_components_across_the_periodic_boundary():
    r = connectivity(image(voxels=[(0, 0, 4), (7, 7, 4)]))  # an edge contact through the x and y boundaries
    assert list(r.edge_contacts) == [0, 0, 1] and r.components == 2
    r = connectivity(image(voxels=[(0, 4, 4), (7, 4, 4)]))  # a face contact through the x boundary
    assert r.hinges == 0 and r.components == 1
    r = connectivity(image(voxels=[(0, 0, 0), (7, 7, 7)]))
    assert r.corner_contacts == 1
    labels, n = periodic_label(image(voxels=[(0, 4, 4), (7, 4, 4), (3, 3, 3)]) > 0)
    assert n == 2 and labels[0, 4, 4] == labels[7, 4, 4] != labels[3, 3, 3]


def test_islands_hinged_and_floating_and_their_removal():
    img = np.zeros((10, 10, 10), dtype=np.int8)
    img[:, :, 0:2] = 1  # a percolating plate
    img[4, 4, 2] = 1  # attached face-wise: part of the main solid
    img[2, 7, 3] = 1  # two layers above the plate, touching nothing: floating
    img[7, 3, 3] = 1  # floating too
    img[4, 5, 3] = 1  # edge-only contact with (4, 4, 2) (edge along x): a hinged island
    r = connectivity(img)
    assert r.main_voxels == 201 and r.components == 4
    assert (r.hinged_islands, r.hinged_island_voxels) == (1, 1)
    assert (r.floating_islands, r.floating_island_voxels) == (2, 2)
    assert list(r.edge_contacts) == [1, 0, 0]
    cleaned = remove_floating_islands(img)
    assert cleaned.sum() == img.sum() - 2 and cleaned[4, 5, 3] == 1 and cleaned[2, 7, 3] == 0
    after = connectivity(cleaned)
    assert after.floating_islands == 0 and after.hinged_islands == 1


def test_floating_islands_do_not_change_c():
    """An island inside a closed pore carries no load: C is the same with and without it (hex8, zero void; the
    island's rigid-body modes cost CG a few iterations, 26 against 20, measured)."""
    from homogenization.fft import homogenize_fft
    from homogenization.tensors import isotropic_voigt

    img = np.ones((10, 10, 10), dtype=np.int8)
    img[2:8, 2:8, 2:8] = 0  # a closed cubic pore
    img[4:6, 4:6, 4:6] = 1  # an island floating in it
    assert connectivity(img).floating_islands == 1
    materials = [np.zeros((6, 6)), isotropic_voigt(1.0, 0.3)]
    kwargs = dict(discretization="hex8", tol=1e-10, threads=1, macro_strains=np.eye(6)[[0, 3]])
    a = homogenize_fft(img, materials, **kwargs).C_raw[:, [0, 3]]
    b = homogenize_fft(remove_floating_islands(img), materials, **kwargs).C_raw[:, [0, 3]]
    assert np.abs(a - b).max() < 1e-9 * np.abs(b).max()


def test_bad_images_are_refused():
    with pytest.raises(InputError, match="3-D"):
        connectivity(np.zeros((4, 4)))
    with pytest.raises(InputError, match="dtype"):
        connectivity(np.zeros((4, 4, 4)))
    assert connectivity(np.zeros((4, 4, 4), dtype=bool)).components == 0
