#!/usr/bin/env bash
# One command for a GPU machine (issue 14 item 6): GPU/CPU parity of short rotor and
# two_balls runs, then rotor throughput at 512^2-4096^2 (and the 100-disc suspension with
# --suspension 300,1024).  Extra arguments go to benchmarks/gpu_check.py.  The next loan's
# command (about 5 minutes on an H200; docs/benchmarks.md "On a GPU"):
#   bash benchmarks/gpu.sh --parity-steps 200 --sizes 512,2048 --band-compare 256,512 \
#       --band-compare-3d 64,128 --sizes-3d 192 --incompressible 512 --steps 20
#
# The CUDA build of JAX: on the `device` tool's H200 image it is already installed (jax
# 0.11.x with the CUDA 13 plugin), and that machine cannot download, so nothing is installed
# there; elsewhere set REFMAP_INSTALL_JAX=1 to `pip install "jax[cuda12]"` first.  refmap
# runs from this checkout's src/ (PYTHONPATH), under whatever JAX the machine has; its
# figures go to $OUT/gpu_check.json (or ./gpu_check.json).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${REFMAP_INSTALL_JAX:-0}" = "1" ]; then
    python3 -m pip install -q "jax[cuda12]"
fi
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
python3 benchmarks/gpu_check.py --json "${OUT:-.}/gpu_check.json" "$@"
