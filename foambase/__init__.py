"""The bottom floor of fenicsfoam: infrastructure without physics, imported by every other package.

* :mod:`foambase.errors` — the error family (:class:`~foambase.errors.FenicsfoamError`) and its exit codes;
* :mod:`foambase.files` — atomic file writes (temporary file in the same directory, then ``os.replace``);
* :mod:`foambase.mpi` — work done on rank 0 whose failure every rank learns;
* :mod:`foambase.threads` — default thread counts;
* :mod:`foambase.nullspace` — the rigid-body near-nullspace of a 3D vector space (dolfinx/PETSc);
* :mod:`foambase.logs` and :mod:`foambase.cli` — logging set-up and sub-command dispatch for command lines.

Nothing here imports ``meshes``, ``homogenization`` or ``fenicsfoam``; importing this package imports nothing
heavy (dolfinx and PETSc only through :mod:`foambase.nullspace`).
"""
