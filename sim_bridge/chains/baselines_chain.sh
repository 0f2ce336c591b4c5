#!/usr/bin/env bash
# The paper's Fig. 5 with its baselines (issue 41, item 5; sim_bridge/doc/baselines.md):
# VGN and VN-EdgeGraspNet (published weights, Panda hand) and VGN's grasps on the 2F-85,
# on the same scenes and protocol as the committed 2F-85 rounds of Ours, Binary and
# Ours-Precision, which are copied, not rerun. Resumable; `make benchmark-baselines` starts
#   ros_ws/run_pinned.sh COMMIT out/benchmark_baselines.log -- out/pinned/<COMMIT:12>/sim_bridge/chains/baselines_chain.sh
# Into sim_bridge/results/baselines_heldout (from heldout_v4: the 48 held-out meshes) and
# baselines_procedural (from procedural_v4: procedural seed 1000), 16 scenes each:
# vgn and vn_edge at 0.1, 0.5 and 1.5 kg, vgn_2f85 at 0.1 and 1.5 kg: 128 rounds a set.
# Cost, estimated (not measured on these methods): the 356 committed 2F-85 rounds took
# 251 CPU-s each on average (4.1 views a round; doc/baselines.md has the command);
# vn_edge adds ~10-12 CPU-s a view (doc/vn-edge-baseline.md), ~+45 s a round. So ~12.0k
# (vgn) + 8.0k (vgn_2f85) + 14.2k (vn_edge) = ~34k CPU-s a set, ~69k CPU-s (~19 CPU-h)
# in all: ~10 h on 2 free cores, more while other jobs share them.
# Order: the range's ends first (0.1 and 1.5 kg, all three methods, held-out then
# procedural), then 0.5 kg; scene-major within each step, so a step cut short has every
# method on the same scenes. Last, procedural Ours-Precision (48 2F-85 rounds), which
# procedural_v4 never ran. The reports and the figure are written at the end (the
# figure also any time: python -m sim_bridge.benchmark.baselines_figure).
set -euo pipefail
export PYTHONUNBUFFERED=1
[ $# -eq 0 ] || { echo "usage: sim_bridge/chains/baselines_chain.sh (no arguments; WORKERS=2 MESHES=DIR)" >&2; exit 2; }
meshes="${MESHES:-$PWD/../shared/meshes/vgn_train}"  # run_pinned.sh starts it in the project root
workers="${WORKERS:-2}"
copied=ours,binary,ours_precision  # the 2F-85 methods whose committed rounds are paired
all="$copied,vgn,vn_edge,vgn_2f85"
heldout=(--meshes "$meshes" --only models/vgn_heldout_meshes.txt)  # heldout_v4's options
prepare() {  # prepare SOURCE OUT: the committed run's scenes and copied methods' rounds (idempotent)
  python -m sim_bridge.studies.detection_levers paired_run --source "sim_bridge/results/$1" --out "sim_bridge/results/$2" \
    --methods "$copied"
}
bench() {  # bench OUT WEIGHTS METHODS [OPTION...]
  echo "[baselines] $(date -u +%FT%TZ) $1: $3 at $2 kg"
  python -m sim_bridge.studies.detection_levers --out "sim_bridge/results/$1" --workers "$workers" \
    --no-progress --scenes 16 --weights "$2" --methods "$3" "${@:4}" \
    || echo "[baselines] some rounds of $1 failed (listed above; a rerun retries them); going on"
}
report() {  # report OUT [OPTION...]: results.md etc. over every method, paired per scene
  python -m sim_bridge.studies.detection_levers --out "sim_bridge/results/$1" --report --no-progress \
    --scenes 16 --weights 0.1,0.5,1.5 --methods "$all" "${@:2}" >/dev/null \
    || echo "[baselines] the report of $1 failed; going on"
}
prepare heldout_v4 baselines_heldout
prepare procedural_v4 baselines_procedural
bench baselines_heldout 0.1,1.5 vgn,vgn_2f85,vn_edge "${heldout[@]}"
bench baselines_procedural 0.1,1.5 vgn,vgn_2f85,vn_edge
bench baselines_heldout 0.5 vgn,vn_edge "${heldout[@]}"
bench baselines_procedural 0.5 vgn,vn_edge
# procedural_v4 never ran Ours-Precision: its rounds are run here, on the baselines' code
bench baselines_procedural 0.1,1.5 ours_precision
bench baselines_procedural 0.5 ours_precision
report baselines_heldout "${heldout[@]}"
report baselines_procedural
python -m sim_bridge.benchmark.baselines_figure
echo "[baselines] $(date -u +%FT%TZ) done"
