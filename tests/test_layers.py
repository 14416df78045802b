"""The packages' dependencies point one way, foambase ← meshes ← homogenization ← fenicsfoam (docs/architecture.md):
every import statement of every module, read with ``ast`` (lazy imports inside functions included)."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Package → the packages of the project it may import (besides itself).
ALLOWED = {"foambase": set(), "meshes": {"foambase"}, "homogenization": {"foambase", "meshes"},
           "fenicsfoam": {"foambase", "meshes", "homogenization"}}


def imported(path: Path) -> set[str]:
    """Top-level names of every module ``path`` imports (absolute imports)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
    return names


@pytest.mark.parametrize("package", list(ALLOWED))
def test_no_package_imports_one_above_it(package):
    upward = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        above = {n for n in imported(path) if n.split(".")[0] in set(ALLOWED) - ALLOWED[package] - {package}}
        if above:
            upward[str(path.relative_to(ROOT))] = sorted(above)
    assert not upward, f"imports against foambase ← meshes ← homogenization ← fenicsfoam: {upward}"


def test_the_material_room_reads_no_scene_and_no_dolfinx():
    """fenicsfoam.material is below the scene layer (the schema and the builder loop over its registry)."""
    for path in sorted((ROOT / "fenicsfoam" / "material").glob("*.py")):
        names = {n for n in imported(path) if n.startswith(("fenicsfoam.scene", "dolfinx", "ufl", "petsc4py"))}
        assert not names, f"{path.name} imports {sorted(names)}"
