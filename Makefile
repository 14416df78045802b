# fenicsfoam — the only set-up a user needs on a fresh Debian 12 machine.
#   make demo      install what is missing, then run the main job on the shipped defaults (outputs in out/)
#   make test      install, then the test suite serially and its `mpi` subset under mpirun -n 2
#   make test-all  the same including `slow` cases
#   make bench     benchmarks (tables printed, CSV written under out/bench/)
#   make mutate    deliberate bugs applied to copies of the repository: are they caught? (MUTATE_ARGS="--full")
SHELL := /bin/bash
.SHELLFLAGS := -euo pipefail -c

# Debian packages: the FEniCSx 0.5 stack, gmsh, FFTW, MPI, a threaded BLAS (the default reference BLAS
# makes MUMPS ~5x slower), and the Mesa EGL/GL libraries that PyPI's vtk needs to render offscreen.
DEB_PACKAGES := python3-dolfinx-real python3-dolfinx-mpc python3-gmsh python3-meshio python3-pyfftw \
	python3-mpi4py python3-mpi4py-fft python3-scipy python3-matplotlib python3-tqdm python3-pytest python3-skimage python3-venv \
	openmpi-bin libopenblas0-pthread libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libxrender1

VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.stamp-install
NPROC ?= 2
# openmpi refuses root unless told; the single-copy mechanism (CMA) is unavailable in most containers.
export OMPI_ALLOW_RUN_AS_ROOT := 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM := 1
export OMPI_MCA_btl_vader_single_copy_mechanism := none
export OMPI_MCA_rmaps_base_oversubscribe := 1
export OPENBLAS_NUM_THREADS := 1
export VTK_DEFAULT_OPENGL_WINDOW := vtkEGLRenderWindow
MPIRUN := mpirun -n $(NPROC)
PYTEST_MPI := $(MPIRUN) $(PY) -m mpi4py -m pytest -p no:cacheprovider -q

.PHONY: install demo test test-all bench mutate lint clean

install: $(STAMP)

$(STAMP): pyproject.toml
	@missing=""; for p in $(DEB_PACKAGES); do \
	  dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q "ok installed" || missing="$$missing $$p"; \
	done; \
	if [ -n "$$missing" ]; then \
	  SUDO=""; [ "$$(id -u)" -eq 0 ] || SUDO=sudo; \
	  echo "installing Debian packages:$$missing"; \
	  export DEBIAN_FRONTEND=noninteractive; \
	  $$SUDO apt-get install -y --no-install-recommends $$missing \
	    || { $$SUDO apt-get update && $$SUDO apt-get install -y --no-install-recommends $$missing; }; \
	fi
	@[ -x $(PY) ] || /usr/bin/python3 -m venv --system-site-packages $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check --no-build-isolation -e '.[test,demo]'
	@touch $@

demo: install
	$(PY) demos/pipeline.py --out out

test: install
	$(PY) -m pytest
	$(PYTEST_MPI) -m "mpi and not slow"

test-all: install
	$(PY) -m pytest -m "slow or not slow"
	$(PYTEST_MPI) -m "mpi"

bench: install
	@for b in bench/*.py; do echo "== $$b"; $(PY) $$b --out out/bench; done

mutate: install
	$(PY) tests/mutation/mutate.py $(MUTATE_ARGS)

lint: install
	$(PY) -m ruff check .

clean:
	rm -rf out .pytest_cache .ruff_cache *.egg-info
