# Two commands do all the set-up on a fresh machine:
#   make demo   - create .venv, install, run the main job
#   make test   - the same set-up, then the whole test suite
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

# ROS 2 discovery never leaves this machine (Fast DDS multicasts on the network otherwise).
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: setup syslibs demo test bench models clean

setup: syslibs $(STAMP)

# open3d's wheel links against libusb-1.0; install it when missing (root) or say what to do.
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

# Re-installs only when setup.py changes (or the venv is new): fast when nothing changed.
$(STAMP): setup.py
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check --upgrade "pip>=24"
	$(PY) -m pip install -q --disable-pip-version-check -e ".[ros,test]"
	@touch $(STAMP)

demo: setup
	$(VENV)/bin/affordance-registration demo

test: setup
	$(PY) -m pytest -q test

bench: setup
	$(VENV)/bin/affordance-registration bench

# Regenerate the taskboard meshes and YAML files in models/ (they are committed).
models: setup
	$(VENV)/bin/affordance-registration generate-models --out models

clean:
	rm -rf $(VENV) demo_output .pytest_cache
