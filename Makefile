# Two entry points for a fresh machine: `make demo` and `make test`.
# Both create .venv and install hmpc (editable) with what it needs.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint typecheck bench clean sysdeps

# --no-compile: Python compiles a module when it is first imported; compiling all ~5,800 of
# the dependencies' modules at install took 16 of the install's 31 s, for ~660 ever imported.
$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet --no-compile -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/python -m hmpc.tools.demo --out out/demo

# Programs some tests drive (tmux for the terminal operator, Chromium for the HTML report):
# installed from Debian's packages when missing and this user may (root); otherwise those
# tests skip and say why.
sysdeps:
	@command -v tmux >/dev/null && command -v chromium >/dev/null || \
	  { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && \
	    (apt-get update -qq && apt-get install -y -qq tmux chromium >/dev/null) || \
	    echo "note: tmux/chromium not installed; their tests will skip"; }

# Static checks, also run by `make test` before the tests. mypy checks the package hmpc, whose
# directory is this one: it is linked as $(VENV)/mypy-root/hmpc (pyproject.toml, [tool.mypy]).
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	@mkdir -p $(VENV)/mypy-root && ln -sfn "$(CURDIR)" $(VENV)/mypy-root/hmpc
	$(BIN)/mypy

# The real-time tests run after the CPU-bound ones, six at a time: each keeps a 50-100 Hz
# loop and uses about a sixth of a core. The tests marked long go first, each to a worker of
# its own (tests/conftest.py). That run collects only the files that hold real-time tests, and
# both let Python cache its bytecode (which PYTHONDONTWRITEBYTECODE would stop): every worker
# and every subprocess would otherwise compile and assertion-rewrite the same modules again.
REALTIME_FILES = $(shell grep -rl --include='test_*.py' 'mark.realtime' tests)
test: $(STAMP) sysdeps lint typecheck
	PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest -q -n 2 -m 'not realtime' tests
	PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest -q -n 6 --dist load -m realtime $(REALTIME_FILES)

# bench_ingest exits 1 when it misses a target, bench_identify when its accuracy check fails;
# bench_mpc prints PASS/MISS against its target.
bench: $(STAMP)
	$(BIN)/python -m hmpc.tools.bench_ingest
	$(BIN)/python -m hmpc.tools.bench_identify
	$(BIN)/python -m hmpc.tools.bench_mpc

clean:
	rm -rf $(VENV) out
