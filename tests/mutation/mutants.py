"""The curated deliberate bugs of ``make mutate`` (see ``mutate.py``): each an exact substitution in one file.

Every entry names the tests that should catch it (``targets``, run serially; ``mpi_targets``, run under
``mpirun -n 2`` when the bug only shows with several ranks). ``tests/test_mutation.py`` checks on every
``make test`` that each pattern still occurs exactly once (so a refactoring that moves the code makes that test
fail instead of leaving a mutation that silently tests nothing): when you move such code, update its entry here.
"""

from mutate import Mutation

MUTATIONS: tuple[Mutation, ...] = (
    # ---- the data pipeline: foam → voxels → FFT → table → materials -------------------------------------------
    Mutation(
        "table-ti-axis-z", "homogenization/tables.py",
        "ti = closest_transverse_isotropic(C, axis=(1.0, 0.0, 0.0))",
        "ti = closest_transverse_isotropic(C, axis=(0.0, 0.0, 1.0))",
        "the table's TI fit taken about z instead of the foam's distinct axis x",
        targets=("tests/test_tables.py::test_sample_row_fits_ti_about_the_foams_x_axis",)),
    Mutation(
        "paper-fit-nu-tl", "fenicsfoam/material/foam.py",
        'nu_tl=(q("nu21") + q("nu31")) / 2',
        'nu_tl=(q("nu12") + q("nu13")) / 2',
        '`fit="paper"`: ν_tl from ν12, ν13 instead of ν21, ν31',
        targets=("tests/test_tables.py::test_paper_fit_of_an_exactly_ti_table_returns_its_constants",
                 "tests/test_tables.py::test_paper_fit_of_the_shipped_table_averages_its_engineering_columns")),
    Mutation(
        "table-mean-first-seed", "homogenization/tables.py",
        "out[name] = float(values.mean())",
        "out[name] = float(values[0])",
        "the aggregated table takes the first seed instead of the mean over seeds",
        targets=("tests/test_tables.py::test_aggregate_is_the_mean_and_sample_std_over_seeds",)),
    Mutation(
        "fft-stop-10-tol", "homogenization/fft.py",
        '        if history[-1] <= tol:\n            return mean, history, True, ""\n        beta = rr_new / rr',
        '        if history[-1] <= 10 * tol:\n            return mean, history, True, ""\n        beta = rr_new / rr',
        "CG stops at 10 × tol",
        targets=("tests/test_fft.py::test_equilibrium_residual_of_the_returned_fields_is_below_tol",)),
    Mutation(
        "fft-macro-strain-shear", "homogenization/fft.py",
        "E = np.ldexp(E_voigt, k_strain) / _MANDEL",
        "E = np.ldexp(E_voigt, k_strain) * _MANDEL",
        "FFT macro strain: engineering shear multiplied instead of divided by √2 (a dropped ½ in ε_ij)",
        targets=("tests/test_fft.py",)),
    Mutation(
        "fft-rotated-wave-vector", "homogenization/fft.py",
        "comps = [inv_h[0] * s[0] * c[1] * c[2], ",
        "comps = [inv_h[0] * s[0] * c[1], ",
        "Willot's rotated wave vector missing a cosine factor in k_1",
        targets=("tests/test_fft.py",)),
    Mutation(
        "pcg-ghost-wrap", "homogenization/_nodal.py",
        "array[..., 0:1, :, :] = array[..., last, :, :]",
        "array[..., 0:1, :, :] = array[..., first, :, :]",
        "pcg's nodal operator: the leading ghost plane wraps to the first plane instead of the last (x not periodic)",
        targets=("tests/test_fft.py",)),
    Mutation(
        "pcg-strain-h-index", "homogenization/_nodal.py",
        "g[:, 1] = (roll(a3, -1, 2) - a3) / ws.h[1]",
        "g[:, 1] = (roll(a3, -1, 2) - a3) / ws.h[2]",
        "pcg's voxel strain: ∂u/∂y divided by the voxel size along z instead of y",
        targets=("tests/test_fft.py",)),
    Mutation(
        "voxel-centres", "meshes/foam.py",
        "c = [(np.arange(n) + 0.5) / n * length for n, length in zip(shape, box)]",
        "c = [np.arange(n) / (n - 1) * length for n, length in zip(shape, box)]",
        "voxel centres at i/(N−1) instead of (i+½)/N",
        targets=("tests/test_foam.py::test_voxelize_is_the_distance_test_at_the_documented_voxel_centres",
                 "tests/test_foam.py::test_seeds_shifted_by_whole_voxels_roll_the_image")),
    Mutation(
        "foam-radius-quantile", "meshes/foam.py",
        "(the exact root of φ̂(r) = density)\n        rank = max(math.ceil(density * len(sample)) - 1, 0)",
        "(the exact root of φ̂(r) = density)\n        rank = max(math.ceil(0.95 * density * len(sample)) - 1, 0)",
        "strut radius found for 95 % of the requested density",
        targets=("tests/test_foam.py",)),
    Mutation(
        "voxel-mesh-axes", "meshes/voxel.py",
        "solid = image[index[:, 0], index[:, 1], index[:, 2]].astype(bool)",
        "solid = image[index[:, 2], index[:, 1], index[:, 0]].astype(bool)",
        "voxel mesh reads the image with x and z swapped",
        targets=("tests/test_fem_fft_crosscheck.py::test_voxel_mesh_cells_are_tagged_by_the_documented_voxel_boxes",)),
    # ---- tensors, materials ----------------------------------------------------------------------------------
    Mutation(
        "ti-compliance-s66", "homogenization/tensors.py",
        "S[5, 5] = 2.0 * (1.0 + nu_t) / E_t",
        "S[5, 5] = (1.0 + nu_t) / E_t",
        "TI compliance S66 = 1/(2 G12): a wrong Voigt shear factor",
        targets=("tests/test_tensors.py",)),
    Mutation(
        "spencer-beta", "fenicsfoam/material/moduli.py",
        '"beta": C[..., 0, 0] + C[..., 2, 2] - 2.0 * C[..., 0, 2] - 4.0 * C[..., 3, 3]}',
        '"beta": C[..., 0, 0] + C[..., 2, 2] - 2.0 * C[..., 0, 2] - 2.0 * C[..., 3, 3]}',
        "Spencer modulus β with 2 C44 instead of 4 C44",
        targets=("tests/test_materials.py",)),
    # ---- calibration, uncertainty ----------------------------------------------------------------------------
    Mutation(
        "calibrate-affine-intercept", "fenicsfoam/calibrate.py",
        "a = p0 - b / E0",
        "a = p0 - b / E1",
        "calibration's affine model p = a + b/E with its intercept taken at the wrong modulus",
        targets=("tests/test_calibrate.py::test_recovers_a_known_E_solid_on_the_beam",)),
    Mutation(
        "uncertainty-population-std", "fenicsfoam/uncertainty.py",
        "std = rows.std(axis=0, ddof=1) if len(rows) > 1",
        "std = rows.std(axis=0, ddof=0) if len(rows) > 1",
        "probes' σ over the seeds as the population standard deviation (ddof 0) instead of the sample one",
        targets=("tests/test_uncertainty.py::test_std_equals_the_closed_form_and_grows_with_the_scatter",)),
    # ---- constitutive models, solver, stability --------------------------------------------------------------
    Mutation(
        "spencer-energy-sign", "fenicsfoam/constitutive.py",
        '+ m["alpha"] * tr_Ae * ufl.tr(e)',
        '- m["alpha"] * tr_Ae * ufl.tr(e)',
        "sign of the α term of the TI Spencer energy",
        targets=("tests/test_constitutive.py",)),
    Mutation(
        "green-lagrange-half", "fenicsfoam/constitutive.py",
        "return 0.5 * (F.T * F - ufl.Identity(F.ufl_shape[0]))",
        "return (F.T * F - ufl.Identity(F.ufl_shape[0]))",
        "Green–Lagrange strain without its ½",
        targets=("tests/test_constitutive.py", "tests/test_solver.py")),
    Mutation(
        "corotational-r-transposed", "fenicsfoam/constitutive.py",
        "return ufl.sym(R.T * deformation_gradient(u)) - ufl.Identity(len(u))",
        "return ufl.sym(R * deformation_gradient(u)) - ufl.Identity(len(u))",
        "corotational strain sym(R F) instead of sym(Rᵀ F)",
        targets=("tests/test_constitutive.py", "tests/test_solver.py")),
    Mutation(
        "svk-piola-order", "fenicsfoam/constitutive.py",
        "return deformation_gradient(u) * stress(self.strain(u), material, orientation)",
        "return stress(self.strain(u), material, orientation) * deformation_gradient(u)",
        "SVK first Piola–Kirchhoff stress S F instead of F S",
        targets=("tests/test_constitutive.py", "tests/test_solver.py")),
    Mutation(
        "corotational-piola-order", "fenicsfoam/constitutive.py",
        "return rotation.R * stress(strain, material, orientation)",
        "return stress(strain, material, orientation) * rotation.R",
        "corotational stress σ R instead of R σ",
        targets=("tests/test_constitutive.py", "tests/test_solver.py")),
    Mutation(
        "polar-rotation-transposed", "fenicsfoam/constitutive.py",
        "            break\n    return R\n",
        "            break\n    return R.transpose(0, 2, 1)\n",
        "polar decomposition returns Rᵀ",
        targets=("tests/test_constitutive.py", "tests/test_solver.py")),
    Mutation(
        "rotation-tangent-factor", "fenicsfoam/constitutive.py",
        "omega = 2.0 * ufl.inv(ufl.tr(U) * ufl.Identity(3) - U)",
        "omega = ufl.inv(ufl.tr(U) * ufl.Identity(3) - U)",
        "corotational tangent: the spin ω without its factor 2 (inconsistent Jacobian)",
        targets=("tests/test_solver.py",)),
    Mutation(
        "gravity-factor", "fenicsfoam/solver.py",
        "- material.rho * ufl.inner(self._body_acceleration, v) * ufl.dx)",
        "- 0.5 * material.rho * ufl.inner(self._body_acceleration, v) * ufl.dx)",
        "body force ½ ρ g instead of ρ g",
        targets=("tests/test_solver.py",)),
    Mutation(
        "rodrigues-transposed", "fenicsfoam/bcs.py",
        "return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)",
        "return np.eye(3) - np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)",
        "prescribed rotations turn the wrong way (Rᵀ)",
        targets=("tests/test_solver.py",)),
    Mutation(
        "acoustic-tensor-indices", "fenicsfoam/stability.py",
        "A = A.transpose(0, 1, 3, 2, 4).reshape(p, 9, 9)",
        "A = A.transpose(0, 1, 2, 3, 4).reshape(p, 9, 9)",
        "acoustic tensor A_ijkl n_k n_l instead of A_ijkl n_j n_l",
        targets=("tests/test_stability.py",)),
    Mutation(
        "validity-half", "fenicsfoam/validity.py",
        "quadratic = 0.5 * grad.T * grad",
        "quadratic = grad.T * grad",
        "small-strain validity measure without the ½ of ½ ∇uᵀ∇u",
        targets=("tests/test_extremes.py",)),
    # ---- orientation, probes, scenes, meshes -------------------------------------------------------------------
    Mutation(
        "spiral-handedness", "fenicsfoam/orientation.py",
        "d = math.sin(p) * e_r + h * math.cos(p) * e_theta",
        "d = math.sin(p) * e_r - h * math.cos(p) * e_theta",
        "spiral fibres of the opposite handedness",
        targets=("tests/test_scene.py",)),
    Mutation(
        "probe-twist-sign", "fenicsfoam/probes.py",
        "s, c = R[1, 0] - R[0, 1], R[0, 0] + R[1, 1]",
        "s, c = R[0, 1] - R[1, 0], R[0, 0] + R[1, 1]",
        "centre rotation probe with the wrong sign",
        targets=("tests/test_probes.py",)),
    Mutation(
        "probe-missing-allreduce", "fenicsfoam/probes.py",
        "return self._comm.allreduce(dolfinx.fem.assemble_scalar(form), op=MPI.SUM)",
        "return dolfinx.fem.assemble_scalar(form)",
        "probe integrals not summed over ranks",
        mpi_targets=("tests/test_probes.py",)),
    Mutation(
        "fem-missing-allreduce", "homogenization/fem.py",
        "comm.Allreduce(local, total, op=MPI.SUM)\n        sigma = total.reshape(3, 3) / box_volume",
        "total[:] = local\n        sigma = total.reshape(3, 3) / box_volume",
        "FEM RVE mean stress not summed over ranks",
        mpi_targets=("tests/test_fem_rve.py",)),
    Mutation(
        "fem-periodic-offset", "homogenization/fem.py",
        "out[:3] = np.where(upper, lo, x[:3])",
        "out[:3] = np.where(upper, 2 * lo - hi, x[:3])",
        "periodic constraint maps upper-face dofs one period too far",
        targets=("tests/test_fem_rve.py",)),
    Mutation(
        "fem-unit-shear-strain", "homogenization/fem.py",
        "    E[i, j] += 0.5\n    E[j, i] += 0.5\n",
        "    E[i, j] += 1.0\n    E[j, i] += 1.0\n",
        "FEM RVE unit shear strains ε_ij = 1 instead of ½ (γ_ij = 2): a wrong Voigt shear factor",
        targets=("tests/test_fem_rve.py",)),
    Mutation(
        "scene-servo-degrees", "fenicsfoam/scene/build.py",
        'angles = {name: math.radians(servos[name]["setup_deg"] + a) for name, a in turned.items()}',
        'angles = {name: math.radians(servos[name]["setup_deg"] + a) / 2 for name, a in turned.items()}',
        "scene servo angles halved in the conversion to radians",
        targets=("tests/test_scene.py",)),
    Mutation(
        "rve-periodic-rank", "meshes/rve.py",
        "    wrapped = ijk % n\n",
        "    wrapped = ijk\n",
        "RVE nodes on opposite faces not identified as periodic images (ranks without the modulo)",
        targets=("tests/test_foam_rve.py",)),
    Mutation(
        "beam-box-offset", "meshes/beam.py",
        "box = occ.addBox(0.0, -width / 2, -height / 2, length, width, height)",
        "box = occ.addBox(0.0, -width / 2, -height, length, width, height)",
        "beam box not centred in z (its top face at z = 0)",
        targets=("tests/test_beam_mesh.py::test_bounding_box_and_sizes",)),
    Mutation(
        "tripod-servo-axis", "meshes/tripod.py",
        "axis=np.array([-e[1], e[0], 0.0]))",
        "axis=np.array([e[1], -e[0], 0.0]))",
        "servo axes reversed: positive horn angles lower the arm ends",
        targets=("tests/test_tripod_mesh.py",)),
)
