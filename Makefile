# parefg: setup, demo and tests on Debian 12.  `make demo` and `make test` are
# the two commands of the README; both set up what is missing first.

VENV      := .venv
PY        := $(VENV)/bin/python
STAMP     := $(VENV)/.parefg-installed
# Redone when a kernel source changes: the numba kernels compile into their cache, and
# ahead of time into the environment (parefg.discretization.aot), once here.
KERNELS   := $(VENV)/.parefg-kernels
# Redone when the package or a built-in scene changes (their entries' keys hash the source).
PREBUILT  := $(VENV)/.parefg-prebuilt
DEB_PKGS  := python3-petsc4py python3-mpi4py python3-h5py-mpi python3-gmsh \
             python3-numpy python3-scipy python3-sympy python3-matplotlib \
             python3-numba python3-venv python3-pip openmpi-bin gcc python3-dev
# Open MPI refuses root without these; CI and containers run as root.
export OMPI_ALLOW_RUN_AS_ROOT := 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM := 1
export OMPI_MCA_rmaps_base_oversubscribe := 1
# Never let pip replace Debian's numpy 1.24 (petsc4py is built against it).
export PIP_CONSTRAINT := $(CURDIR)/scripts/setup/constraints.txt
MPIRUN    := mpirun --timeout 1500 -n 2
# The serial pass runs on up to 4 pytest-xdist workers (one per core), one BLAS thread each.
WORKERS   := $(shell n=$$(nproc); echo $$(( n < 4 ? n : 4 )))

.PHONY: setup demo test lint clean bench-getfem

setup: $(STAMP) $(KERNELS) $(PREBUILT)
	@# Byte-compile the package: with PYTHONDONTWRITEBYTECODE set (as on some CI machines)
	@# Python would compile its 80 modules from source in every process (~0.09 s a run).
	@$(PY) -m compileall -q parefg

# ~50 s on a new machine (~15 s of it the ahead-of-time module), ~3 s when the cache is
# current; a first user run then does not spend ~20 s compiling, nor any run ~0.35 s
# importing numba.
$(KERNELS): $(STAMP) $(wildcard parefg/discretization/*.py) scripts/setup/warm_kernels.py
	$(PY) scripts/setup/warm_kernels.py
	@touch $@

# ~1 s: the built-in scenes' derived data and meshes, so that their runs import neither
# sympy nor gmsh (parefg.user_cache.prebuilt_dir).
$(PREBUILT): $(STAMP) $(shell find parefg -name '*.py' -o -name '*.toml') \
		scripts/setup/prebuild_scenes.py
	$(PY) scripts/setup/prebuild_scenes.py
	@touch $@

$(STAMP): pyproject.toml scripts/setup/setup.sh
	bash scripts/setup/setup.sh $(DEB_PKGS)
	@touch $@

demo: setup
	$(MPIRUN) $(VENV)/bin/parefg

lint: setup
	$(VENV)/bin/ruff check parefg tests scripts
	$(VENV)/bin/ruff format --check parefg tests scripts
	$(VENV)/bin/mypy parefg

test: lint
	OMP_NUM_THREADS=1 $(PY) -m pytest -n $(WORKERS) -p no:cacheprovider --durations=20 tests
	$(MPIRUN) $(PY) -m pytest -p no:cacheprovider -q tests

# The side-by-side benchmark against GetFEM (README, Performance; 5-13 min).  Its optional
# dependency, Debian's python3-getfem, is installed here only: setup and CI never need it.
bench-getfem: setup
	bash scripts/setup/setup.sh $(DEB_PKGS) python3-getfem
	$(PY) scripts/bench/getfem_side_by_side.py --repeats 3

clean:
	rm -rf $(VENV) *.egg-info
