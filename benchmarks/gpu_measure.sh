#!/usr/bin/env bash
# Every GPU figure docs/gpu.md section 7 leaves unmeasured, in one go (at most about 10 minutes on an
# H200-class GPU), each step under its own time limit, each log in OUT_DIR:
#
#   bash benchmarks/gpu_measure.sh OUT_DIR [PYTHON]
#
# PYTHON defaults to .venv/bin/python (on an offline GPU machine without the venv: python3 with
# the project on PYTHONPATH). Without a CUDA GPU it stops at once: one line, exit 1, nothing written.
# A step that fails or runs out of time is noted in OUT_DIR/summary.txt and the next one runs.
# Steps: the GPU check (make gpu-check), the step census with eager and captured samples/s at
# 128 px and 32 px and runs side by side, Table III's variants, seeds batched against a compiled
# step; then gpu_cost.py at the rate just measured (fill it in by hand from bench_census's
# side-by-side line if the parse below finds none).
set -u
out=${1:?usage: bash benchmarks/gpu_measure.sh OUT_DIR [PYTHON]}
py=${2:-.venv/bin/python}
# No CUDA GPU (or no torch): say so in one line at once and write nothing, instead of every step
# failing or running out its time limit (about 5 minutes) and the script exiting 0.
gpus=$(timeout 120 "$py" -c 'import torch; print(torch.cuda.device_count() if torch.cuda.is_available() else 0)' \
       2>/dev/null | tail -n 1)
case "$gpus" in
    ''|*[!0-9]*) echo "error: $py: could not import torch (expected the project's Python: .venv/bin/python," \
                      "or python3 with the project on PYTHONPATH)" >&2; exit 1 ;;
    0) echo "error: no CUDA GPU: torch under $py sees none (these are GPU measurements; docs/gpu.md)" >&2; exit 1 ;;
esac
mkdir -p "$out"
summary="$out/summary.txt"
: > "$summary"

step() {  # step NAME SECONDS COMMAND...
    local name=$1 limit=$2
    shift 2
    local t0=$SECONDS
    timeout "$limit" "$@" > "$out/$name.log" 2>&1
    local rc=$?
    echo "$name: exit $rc after $((SECONDS - t0)) s ($*)" | tee -a "$summary"
}

step gpu_check 200 "$py" benchmarks/gpu_check.py --device cuda
step census_128 120 "$py" benchmarks/bench_census.py --size 128 --only compact_15l compact_15l_mgn chen_bev --side-by-side 4 12
step census_32 90 "$py" benchmarks/bench_census.py --size 32 --only compact_15l --side-by-side 12
step table3 60 "$py" benchmarks/bench_gpu.py --device cuda --fold-bn --json "$out/table3.json"
step batched_seeds 90 "$py" benchmarks/bench_batched_seeds.py --size 128 --k 1 4 12 --steps 5

rate32=$(sed -n 's/.* side by side: .*, \([0-9.]*\) together.*/\1/p' "$out/census_32.log" | tail -1)
rate128=$(sed -n 's/.* side by side: .*, \([0-9.]*\) together.*/\1/p' "$out/census_128.log" | tail -1)
if [ -n "$rate32" ] && [ -n "$rate128" ]; then
    step gpu_cost 30 "$py" benchmarks/gpu_cost.py --rate "full=$rate32" "paper=$rate128"
else
    echo "gpu_cost: not run (no side-by-side rate found in the census logs)" | tee -a "$summary"
fi
