# Two commands do all the set-up on a fresh machine:
#   make demo   - create .venv, install, run the main job
#   make test   - the same set-up, then the whole test suite
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
# make test runs the suite on this many pytest-xdist workers (whole files each, each in its own ROS
# domain); TEST_WORKERS=0 runs it in one process. Four on two cores: much of the suite's time is
# spent waiting for nodes, browsers and events, which the workers beyond two fill (on 2 idle
# cores: 3 workers 634 s of pytest, 4 workers 572 s).
TEST_WORKERS ?= 4
STAMP  := $(VENV)/.installed
INTERFACES_STAMP := $(VENV)/.interfaces
INTERFACES_SOURCES := affordance_registration/ros/standins/interfaces/build.py \
	$(wildcard affordance_registration/ros/standins/interfaces/*/msg/*.msg)

# ROS 2 discovery never leaves this machine (Fast DDS multicasts on the network otherwise).
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: setup syslibs browser demo test bench models clean

setup: syslibs $(STAMP) $(INTERFACES_STAMP)

# open3d's wheel links against libusb-1.0; install it when missing (root) or say what to do.
# g++ builds tf2_msgs and the other interfaces (below); without it setup goes on and the node has
# no TF output.
syslibs:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then \
	  if [ "$$(id -u)" = "0" ]; then \
	    echo "installing libusb-1.0-0 (needed by open3d) with apt"; \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0) >/dev/null || \
	      { echo "apt-get install libusb-1.0-0 failed"; exit 1; }; \
	  else \
	    echo "libusb-1.0-0 is missing; install it as root: sudo apt-get install libusb-1.0-0"; exit 1; \
	  fi; \
	fi
	@if ! command -v g++ >/dev/null 2>&1; then \
	  if [ "$$(id -u)" = "0" ]; then \
	    echo "installing g++ (builds tf2_msgs) with apt"; \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq g++) >/dev/null || \
	      echo "apt-get install g++ failed: the venv gets no tf2_msgs"; \
	  else \
	    echo "g++ is missing (sudo apt-get install g++): the venv gets no tf2_msgs"; \
	  fi; \
	fi

# The station's browser test drives Debian's chromium (headless, software WebGL) with Playwright;
# install it when missing (root) or say what to do. Only the tests need it, not `make demo`.
browser:
	@if ! [ -x /usr/bin/chromium ]; then \
	  if [ "$$(id -u)" = "0" ]; then \
	    echo "installing chromium (the station's browser test) with apt"; \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium) >/dev/null || \
	      { echo "apt-get install chromium failed"; exit 1; }; \
	  else \
	    echo "chromium is missing; install it as root: sudo apt-get install chromium"; exit 1; \
	  fi; \
	fi

# Re-installs only when setup.py changes (or the venv is new): fast when nothing changed.
$(STAMP): setup.py
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check --upgrade "pip>=24"
	$(PY) -m pip install -q --disable-pip-version-check -e ".[ros,test]"
	@touch $(STAMP)

# ROS 2 Jazzy's wheels have no tf2_msgs, moveit_msgs or vision_msgs: generate and compile the
# messages the package uses into the venv (under a minute; again only when the venv was
# reinstalled or the definitions changed). Where that fails, one line says why and setup goes on:
# the engine node then runs without TF output, collision objects and detections.
$(INTERFACES_STAMP): $(STAMP) $(INTERFACES_SOURCES)
	@$(PY) -m affordance_registration.ros.standins.interfaces.build --prefix $(VENV) && touch $@ || true

demo: setup
	$(VENV)/bin/affordance-registration demo

# The suite starts some 300 Python processes (nodes, CLI commands, pytest workers), each importing
# the package: compiled to bytecode once here (a second or so; __pycache__/ is ignored by git), so
# that none compiles it again where PYTHONDONTWRITEBYTECODE is set (Python then reads bytecode but
# never writes it: every process compiled the modules it imports, about 0.1 s each). The compiled
# kernels (numba, cached beside their module) likewise: compiled once here (11 s of CPU), where
# each worker and node started before the cache was written compiled them again.
# The real-scan tests fetch the or-pcd wheel (Stanford Armadillo range scans, 1.7 MB) with pip
# into ~/.cache/affordance_registration (AFFORDANCE_DATA_CACHE); fetched here first, so a failed
# download is said once, up front -- the tests then fail with the same reason, nothing is skipped.
test: setup browser
	@$(PY) -c "from affordance_registration.evaluation.realscans import fetch_or_pcd; fetch_or_pcd()" \
	  || echo "could not fetch or-pcd: the real-scan tests will fail"
	@$(PY) -m compileall -q -j 0 affordance_registration test >/dev/null || true
	@$(PY) -c "from affordance_registration.core.compiled import kernels; kernels()" || true
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile test

bench: setup
	$(VENV)/bin/affordance-registration bench

# Regenerate the taskboard meshes and YAML files in models/ (they are committed).
models: setup
	$(VENV)/bin/affordance-registration generate-models --out models

clean:
	rm -rf $(VENV) demo_output .pytest_cache
