# Quick start:  make demo   |   make test
# Both create .venv (Python 3.11), install torch==2.13.0 first when it is missing
# (a CPU wheel; a plain `torch` would pull a multi-GB CUDA build), then the project.

PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

# The default suite runs on every core (at most 4 workers, one test file per worker at a time, so a
# module's fixtures are made once); TEST_PARALLEL= runs it in one process.
TEST_PARALLEL ?= -n auto --maxprocesses 4 --dist loadfile

.PHONY: install demo demo-quick test test-slow bench docs docs-serve clean

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

$(STAMP): $(PY) pyproject.toml
	@$(PY) -c "import torch" 2>/dev/null || $(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e ".[all,test]"
	@touch $(STAMP)

install: $(STAMP)

# demo: simulated capture of the bundled bottle -> refine poses -> reconstruct -> assets -> truth.json
# -> Drake evaluation -> report (demo_out/); demo-quick: the small version (CI tests a smaller one still).
demo: $(STAMP)
	$(VENV)/bin/real2sim demo --out demo_out --overwrite

demo-quick: $(STAMP)
	$(VENV)/bin/real2sim demo --out demo_out --overwrite --quick

# The report's browser test needs Debian's chromium: installed here where apt-get runs as root,
# otherwise that test is skipped and says why.
test: $(STAMP)
	@command -v chromium >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
		apt-get install -y -q chromium >/dev/null 2>&1; } || echo "note: no chromium; the browser test will be skipped"
	$(PY) -m pytest -q -m "not slow" $(TEST_PARALLEL) tests

test-slow: $(STAMP)
	$(PY) -m pytest -q -m slow tests

bench: $(STAMP)
	$(PY) benchmarks/run_all.py

# The docs site (mkdocs.yml) into site/, strict: a broken link or a docstring warning fails it.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --site-dir site

docs-serve: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs serve

clean:
	rm -rf $(VENV) demo_out .pytest_cache site
