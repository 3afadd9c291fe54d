#!/bin/bash
# Device check for issue 43 item 4: fern default run and the rasterizer benchmark on CUDA.
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 3
export PYTHONPATH=/tmp/site PATH=/tmp/site/bin:$PATH SPLAT_DATA=$PWD/.devdata SPLAT_CACHE=/tmp/splatcache PYTHONUNBUFFERED=1 COLUMNS=100
{ nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv; nproc; uptime;
  python3 -c "import torch,sys;print(sys.version);print(torch.__version__, torch.cuda.is_available(), torch.cuda.get_device_name())"; } > $OUT/machine.txt 2>&1
cat $OUT/machine.txt
run_fern() {  # $1: label
  local t0=$(date +%s.%N)
  timeout ${2:-200} splat-train scgaussian --data llff/fern --device cuda --output /tmp/$1 > $OUT/$1.log 2>&1
  local rc=$?
  local t1=$(date +%s.%N)
  echo "$1 rc=$rc wall_s=$(python3 -c "print(round($t1-$t0,1))")" | tee -a $OUT/summary.txt
  tail -32 $OUT/$1.log
  cp /tmp/$1/metrics.json $OUT/$1-metrics.json 2>/dev/null
}
run_fern fern-cold 220
timeout 150 python3 benchmarks/rasterizer.py --device cuda --sizes 10000 50000 200000 --repeats 5 --modes eager compiled --json $OUT/rasterizer-cuda.json --md $OUT/rasterizer-cuda.md > $OUT/rasterizer.log 2>&1; echo "bench rc=$?" | tee -a $OUT/summary.txt
tail -20 $OUT/rasterizer.log
run_fern fern-warm 150
