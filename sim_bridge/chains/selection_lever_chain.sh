#!/usr/bin/env bash
# Issue 42's selection levers: one registered method (a model with a selection rule:
# sim_bridge/benchmark/methods) run beside the committed rounds of the same 16 scenes, so
# that only the new method costs CPU:
#   sim_bridge/results/heldout_v4_<LEVER> (the 48 held-out meshes) and
#   procedural_v4_<LEVER> (procedural seed 1000), LEVER = METHOD without "ours_";
# the scenes and the Ours and Binary rounds of heldout_v4_sure / procedural_v4_sure, and the
# Ours-Precision rounds of heldout_v4 / baselines_procedural (the same scenes), are copied
# (paired_run), then METHOD runs at 0.1 and 1.5 kg (32 rounds a set, ~40 min on 2 cores);
# its report pairs them all with Binary per scene (doc/levers.md reads it).
# One line per session resumes it (`make lever-selection METHOD=... PIN=<the commit it started on>`):
#   ros_ws/run_pinned.sh COMMIT out/lever_METHOD.log -- out/pinned/<COMMIT:12>/sim_bridge/chains/selection_lever_chain.sh METHOD
# Commit the rounds as they come: git add sim_bridge/results/*_v4_<LEVER> && git commit -m "..."
set -euo pipefail
export PYTHONUNBUFFERED=1
[ $# -eq 1 ] || { echo "usage: sim_bridge/chains/selection_lever_chain.sh METHOD (a registered method, e.g. ours_precision_sure; WORKERS=2 MESHES=DIR)" >&2; exit 2; }
method="$1"
lever="${method#ours_}"
meshes="${MESHES:-$PWD/../shared/meshes/vgn_train}"  # run_pinned.sh starts it in the project root
workers="${WORKERS:-2}"
size=(--scenes 16 --weights 0.1,1.5)

lever() {  # lever OURS_SOURCE PRECISION_SOURCE OUT [OPTION...]
  local out="sim_bridge/results/$3"
  python -m sim_bridge.studies.detection_levers paired_run --source "sim_bridge/results/$1" --out "$out" --methods ours,binary
  python -m sim_bridge.studies.detection_levers paired_run --source "sim_bridge/results/$2" --out "$out" --methods ours_precision
  echo "[$method] $(date -u +%FT%TZ) $3: $method at 0.1,1.5 kg"
  python -m sim_bridge.studies.detection_levers --out "$out" --workers "$workers" --no-progress \
    "${size[@]}" --methods "$method" "${@:4}" \
    || echo "[$method] some rounds of $3 failed (listed above; a rerun retries them); going on"
  python -m sim_bridge.studies.detection_levers --out "$out" --report --no-progress \
    "${size[@]}" --methods "ours,binary,ours_precision,$method" "${@:4}" | tail -n 16
}
lever heldout_v4_sure heldout_v4 "heldout_v4_$lever" --meshes "$meshes" --only models/vgn_heldout_meshes.txt
lever procedural_v4_sure baselines_procedural "procedural_v4_$lever"
echo "[$method] $(date -u +%FT%TZ) done"
