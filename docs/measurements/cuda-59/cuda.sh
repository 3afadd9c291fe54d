#!/bin/bash
# Device check for issue 59: the fern default run on CUDA with the code before the issue
# (7d6e5ee: torch.compile'd projection and loss) and after it (native CPU kernels; on CUDA the
# projection runs in eager torch, the loss compiled), each from an empty cache, then each again.
# Needs .whl (pure-Python requirements; before/ and after/ hold the two project wheels, built
# from `git archive`) and .devdata/llff/fern (images_8 and poses_bounds.npy) carried.
start=$(date +%s)
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl || exit 3
for v in before after; do
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/$v .whl/$v/*.whl || exit 3
done
export SPLAT_DATA=$PWD/.devdata PYTHONUNBUFFERED=1 COLUMNS=100
{ nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv; nproc; uptime;
  PYTHONPATH=/tmp/site python3 -c "import torch,sys;print(sys.version);print(torch.__version__, torch.cuda.is_available(), torch.cuda.get_device_name())"; } > $OUT/machine.txt 2>&1
cat $OUT/machine.txt
run_fern() {  # $1: before|after  $2: cold|warm
  local left=$(( ${BUDGET:-540} - ($(date +%s) - start) ))
  if [ $left -lt 130 ]; then echo "$1-$2 skipped: ${left} s left" | tee -a $OUT/summary.txt; return; fi
  local t0=$(date +%s.%N)
  PYTHONPATH=/tmp/$1:/tmp/site PATH=/tmp/$1/bin:$PATH SPLAT_CACHE=/tmp/cache-$1 \
    timeout $(( left < 240 ? left : 240 )) splat-train scgaussian --data llff/fern --device cuda --output /tmp/$1-$2 > $OUT/$1-$2.log 2>&1
  local rc=$?
  local t1=$(date +%s.%N)
  echo "$1-$2 rc=$rc wall_s=$(python3 -c "print(round($t1-$t0,1))")" | tee -a $OUT/summary.txt
  grep -v "^\(SCGaussian warm-up\|training\|evaluating\|rendering\):" $OUT/$1-$2.log | tail -25
  { echo "== $1-$2"; cat /tmp/$1-$2/metrics.json; echo; } >> $OUT/metrics.txt 2>/dev/null
}
run_fern after cold
run_fern before cold
run_fern after warm
run_fern before warm
