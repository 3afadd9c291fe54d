#!/bin/bash
# Device check for issue 59: the photometric loss (L1 + SSIM) on CUDA, eager against torch.compile'd,
# at fern's training size (378x504): the compile's one-off cost against what it saves per step.
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site .whl/*.whl .whl/after/*.whl || exit 3
export PYTHONPATH=/tmp/site PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name --format=csv,noheader
python3 - <<'PY' 2>&1 | tee $OUT/loss.txt
import time, torch
from splat_framework import losses
torch.manual_seed(0)
pred0 = torch.rand(378, 504, 3, device="cuda"); gt = torch.rand(378, 504, 3, device="cuda")
def step(fn):
    p = pred0.clone().requires_grad_(True)
    fn(p, gt, 0.2).backward()
def timed(fn, n=300):
    for _ in range(10): step(fn)
    torch.cuda.synchronize(); t = time.perf_counter()
    for _ in range(n): step(fn)
    torch.cuda.synchronize(); return (time.perf_counter() - t) / n * 1e3
print("eager ms/step", round(timed(losses._photometric), 3))
comp = torch.compile(losses._photometric)
t = time.perf_counter(); step(comp); torch.cuda.synchronize(); print("compile s", round(time.perf_counter() - t, 1))
print("compiled ms/step", round(timed(comp), 3))
print("eager ms/step again", round(timed(losses._photometric), 3))
PY
