# The two commands of the README's quick start are `make demo` and `make test`.
# Installs take the tested versions pinned in constraints.txt; `make constraints` refreshes it.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test bench results results-check lint clean constraints

$(STAMP): pyproject.toml constraints.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c constraints.txt -e '.[dev]'
	touch $(STAMP)

# Refresh the pinned versions: install the newest that pyproject.toml allows into the venv,
# then pin what is installed (uvd itself excluded). Run `make test` before committing it.
constraints:
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade --upgrade-strategy eager -e '.[dev]'
	{ echo "# The versions uvd was tested with (pip freeze of the test venv, uvd itself excluded)."; \
	  echo "# make demo, make test and CI install with -c constraints.txt; refresh: make constraints."; \
	  $(PY) -m pip freeze --exclude uvd; } > constraints.txt
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/uvd demo --duration 60

# Both cores (pytest-xdist): the real-time tests form one xdist group (tests/conftest.py), so
# they run one after another on one worker while the other worker runs the rest; then the
# tests marked serial run alone, also when the first part failed (each prints its own count).
# Bytecode is written even if PYTHONDONTWRITEBYTECODE is set: otherwise every worker re-rewrites
# the asserts of every test module and each of the suite's hundreds of subprocesses recompiles
# uvd (collection 17 s → 4 s).
# `uvd compile` fills the kernel cache beside the workers' first tests (45 s when it is empty,
# under 1 s when not); the real-time group starts with its modules that call no kernel
# (tests/conftest.py), so its daemons find them compiled. Its summary line comes at the end;
# Ctrl-C stops it too (a background job of a shell ignores SIGINT).
TEST_WORKERS ?= 2
test: $(STAMP)
	export PYTHONDONTWRITEBYTECODE=; \
	$(PY) -m uvd compile --quiet > $(VENV)/compile.log 2>&1 & compiling=$$!; \
	trap 'kill $$compiling 2>/dev/null; exit 130' INT TERM; \
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadgroup -m "not serial"; parallel=$$?; \
	wait $$compiling; compiled=$$?; cat $(VENV)/compile.log; \
	$(PY) -m pytest -q -m serial; serial=$$?; \
	test $$parallel -eq 0 -a $$serial -eq 0 -a $$compiled -eq 0

bench: $(STAMP)
	$(PY) -m uvd.bench.all

results: $(STAMP)
	$(PY) -m uvd.experiments.results

# Every experiment of docs/RESULTS.md re-run from its printed command and compared with the
# committed JSON (<= 1e-9 relative); NAMES="pdc-vs-ambc fig51-hunt" picks some. Hours of CPU.
results-check: $(STAMP)
	$(PY) -m uvd.experiments.reproduce $(NAMES)

lint: $(STAMP)
	$(VENV)/bin/ruff check .

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
