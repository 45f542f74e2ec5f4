# Two entry points (README "Reproduce"). Both set up .venv idempotently first.
PY      := .venv/bin/python
STAMP   := .venv/.installed
export DVC_NO_ANALYTICS := 1
# Stage commands call `python`: make it the project venv.
export PATH := $(CURDIR)/.venv/bin:$(PATH)

.PHONY: setup repro test test-fast bench gpu-check clean-venv

$(STAMP): requirements.txt pyproject.toml
	test -x $(PY) || python3 -m venv .venv
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	$(PY) -m pip install --quiet --no-deps -e .
	touch $(STAMP)

setup: $(STAMP)

## Reproduce every result on the embedded simulated data (default scale).
repro: $(STAMP)
	.venv/bin/dvc repro

## Run the test suite (unit, integration and the tiny end-to-end dvc repro).
test: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile

test-fast: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile -m "not slow"

## Print the speed/memory figures of every benchmark script.
bench: $(STAMP)
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

## Every path past the CPU default on one GPU, in minutes (docs/gpu.md); exits non-zero on a failure.
## Extra arguments: make gpu-check ARGS="--device cpu --size 32"
gpu-check: $(STAMP)
	$(PY) benchmarks/gpu_check.py $(ARGS)

clean-venv:
	rm -rf .venv
