# calnav: `make demo` and `make test` set everything up on a fresh machine (Python 3.11 + apt).
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
# The CPU build of torch that these machines carry locally; override to use another build.
TORCH_SPEC ?= torch==2.13.0
STAMP  := $(VENV)/.calnav-installed
# habitat-lab pins numpy==1.26.4 (the main venv has numpy 2), so its interop runs in its own venv
HABITAT_VENV  ?= .venv-habitat
HPY           := $(HABITAT_VENV)/bin/python
HABITAT_STAMP := $(HABITAT_VENV)/.calnav-installed

.PHONY: setup habitat-setup demo test test-full docs bench study clean-cache

setup: $(STAMP)

habitat-setup: $(HABITAT_STAMP)

$(STAMP): pyproject.toml
	@bash .ci/system-deps.sh
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip show -q torch >/dev/null 2>&1 || $(PY) -m pip install -q "$(TORCH_SPEC)"
	$(PY) -m pip install -q -e ".[test,ray,hf,onnx,viz,ros]"
	@touch $(STAMP)

# habitat-lab + calnav's [habitat] extra (numpy 1.26.4, OpenCV < 5); habitat-sim is not needed
$(HABITAT_STAMP): pyproject.toml
	@bash .ci/system-deps.sh
	@test -x $(HPY) || $(PYTHON) -m venv $(HABITAT_VENV)
	$(HPY) -m pip install -q --upgrade pip
	$(HPY) -m pip show -q torch >/dev/null 2>&1 || $(HPY) -m pip install -q "$(TORCH_SPEC)"
	$(HPY) -m pip install -q -e ".[test,habitat]"
	@touch $(HABITAT_STAMP)

demo: $(STAMP)
	$(VENV)/bin/calnav demo

# the main suite, one pytest-xdist worker per core (TEST_WORKERS; 0 runs it in this process), a
# test file per worker so module fixtures are built once; its 10 slowest tests listed: it keeps
# well under 10 minutes on 2 cores. Then the habitat-lab interop tests (marker habitat) for real
# in .venv-habitat, then the docs site (mkdocs.yml; strict: a broken link or anchor fails) into
# the ignored site/
TEST_WORKERS ?= auto
test: $(STAMP) $(HABITAT_STAMP)
	$(PY) -m pytest -q -ra --durations=10 -n $(TEST_WORKERS) --dist loadfile
	CALNAV_REQUIRE_HABITAT=1 $(HPY) -m pytest -q -ra -m habitat
	$(VENV)/bin/mkdocs build --strict --quiet --site-dir site

test-full: $(STAMP) $(HABITAT_STAMP)
	CALNAV_FULL_TESTS=1 $(PY) -m pytest -q -ra -n $(TEST_WORKERS) --dist loadfile
	CALNAV_REQUIRE_HABITAT=1 CALNAV_FULL_TESTS=1 $(HPY) -m pytest -q -ra -m habitat

# the documentation site (docs/, mkdocs.yml) into site/; `$(VENV)/bin/mkdocs serve` to browse it
docs: $(STAMP)
	$(VENV)/bin/mkdocs build --strict --site-dir site

bench: $(STAMP)
	$(VENV)/bin/calnav bench --output bench.json

# The ObjectNav study (docs/objectnav_study.md): every row of configs/study.yaml tuned on val,
# evaluated on test; resumable (rerun to continue)
study: $(STAMP)
	$(VENV)/bin/calnav study configs/study.yaml --output docs/objectnav_study/study

clean-cache:
	rm -rf $${CALNAV_CACHE:-$$HOME/.cache/calnav}
