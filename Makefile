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

test: $(STAMP)
	$(PY) -m pytest -q

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
