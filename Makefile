# Two commands for a fresh Debian machine: `make demo` and `make test` (see README.md).
# Both set up what they need first: system libraries, then .venv with amslam installed in it.

PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.amslam-installed
# Shared libraries the Python wheels load at import time, and the Debian packages providing them.
SYSTEM_LIBS := libusb-1.0.so.0:libusb-1.0-0 libgomp.so.1:libgomp1
# Programs optional features use, and their Debian packages: Graphviz draws `amslam tree --format svg|png`,
# Chromium and its driver run the viewer's browser tests and `amslam view --screenshot`. Set-up installs
# them where it can (root or password-less sudo) and otherwise goes on with a warning.
OPTIONAL_PROGRAMS := dot:graphviz chromium:chromium chromedriver:chromium-driver

.PHONY: setup system-deps demo test lint docs clean

setup: $(STAMP)

system-deps:
	@missing=""; \
	for pair in $(SYSTEM_LIBS); do \
	  lib=$${pair%%:*}; pkg=$${pair##*:}; \
	  ldconfig -p 2>/dev/null | grep -q "$$lib" || missing="$$missing $$pkg"; \
	done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ]; then SUDO=""; \
	  elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then SUDO="sudo"; \
	  else echo "amslam needs these Debian packages:$$missing"; \
	       echo "install them with:  sudo apt-get install -y$$missing   then run make again"; exit 1; fi; \
	  echo "installing system packages:$$missing"; \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq$$missing >/dev/null \
	    || { echo "could not install:$$missing (run: sudo apt-get install -y$$missing)"; exit 1; }; \
	fi
	@missing=""; \
	for pair in $(OPTIONAL_PROGRAMS); do \
	  prog=$${pair%%:*}; pkg=$${pair##*:}; \
	  command -v "$$prog" >/dev/null 2>&1 || missing="$$missing $$pkg"; \
	done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ]; then SUDO=""; \
	  elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then SUDO="sudo"; \
	  else SUDO="-"; fi; \
	  failed=""; \
	  if [ "$$SUDO" = "-" ]; then failed="$$missing"; \
	  else \
	    echo "installing optional system packages:$$missing"; \
	    $$SUDO apt-get update -qq >/dev/null 2>&1; \
	    for pkg in $$missing; do \
	      DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $$pkg >/dev/null 2>&1 || failed="$$failed $$pkg"; \
	    done; \
	  fi; \
	  if [ -n "$$failed" ]; then \
	    echo "warning: optional Debian packages not installed:$$failed"; \
	    echo "         tree drawings (svg/png), browser tests and page screenshots are skipped without them;"; \
	    echo "         install them with:  sudo apt-get install -y$$failed"; \
	  fi; \
	fi

$(STAMP): pyproject.toml constraints.txt | system-deps
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' \
	  || { echo "amslam needs Python >= 3.11 (found $$($(PYTHON) --version))"; exit 1; }
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV) \
	  || { echo "could not create $(VENV): install python3-venv (sudo apt-get install -y python3-venv)"; exit 1; }
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c constraints.txt -e '.[dev]' \
	  || { echo "warning: the pinned versions of constraints.txt do not install here; installing the newest"; \
	       echo "         allowed instead: flights may give other numbers than docs/ records"; \
	       $(BIN)/python -m pip install -q -e '.[dev]'; }
	@touch $(STAMP)

demo: setup
	$(BIN)/amslam run demo

# Two parts at once (issue #20), on pytest-xdist workers that steal work from each other: the
# realtime tests (tests/conftest.py: they measure on the wall clock, and mostly wait on it) on two
# workers at normal priority, every other test on three at the lowest, filling the two cores
# meanwhile (a third worker takes the core a worker waiting for its subprocess leaves). The
# realtime part's log is printed after the other part's. --durations: the slowest tests of each.
# A realtime test that failed while the other part loaded the cores (or other users of a shared
# machine did) runs once more, alone, after it: the realtime part keeps its own pytest cache, so
# --last-failed picks exactly its failures; a test failing twice fails `make test`.
REALTIME_LOG := .pytest-realtime.log
REALTIME_CACHE := -o cache_dir=.pytest-realtime-cache
test: setup
	@$(BIN)/python -m pytest -q -n 2 --dist worksteal -m "realtime and not slow" --durations=5 \
	    $(REALTIME_CACHE) >$(REALTIME_LOG) 2>&1 & realtime=$$!; \
	trap 'kill $$realtime 2>/dev/null; exit 130' INT TERM; \
	nice -n 19 $(BIN)/python -m pytest -q -n 3 --dist worksteal -m "not slow and not realtime" --durations=15; \
	rest=$$?; \
	echo "== realtime tests, run meanwhile at normal priority ($(REALTIME_LOG)) =="; \
	wait $$realtime; timed=$$?; \
	cat $(REALTIME_LOG); \
	if [ $$timed = 1 ]; then \
	  echo "== realtime tests that failed above, run again alone now that the other part is done =="; \
	  $(BIN)/python -m pytest -q -m "realtime and not slow" --last-failed --last-failed-no-failures none \
	      $(REALTIME_CACHE); timed=$$?; \
	fi; \
	test $$rest = 0 && test $$timed = 0

lint: setup
	$(BIN)/ruff check . && $(BIN)/ruff format --check .

# API reference (Markdown) generated from the code: hookspecs, interfaces, data types, contract kits.
docs: setup
	$(BIN)/python docs/reference/generate.py docs/reference

clean:
	rm -rf $(VENV) runs build *.egg-info
