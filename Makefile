# Two commands for a fresh machine (Debian/Ubuntu, Python 3.11):
#   make run    one simulated episode on the default scenario (output in out/<timestamp>-<random>/)
#   make test   the test suite
#   make docs   the documentation site (mkdocs build --strict into site/)
# Both install what they need on first use: system libraries through apt
# (sudo if not root) and a virtualenv in .venv with the package in editable mode.
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed
SYSTEM_LIBS := libusb-1.0-0 libegl1 libegl-mesa0 libgl1-mesa-dri graphviz
ARGS ?=
PYTEST_ARGS ?=

.PHONY: run test docs setup system-deps clean

run: $(STAMP)
	$(VENV)/bin/lmap-drake run $(ARGS)

# The tests marked realtime (a digital twin driven in real time, kill
# timings) run alone after the rest: on two cores shared with the other
# tests' worker they measured the starved machine, not the code.
# (Exit code 5: the selection holds none of them.)
test: $(STAMP)
	$(VENV)/bin/python -m pytest -q -n auto --dist loadfile -m "not realtime" $(PYTEST_ARGS) \
	  || test $$? -eq 5
	$(VENV)/bin/python -m pytest -q -m realtime $(PYTEST_ARGS) || test $$? -eq 5

docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/python -m mkdocs build --strict

setup: $(STAMP)

$(STAMP): pyproject.toml
	@$(MAKE) --no-print-directory system-deps
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --upgrade pip
	$(VENV)/bin/python -m pip install --quiet -e '.[test]'
	$(VENV)/bin/python -m lmap_drake.deformation.warmup
	touch $(STAMP)

system-deps:
	@missing=""; for p in $(SYSTEM_LIBS); do \
	  dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing system packages:$$missing"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update -q && $$SUDO apt-get install -y -q --no-install-recommends $$missing; \
	fi

clean:
	rm -rf $(VENV) *.egg-info out site
