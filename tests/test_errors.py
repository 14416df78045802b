"""One error family: every exception class of the project derives from FenicsfoamError, keeps its builtin parent and
carries its exit code; representative bad calls of the public API are caught as FenicsfoamError and as the builtin."""

import importlib
import inspect
import pkgutil

import numpy as np
import pytest

import fenicsfoam
from foambase.errors import (
    EXIT_FAILURE,
    EXIT_INPUT,
    EXIT_NOT_CONVERGED,
    ComputationError,
    FenicsfoamError,
    InputError,
    NotConvergedError,
    exit_code,
)

PACKAGES = ("foambase", "meshes", "homogenization", "fenicsfoam")
#: Every named error of the project, its builtin parent and its exit code.
NAMED = {
    "meshes.foam.FoamParameterError": (ValueError, EXIT_INPUT),  # defined in meshes.errors
    "homogenization.tensors.InadmissibleMaterialError": (ValueError, EXIT_INPUT),
    "homogenization.fft.FFTConvergenceError": (RuntimeError, EXIT_NOT_CONVERGED),
    "fenicsfoam.solver.ConvergenceError": (RuntimeError, EXIT_NOT_CONVERGED),
    "fenicsfoam.scene.SceneError": (ValueError, EXIT_INPUT),
    "fenicsfoam.orientation.OrientationError": (ValueError, EXIT_INPUT),
    "fenicsfoam.validity.SmallStrainValidityError": (RuntimeError, EXIT_FAILURE),
    "fenicsfoam.calibrate.CalibrationError": (ValueError, EXIT_INPUT),
}


def project_modules():
    """Every module of the four packages (imported, so that a new module's errors are found too)."""
    for name in PACKAGES:
        package = importlib.import_module(name)
        yield package
        for info in pkgutil.walk_packages(package.__path__, prefix=f"{name}."):
            yield importlib.import_module(info.name)


def project_exceptions():
    found = {}
    for module in project_modules():
        for _, obj in inspect.getmembers(module, inspect.isclass):
            if issubclass(obj, BaseException) and obj.__module__.split(".")[0] in PACKAGES:
                found[f"{obj.__module__}.{obj.__qualname__}"] = obj
    return found


def named(path):
    module, _, name = path.rpartition(".")
    return getattr(importlib.import_module(module), name)


def test_every_exception_class_of_the_project_is_a_fenicsfoam_error():
    found = project_exceptions()
    assert {named(path) for path in NAMED} <= set(found.values())
    assert len(found) >= len(NAMED) + 4  # the named errors and the four categories (more as the project grows)
    # an interruption (foambase.signals.Interrupted) is a KeyboardInterrupt, not an error: `except Exception`
    # must not catch it
    outside = sorted(name for name, cls in found.items()
                     if not issubclass(cls, FenicsfoamError) and not issubclass(cls, KeyboardInterrupt))
    assert not outside, f"not in the FenicsfoamError family: {outside}"


@pytest.mark.parametrize("name", sorted(NAMED))
def test_named_errors_keep_their_builtin_parent_and_exit_code(name):
    cls = named(name)
    parent, code = NAMED[name]
    assert issubclass(cls, FenicsfoamError) and issubclass(cls, parent)
    assert cls.exit_code == code


def test_categories_and_exit_codes():
    assert issubclass(InputError, ValueError) and InputError.exit_code == 2
    assert issubclass(NotConvergedError, RuntimeError) and NotConvergedError.exit_code == 3
    assert issubclass(ComputationError, RuntimeError) and ComputationError.exit_code == 1
    assert exit_code(InputError("x")) == 2 and exit_code(KeyError("x")) == 1
    error = ComputationError("rank 0 failed")
    error.exit_code = 3  # an instance may carry another rank's code
    assert exit_code(error) == 3
    assert fenicsfoam.FenicsfoamError is FenicsfoamError
    from fenicsfoam.errors import FenicsfoamError as reexported
    assert reexported is FenicsfoamError


def test_package_face_imports_no_dolfinx():
    import subprocess
    import sys
    code = "import sys, fenicsfoam, fenicsfoam.errors; print('dolfinx' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def bad_density():
    from meshes.foam import VoronoiFoam
    VoronoiFoam(n_cells=8, density=1.5, gamma=1.0, seed=0)


def bad_scene_key():
    from fenicsfoam.scene import parse_scene
    region = {"tags": "beam", "material": "isotropic", "E": 1e6, "nu": 0.3}
    parse_scene({"geometry": {"builder": "beam"}, "regions": {"beam": region}, "steps": [{"label": "a"}],
                 "colour": "red"})


def bad_fft_phases():
    from homogenization.fft import homogenize_fft
    homogenize_fft(np.zeros((4, 4), dtype=np.int8), [np.eye(6)])


def bad_material():
    from fenicsfoam.materials import Isotropic
    Isotropic(E=-1.0, nu=0.3)


def bad_foam_table_solid():
    from fenicsfoam.materials import foam_material
    foam_material(0.18, 0.1, 12e6, 0.45)


def bad_fem_degree():
    from dolfinx import mesh
    from mpi4py import MPI

    from homogenization.fem import homogenize_fem
    cube = mesh.create_unit_cube(MPI.COMM_SELF, 1, 1, 1)
    tags = mesh.meshtags(cube, 3, np.arange(6, dtype=np.int32), np.ones(6, dtype=np.int32))
    homogenize_fem(cube, tags, {1: np.eye(6)}, degree=3)


def bad_model():
    from dolfinx import mesh
    from mpi4py import MPI

    from fenicsfoam.constitutive import MaterialField
    from fenicsfoam.materials import Isotropic
    from fenicsfoam.solver import ElasticityProblem
    cube = mesh.create_unit_cube(MPI.COMM_SELF, 1, 1, 1)
    ElasticityProblem(cube, MaterialField.uniform(cube, Isotropic(E=1.0, nu=0.3)), model="neo-hookean")


def bad_beam():
    from mpi4py import MPI

    from meshes.beam import make_beam
    make_beam(MPI.COMM_SELF, length=-1.0, width=0.01, height=0.01, h=0.005)


@pytest.mark.parametrize("call", [bad_density, bad_scene_key, bad_fft_phases, bad_material, bad_foam_table_solid,
                                  bad_fem_degree, bad_model, bad_beam], ids=lambda f: f.__name__)
def test_bad_input_is_a_fenicsfoam_error_and_still_a_value_error(call):
    with pytest.raises(FenicsfoamError) as info:
        call()
    assert call is not bad_scene_key or "colour: unknown key" in str(info.value)
    assert isinstance(info.value, ValueError) and exit_code(info.value) == EXIT_INPUT


def test_non_convergence_is_a_fenicsfoam_error_and_still_a_runtime_error():
    from homogenization.fft import homogenize_fft
    from homogenization.tensors import isotropic_voigt
    image = np.zeros((8, 8, 8), dtype=np.int8)
    image[2:6, 2:6, :] = 1
    with pytest.raises(FenicsfoamError) as info:
        homogenize_fft(image, [isotropic_voigt(1.0, 0.3), isotropic_voigt(100.0, 0.3)], maxiter=1, threads=1)
    assert isinstance(info.value, RuntimeError) and exit_code(info.value) == EXIT_NOT_CONVERGED
