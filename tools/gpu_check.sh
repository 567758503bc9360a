#!/usr/bin/env bash
# One device call (a lent CUDA machine): install the carried wheels, run every example scene and the
# coupled validation scenes briefly on CUDA (does every family still run there from the same code?),
# then the GPU benchmark rows. Usage on the device machine, from the repository root:
#   bash tools/gpu_check.sh [SMOKE_SECONDS] [BENCH_SCENES...]
# Writes $OUT/smoke.txt, $OUT/bench.log and $OUT/PERFORMANCE_GPU.md (docs' copy updated in place).
set -uo pipefail
OUT=${OUT:-/tmp/gpu_out}; mkdir -p "$OUT"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
  && export PYTHONPATH=/tmp/site:$PWD || exit 3
export PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$OUT/gpu.txt"
smoke=${1:-150}; shift || true
scenes=("$@")
run_one() {  # one scene, briefly, on CUDA; prints "rc scene closing-line"
  local f=$1 d; d=/tmp/smoke/$(basename "$f" .yaml)
  timeout 120 python3 -m simcli run "$f" -o "$d" --overwrite --backend cuda --set sim.duration=0.06 -q --json \
    >"$d.log" 2>&1; local rc=$?
  echo "$rc $f $(python3 -c "import json,sys;r=json.load(open('$d/run.json'));print(r.get('status'),r.get('steps_done'),r.get('substeps'),r.get('backend'))" 2>/dev/null)"
}
export -f run_one; mkdir -p /tmp/smoke
ls configs/examples/*.yaml configs/validation/coupling_*{momentum,float}*.yaml configs/validation/emit_mass_*3d.yaml \
  | grep -v "\.case\.yaml$" | sort -u | timeout "$smoke" xargs -P 6 -I{} bash -c 'run_one {}' | sort | tee "$OUT/smoke.txt"
echo "smoke: $(grep -c '^0 ' "$OUT/smoke.txt") ok of $(wc -l <"$OUT/smoke.txt")"
for f in $(awk '$1!=0{print $2}' "$OUT/smoke.txt"); do echo "== $f"; tail -5 "/tmp/smoke/$(basename "$f" .yaml).log"; done | tee "$OUT/smoke_fail.txt" | head -60
if [ ${#scenes[@]} -gt 0 ]; then
  cp docs/PERFORMANCE_GPU.md "$OUT/PERFORMANCE_GPU.md"
  python3 benchmarks/bench.py "${scenes[@]}" --backend cuda --no-genesis --out "$OUT/PERFORMANCE_GPU.md" 2>&1 | tee "$OUT/bench.log" | tail -25
fi
