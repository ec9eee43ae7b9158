#!/usr/bin/env bash
# Turek-Hron on a GPU machine: one command per case, each sized to finish within about 8
# minutes (issue 10 item 4), then the comparison table.
#
#   bash validation/turek_hron_gpu.sh            # every case in turn, then the table
#   bash validation/turek_hron_gpu.sh csm1       # one case: csm1 csm2 cfd1 cfd2 fsi1, or table
#
# Resolutions are chosen from the step counts of this machine's runs and the H200's
# measured step time on small grids (docs/benchmarks.md, "On a GPU": the rotor at 512^2,
# 2.6e5 nodes, takes 1.9 ms a step, bound by kernel launches, not by the grid), assuming
# 2.5 ms a step for the CSM and compressible channel models (a few more kernels) and
# 10-20 ms for the incompressible channel (its pressure solve):
#
#   case  resolution                   steps (estimated)          time (estimated)
#   csm1  10 cells across, sine 1      1.7e5 (rest at ~1.5 s)     ~7 min
#   csm2  10 cells across, sine 1      1.7e5 (rest at ~0.8 s)     ~7 min
#   cfd1  8 cells (ny 164), incompr.   1.5e4 (t = 6 s)            3-5 min
#   cfd2  4 cells (ny 82), incompr.    1.2e4 (t = 10 s)           2-4 min
#   fsi1  4 cells (ny 82), compress.   5e3 rigid + 1.7e5 elastic  ~8 min
#
# None of these has run on a GPU yet (no device was lent to this work when it was
# written); the estimates are untested.  Every run is stopped after $TH_LIMIT seconds
# (default 480); a CSM or channel run that is stopped keeps its CSV log in $OUT but writes
# no JSON, so the table leaves it out.  Results go to ${OUT:-runs/turek_hron_gpu}.
# TH_SMOKE=1 runs every case for a few steps only (a check of the commands on a CPU).
#
# The CUDA build of JAX must be installed (REFMAP_INSTALL_JAX=1 installs jax[cuda12]);
# refmap runs from this checkout's src/ under $PYTHON (default python3).
set -uo pipefail
cd "$(dirname "$0")/.."
PY="${PYTHON:-python3}"
if [ "${REFMAP_INSTALL_JAX:-0}" = "1" ]; then
    "$PY" -m pip install -q "jax[cuda12]"
fi
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
OUT="${OUT:-runs/turek_hron_gpu}"
LIMIT="${TH_LIMIT:-480}"
mkdir -p "$OUT"

if [ "${TH_SMOKE:-0}" = "1" ]; then
    CSM_T=(--t-max 0.002)
    CFD1_T=(--t-end 0.01)
    CFD2_T=(--t-end 0.01)
    RIGID_T=0.01
    FSI_T=0.012
else
    CSM_T=()
    CFD1_T=(--t-end 6)
    CFD2_T=(--t-end 10)
    RIGID_T=8
    FSI_T=12
fi

run() {
    echo "== turek_hron.py $* (limit ${LIMIT} s)"
    timeout "$LIMIT" "$PY" validation/turek_hron.py "$@" --out "$OUT"
    local rc=$?
    if [ "$rc" -eq 124 ]; then
        echo "== stopped at the ${LIMIT} s limit: $*"
    elif [ "$rc" -ne 0 ]; then
        echo "== failed (exit $rc): $*"
    fi
    return 0
}

one() {
    case "$1" in
        csm1) run csm1 --nt 10 --blend sine --blur-width 1 --compression corner "${CSM_T[@]}" ;;
        csm2) run csm2 --nt 10 --blend sine --blur-width 1 --compression corner "${CSM_T[@]}" ;;
        cfd1) run cfd1 --fluid incompressible --ny 164 "${CFD1_T[@]}" ;;
        cfd2) run cfd2 --fluid incompressible --ny 82 "${CFD2_T[@]}" ;;
        fsi1)
            run cfd1 --ny 82 --t-end "$RIGID_T"
            run fsi1 --ny 82 --t-rigid "$RIGID_T" --t-end "$FSI_T"
            ;;
        table) "$PY" validation/turek_hron.py table --out "$OUT" | tee "$OUT/table.md" ;;
        *)
            echo "unknown case '$1': use csm1, csm2, cfd1, cfd2, fsi1, table or nothing (all)" >&2
            exit 2
            ;;
    esac
}

if [ $# -eq 0 ]; then
    for c in csm1 csm2 cfd1 cfd2 fsi1 table; do one "$c"; done
else
    for c in "$@"; do one "$c"; done
fi
