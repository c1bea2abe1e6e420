# Two commands do all the set-up on a fresh Debian 12 machine:
#   make run    install what is missing, then run the main job on the default scene
#   make test   install what is missing, then run every test
# Both are idempotent: with everything in place the install step is a few stat calls.

SHELL := /bin/bash
VENV  ?= .venv
PY    := $(VENV)/bin/python
SCENE ?= jobs/quick.toml
NP    ?= 3
OUT   ?= out
# pytest workers for `make test` (pytest-xdist; one file per worker at a time).
PYTEST_WORKERS ?= 2

# Debian packages: PETSc 3.18 + petsc4py, mpi4py + OpenMPI 4.1, venv support, and OpenBLAS
# (PETSc links the reference BLAS otherwise: OpenBLAS halves the Cholesky factorisations).
APT_PACKAGES := python3-petsc4py python3-mpi4py python3-venv openmpi-bin libopenblas0-pthread
SUDO := $(if $(filter 0,$(shell id -u)),,sudo)

# mpirun as root, and more ranks than cores (tests and `make run` on small machines).
export OMPI_ALLOW_RUN_AS_ROOT := 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM := 1
export OMPI_MCA_rmaps_base_oversubscribe := 1

.PHONY: run test install system-packages clean

run: install
	@echo "main job: the multi-start design service on $(SCENE) ($(NP) MPI ranks: 1 master + $(NP)-1 workers)"
	@mkdir -p $(OUT)
	mpirun -n $(NP) $(VENV)/bin/mscap run $(SCENE) -o $(OUT)/$(basename $(notdir $(SCENE))).h5
	$(VENV)/bin/mscap inspect $(OUT)/$(basename $(notdir $(SCENE))).h5
	$(VENV)/bin/mscap plot $(OUT)/$(basename $(notdir $(SCENE))).h5 -o $(OUT)/$(basename $(notdir $(SCENE))).png

test: install
	$(PY) -m pytest -q --durations=15 -n $(PYTEST_WORKERS) --dist loadfile --no-loadscope-reorder

install: system-packages $(VENV)/.installed

# Checked on every call (a few dpkg-query calls): installs only what is missing.
system-packages:
	@missing=$$(for p in $(APT_PACKAGES); do dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null \
	    | grep -q '^install ok installed' || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	    echo "installing Debian packages: $$missing"; \
	    $(SUDO) apt-get update -qq && \
	    DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq --no-install-recommends $$missing; \
	fi

$(VENV)/.installed: pyproject.toml
	@test -x $(PY) || /usr/bin/python3 -m venv --system-site-packages $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -e '.[test]'
	@$(PY) -c "from mscap.fem.petsc import petsc; import mpi4py, gmsh, h5py, meshio; \
	    print('environment ok: PETSc', '.'.join(map(str, petsc().Sys.getVersion())))"
	@touch $@

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache
