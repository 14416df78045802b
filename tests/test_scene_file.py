"""Scenes on a mesh file (``builder = "file"``): validation of the file's physical groups, and a cantilever
read from a gmsh ``.msh`` file sagging as Timoshenko's beam theory predicts (serial and under mpirun)."""

import gmsh
import pytest
from mpi4py import MPI

from fenicsfoam.scene import SceneError, load_scene, parse_scene, run_scene
from meshes.msh import physical_groups

L, A = 0.25, 0.015                 # beam length and square side (m)
E, NU, RHO = 1.0e6, 0.3, 180.0      # isotropic, SI
H = 0.0075                         # mesh size: P2 is within ~0.1 % of the converged sag here (speed_accuracy)


def write_beam_msh(path, tip_name="tip"):
    """The beam as two volumes (x < L/2: physical 1 "root", x > L/2: physical 2, unnamed), faces x = 0
    (physical 11 "clamped") and x = L (physical 12, named ``tip_name``)."""
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("beam")
        a = gmsh.model.occ.addBox(0, -A / 2, -A / 2, L / 2, A, A)
        b = gmsh.model.occ.addBox(L / 2, -A / 2, -A / 2, L / 2, A, A)
        gmsh.model.occ.fragment([(3, a)], [(3, b)])
        gmsh.model.occ.synchronize()
        volumes = sorted(gmsh.model.getEntities(3), key=lambda e: gmsh.model.occ.getCenterOfMass(*e)[0])
        gmsh.model.addPhysicalGroup(3, [volumes[0][1]], 1)
        gmsh.model.setPhysicalName(3, 1, "root")
        gmsh.model.addPhysicalGroup(3, [volumes[1][1]], 2)
        faces = {round(gmsh.model.occ.getCenterOfMass(2, s)[0], 9): s for _, s in gmsh.model.getEntities(2)}
        gmsh.model.addPhysicalGroup(2, [faces[0.0]], 11)
        gmsh.model.setPhysicalName(2, 11, "clamped")
        gmsh.model.addPhysicalGroup(2, [faces[L]], 12)
        gmsh.model.setPhysicalName(2, 12, tip_name)
        gmsh.option.setNumber("Mesh.MeshSizeMax", H)
        gmsh.model.mesh.generate(3)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    return path


@pytest.fixture
def beam_msh(tmp_path):
    """The beam file, written on rank 0 and shared with the other ranks (a path every rank can read)."""
    comm = MPI.COMM_WORLD
    path = write_beam_msh(tmp_path / "beam.msh") if comm.rank == 0 else None
    return comm.bcast(path, root=0)


def file_scene(path, **overrides):
    material = {"material": "isotropic", "E": E, "nu": NU, "rho": RHO}
    scene = {
        "name": "beam_from_file",
        "geometry": {"builder": "file", "path": str(path)},
        "fem": {"model": "linear", "degree": 2},
        "regions": {"root": {"tags": "root", **material}, "tip_half": {"tags": 2, **material}},
        "loads": {"gravity": [0.0, 0.0, -9.81], "clamp": "clamped"},
        "steps": [{"label": "gravity", "gravity": 1.0}],
        "probes": ["tip_deflection"],
        "outputs": {"xdmf": False, "png": False},
    }
    scene.update(overrides)
    return scene


def timoshenko_sag() -> float:
    """Cantilever under its weight: q L⁴/(8 E I) + q L²/(2 κ G A), κ = 10(1+ν)/(12+11ν), q = ρ g A."""
    q, kappa = RHO * 9.81 * A * A, 10 * (1 + NU) / (12 + 11 * NU)
    return q * L**4 / (8 * E * A**4 / 12) + q * L**2 / (2 * kappa * E / (2 * (1 + NU)) * A * A)


def test_physical_groups_of_a_msh_file(tmp_path):
    groups = physical_groups(write_beam_msh(tmp_path / "beam.msh"))
    assert groups.cells == {1, 2} and groups.facets == {11, 12}
    assert groups.cell_names == {"root": 1} and groups.facet_names == {"clamped": 11, "tip": 12}


@pytest.mark.mpi
def test_beam_from_a_msh_file_sags_as_timoshenko_predicts(beam_msh):
    result = run_scene(file_scene(beam_msh))
    sag = -result.steps[-1].probes["tip_deflection"]
    assert result.n_cells > 0
    assert sag == pytest.approx(timoshenko_sag(), rel=0.01)  # linear P2: within 1 % of the beam theory


def test_relative_path_is_read_from_the_scene_files_directory(tmp_path):
    write_beam_msh(tmp_path / "beam.msh")
    toml = tmp_path / "scene.toml"
    toml.write_text('name = "rel"\n[geometry]\nbuilder = "file"\npath = "beam.msh"\n'
                    '[regions.all]\ntags = [1, 2]\nmaterial = "isotropic"\nE = 1e6\nnu = 0.3\n'
                    '[[steps]]\nlabel = "rest"\n')
    assert load_scene(toml).geometry["path"] == tmp_path / "beam.msh"


@pytest.mark.parametrize("edit, message", [
    (lambda s, p: s["geometry"].update(path=str(p.with_name("missing.msh"))), "geometry.path: .*does not exist"),
    (lambda s, p: s["geometry"].update(path=str(p.with_suffix(".xdmf"))), "does not exist|expected a gmsh .msh"),
    (lambda s, p: s["geometry"].update(h=0.01), r"geometry\.h"),
    (lambda s, p: s["regions"].pop("tip_half"), r"cell tags \[2\] of the file mesh have no region"),
    (lambda s, p: s["regions"]["root"].update(tags="stem"), "unknown region name 'stem'; valid names: root"),
    (lambda s, p: s["regions"]["tip_half"].update(tags=3), "cell tag 3 is not a tag of the file mesh"),
    (lambda s, p: s["loads"].update(clamp="wall"), "unknown facet group name 'wall'"),
    (lambda s, p: s["loads"].update(servos=True), "servo horns need the tripod builder"),
    (lambda s, p: s.update(probes=["center_height"]), "needs the tripod builder"),
])
def test_invalid_file_scene_names_the_key(tmp_path, edit, message):
    path = write_beam_msh(tmp_path / "beam.msh")
    scene = file_scene(path)
    edit(scene, path)
    with pytest.raises(SceneError, match=message):
        parse_scene(scene)


def test_tip_probe_needs_a_tip_facet_group(tmp_path):
    path = write_beam_msh(tmp_path / "beam.msh", tip_name="free_end")
    with pytest.raises(SceneError, match="needs a facet group named 'tip'.*free_end"):
        parse_scene(file_scene(path))


def test_unreadable_file_is_a_scene_error(tmp_path):
    path = tmp_path / "broken.msh"
    path.write_text("$MeshFormat\nnot a mesh\n")
    with pytest.raises(SceneError, match="geometry.path: mesh file .*broken.msh: cannot read it"):
        parse_scene(file_scene(path))
