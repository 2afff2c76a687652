# plod: two commands on a fresh machine:  make demo   and   make test
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
EGL_PKGS := libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0

.PHONY: install demo test test-slow test-all bench fit-real egl clean

install: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	@$(MAKE) --no-print-directory egl
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e ".[test,judge,sweep]"
	touch $(STAMP)

# Headless rendering (pyrender with PYOPENGL_PLATFORM=egl) needs Mesa's EGL; install it when missing.
egl:
	@missing=""; for p in $(EGL_PKGS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages for headless rendering:$$missing"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO="sudo"; \
	  ( $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $$missing >/dev/null ) \
	    || echo "warning: could not install$$missing; rendering will be unavailable (tests that render are skipped)"; \
	fi

demo: install
	PYOPENGL_PLATFORM=egl $(BIN)/plod demo

# Two tiers: `make test` (everything but the tests marked slow, two worker processes: the suite is
# dominated by single-threaded XLA compilation) and `make test-slow` (the compile-heavy model checks).
# .ci/run runs both; `make test-all` is the same in one command.
PYTEST := PYOPENGL_PLATFORM=egl $(BIN)/python -m pytest -q -n 2

test: install
	$(PYTEST) -m "not slow"

test-slow: install
	$(PYTEST) -m slow

test-all: install
	$(PYTEST)

bench: install
	$(BIN)/python -m experiments.bench_pmetric
	$(BIN)/python -m experiments.bench_optim
	$(BIN)/python -m experiments.bench_fit

fit-real: install
	$(BIN)/python -m experiments.fit_real

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis build dist *.egg-info
