# Drovisio: set-up in two commands.
#   make demo    create .venv (once), install, serve the web tool on the sample session
#   make test    create .venv (once), install, run the test suite
# Needs only python3 (>= 3.11, with venv) and make.

PYTHON ?= python3
VENV   ?= .venv
HOST   ?= 127.0.0.1
PORT   ?= 8080
PYTEST_ARGS ?=

VPY   := $(VENV)/bin/python
STAMP := $(VENV)/.drovisio-installed

.DEFAULT_GOAL := help
.PHONY: help install demo test lint samples docs clean distclean

help:
	@echo "make demo      install (once) and serve the web tool on the sample session"
	@echo "               (HOST=0.0.0.0 to reach it from a phone/tablet, PORT=8080)"
	@echo "make test      install (once) and run the tests (PYTEST_ARGS='-k pages' to filter)"
	@echo "make lint      ruff and mypy on the package (CI runs it after the tests)"
	@echo "make samples   regenerate sample_sessions/ with drovisio's renderer"
	@echo "make docs      retake the field guide's screenshots (docs/images/, browser tests)"
	@echo "make clean     remove caches and build leftovers (keeps .venv)"
	@echo "make distclean clean, and remove .venv too"

$(VPY):
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "Drovisio needs Python >= 3.11, found " + sys.version.split()[0])'
	@$(PYTHON) -m venv $(VENV) || { rm -rf $(VENV); \
	  echo "Could not create $(VENV). On Debian/Ubuntu: apt-get install python3-venv" >&2; exit 1; }

# Reinstalled only when pyproject.toml changes (or the venv is new).
$(STAMP): pyproject.toml | $(VPY)
	@echo "[1/2] Installing Drovisio and its libraries into $(VENV) (first time: a few minutes)..."
	$(VPY) -m pip install --disable-pip-version-check --progress-bar on -e '.[test]'
	@echo "[2/2] Compiling the detectors' kernels (once per machine: about 3 min on a small laptop)..."
	$(VPY) -m drovisio.detect.warmup
	@echo "Installed."
	@touch $@

install: $(STAMP)

demo: $(STAMP)
	@echo "Starting the Drovisio web tool on the built-in sample session (Ctrl+C to stop)."
	$(VENV)/bin/drovisio serve --host $(HOST) --port $(PORT)

# pytest exit 5 = no tests collected: an error here, never a silent success.
test: $(STAMP)
	@$(VPY) -m pytest $(PYTEST_ARGS); rc=$$?; \
	if [ $$rc -eq 5 ]; then \
	  echo "ERROR: pytest collected no tests (exit 5). Check tests/ and PYTEST_ARGS." >&2; fi; \
	exit $$rc

lint: $(STAMP)
	$(VENV)/bin/ruff check drovisio webtool tests
	$(VENV)/bin/mypy

samples: $(STAMP)
	$(VENV)/bin/drovisio synth samples --out sample_sessions

# The field guide's screenshots: only this target writes docs/images/ (make test never does).
docs: $(STAMP)
	DROVISIO_DOCS_IMAGES=1 $(VPY) -m pytest tests/browser/test_field_guide.py -q

clean:
	rm -rf build dist .pytest_cache test-results *.egg-info
	find . -path ./$(VENV) -prune -o -name __pycache__ -type d -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV)
