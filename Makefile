# cpdi-verify: orchestration only. Meson compiles; this file bootstraps, builds, tests
# and verifies. On a fresh Debian machine `make test` and `make verify` do all set-up.
SHELL := /bin/bash
.DEFAULT_GOAL := build

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
BUILD  := build
DEBUG_BUILD := build-debug
EXT_SRC := $(wildcard fortran/src/*.f90) fortran/cpdi.pyf meson.build fortran/meson.build meson.options \
           fortran/fflags.txt.in $(wildcard fortran/tests/*.f90 fortran/tests/*.pyf fortran/bench/*)
EXT_STAMP := harness/.ext-built
APT_PKGS := gfortran liblapack-dev libhdf5-dev pkg-config
CASE ?= cases/water_column.toml
THREADS ?=

.PHONY: bootstrap sysdeps venv build test verify verify-quick bench run regen-gold memcheck lint clean distclean help mutate mutate-harness

help:
	@echo "make test          bootstrap, build, run the test suite (Fortran + pytest)"
	@echo "make verify        bootstrap, build, run every check, write reports/<stamp>/"
	@echo "make verify-quick  the same at CI resolution"
	@echo "make bench         performance benchmark -> reports/bench/ (BASE=<sha>: compare with that commit)"
	@echo "make run CASE=cases/x.toml   run one case into runs/<case>/"
	@echo "make regen-gold    rewrite reference/gold/ from a full verify (never in CI)"
	@echo "make memcheck      Fortran-only driver under AddressSanitizer + debug flags (leaks, invalid access)"
	@echo "make mutate        mutation testing of the Fortran core -> reports/mutation/<date>-<sha>/ (SAMPLE=n, RESUME=dir, IDS='id ...', VERIFY=1)"
	@echo "make mutate-harness  mutation testing of the harness's metric and gate code (mutmut)"

# ---------------------------------------------------------------- bootstrap
sysdeps:
	@missing=""; \
	command -v gfortran >/dev/null 2>&1 || missing="$$missing gfortran"; \
	command -v pkg-config >/dev/null 2>&1 || missing="$$missing pkg-config"; \
	{ pkg-config --exists lapack 2>/dev/null || ls /usr/lib/*/liblapack.so >/dev/null 2>&1; } || missing="$$missing liblapack-dev"; \
	{ pkg-config --exists hdf5 2>/dev/null || dpkg -s libhdf5-dev >/dev/null 2>&1; } || missing="$$missing libhdf5-dev"; \
	$(PYTHON) -c 'import sys, venv, ensurepip; sys.exit(sys.version_info < (3, 11))' 2>/dev/null || missing="$$missing python3-venv"; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "bootstrap: installing Debian packages:$$missing"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null || exit 1; \
	  else \
	    echo "error: missing system packages:$$missing. Install them: sudo apt-get install$$missing (Python >= 3.11 is needed)"; \
	    exit 1; \
	  fi; \
	fi

$(VENV)/.installed: pyproject.toml
	@$(MAKE) --no-print-directory sysdeps
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@echo "bootstrap: installing pinned Python packages into $(VENV)"
	@$(PY) -m pip install -q --disable-pip-version-check --upgrade pip >/dev/null
	@$(PY) -m pip install -q --disable-pip-version-check \
	  $$($(PY) -c "import tomllib; p = tomllib.load(open('pyproject.toml','rb'))['project']; \
	     print(' '.join(p['dependencies'] + p['optional-dependencies']['test'] + p['optional-dependencies']['dev']))")
	@touch $@

venv: $(VENV)/.installed
bootstrap: venv

# ---------------------------------------------------------------- build
$(EXT_STAMP): $(VENV)/.installed $(EXT_SRC)
	@# the same meson project as `pip install .` (meson-python); a build/ configured from fortran/ (before the
	@# top-level meson.build) has no build/fortran/ and is set up again
	@test -d $(BUILD)/fortran || rm -rf $(BUILD)
	@test -f $(BUILD)/build.ninja || PATH=$(CURDIR)/$(VENV)/bin:$$PATH $(VENV)/bin/meson setup $(BUILD) . --python.install-env=auto -Dpython.bytecompile=-1 >/dev/null
	@echo "build: compiling the Fortran core and the f2py extensions (log: $(BUILD)/compile.log)"
	@PATH=$(CURDIR)/$(VENV)/bin:$$PATH $(VENV)/bin/meson compile -C $(BUILD) > $(BUILD)/compile.log 2>&1 || \
	  { cat $(BUILD)/compile.log; echo "error: the Fortran build failed; the compiler output is above"; exit 1; }
	@# the solver's extension into harness/; the tests' and the bench's (never installed) into tests/ and tools/
	@rm -f harness/_cpdi*.so tests/_cpdi_test*.so tools/_cpdi_bench*.so
	@cp $(BUILD)/fortran/_cpdi.*.so harness/ && cp $(BUILD)/fortran/_cpdi_test.*.so tests/ && \
	  cp $(BUILD)/fortran/_cpdi_bench.*.so tools/
	@touch $@

build: $(EXT_STAMP)

# ---------------------------------------------------------------- test / verify
test: build
	@PATH=$(CURDIR)/$(VENV)/bin:$$PATH $(VENV)/bin/meson test -C $(BUILD) --print-errorlogs -q
	@$(PY) -m pytest -q --durations=12

verify: build
	@$(PY) -m harness verify

verify-quick: build
	@$(PY) -m harness verify --quick

bench: build
	@$(PY) -m tools.bench $(if $(BASE),--base $(BASE))

run: build
	@$(PY) -m harness run $(CASE)

regen-gold: build
	@$(PY) -m harness verify --regen-gold

mutate: build
	@$(PY) -m pip install -q --disable-pip-version-check \
	  $$($(PY) -c "import tomllib; print(' '.join(tomllib.load(open('pyproject.toml','rb'))['project']['optional-dependencies']['mutation']))")
	@$(PY) -m tools.mutation $(if $(SAMPLE),--sample $(SAMPLE)) $(if $(RESUME),--resume $(RESUME)) $(if $(IDS),--ids $(IDS)) $(if $(VERIFY),--verify)

mutate-harness: build
	@$(PY) -m pip install -q --disable-pip-version-check \
	  $$($(PY) -c "import tomllib; print(' '.join(tomllib.load(open('pyproject.toml','rb'))['project']['optional-dependencies']['mutation']))")
	@$(PY) -c "from tools.mutation import python_target as p; raise SystemExit(p.main())"

memcheck: venv
	@test -d $(DEBUG_BUILD)/fortran || rm -rf $(DEBUG_BUILD)
	@test -f $(DEBUG_BUILD)/build.ninja || PATH=$(CURDIR)/$(VENV)/bin:$$PATH $(VENV)/bin/meson setup $(DEBUG_BUILD) . \
	  -Dfflags_profile=debug -Db_sanitize=address -Dbuildtype=debug >/dev/null
	@PATH=$(CURDIR)/$(VENV)/bin:$$PATH $(VENV)/bin/meson compile -C $(DEBUG_BUILD) cpdi_memcheck > $(DEBUG_BUILD)/compile.log 2>&1 || \
	  { cat $(DEBUG_BUILD)/compile.log; exit 1; }
	@ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 $(DEBUG_BUILD)/fortran/cpdi_memcheck
	@echo "memcheck: again on 2 threads (CPDI_MIN_PER_THREAD=1: the thread teams, their calibration and probes)"
	@CPDI_MIN_PER_THREAD=1 OMP_NUM_THREADS=2 ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 \
	  $(DEBUG_BUILD)/fortran/cpdi_memcheck

lint: venv
	@$(VENV)/bin/ruff check harness tests tools

clean:
	rm -rf $(BUILD) $(DEBUG_BUILD) harness/_cpdi*.so tests/_cpdi_test*.so tools/_cpdi_bench*.so $(EXT_STAMP) runs .bench-base

distclean: clean
	rm -rf $(VENV) reports/2* reports/latest reports/bench
