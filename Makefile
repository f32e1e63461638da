# calnav: `make demo` and `make test` set everything up on a fresh machine (Python 3.11 + apt).
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
# The CPU build of torch that these machines carry locally; override to use another build.
TORCH_SPEC ?= torch==2.13.0
STAMP  := $(VENV)/.calnav-installed

.PHONY: setup demo test test-full bench study clean-cache

setup: $(STAMP)

$(STAMP): pyproject.toml
	@bash .ci/system-deps.sh
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip show -q torch >/dev/null 2>&1 || $(PY) -m pip install -q "$(TORCH_SPEC)"
	$(PY) -m pip install -q -e ".[test,ray]"
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/calnav demo

test: $(STAMP)
	$(PY) -m pytest -q -ra

test-full: $(STAMP)
	CALNAV_FULL_TESTS=1 $(PY) -m pytest -q -ra

bench: $(STAMP)
	$(VENV)/bin/calnav bench --output bench.json

# The README's ObjectNav comparison: tune per segmenter x map, evaluate on a disjoint range
# (several hours on 2 cores; resumable, rerun to continue).
study: $(STAMP)
	CALNAV=$(VENV)/bin/calnav eval/objectnav/study.sh

clean-cache:
	rm -rf $${CALNAV_CACHE:-$$HOME/.cache/calnav}
