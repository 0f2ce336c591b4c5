#!/usr/bin/env bash
# Issue 42's execution lever: the guarded approach (the executor's close_on_contact_within_m,
# what a compliant cell's moveUntilContact does: an approach the arm's contact stop halts at
# most 10 mm short of the grasp closes there instead of backing out). Execution is a run's
# setting, not a method's, so Ours and Binary both run with it, on the same 16 scenes as
# heldout_v4_sure / procedural_v4_sure (their scenes copied), at 0.1 and 1.5 kg:
#   sim_bridge/results/heldout_v4_guarded_approach (the 48 held-out meshes) and
#   procedural_v4_guarded_approach (procedural seed 1000), 64 rounds a set (~80 min on 2 cores).
# Each report pairs Ours with Binary per scene under the guarded approach; against the
# unguarded rounds of the same scenes: python -m sim_bridge.analysis.run_vs_run (benchmark.md).
# One line per session resumes it (`make lever-guarded PIN=<the commit it started on>`):
#   ros_ws/run_pinned.sh COMMIT out/guarded_lever.log -- out/pinned/<COMMIT:12>/sim_bridge/chains/guarded_lever_chain.sh
# Commit the rounds as they come: git add sim_bridge/results/*_v4_guarded_approach && git commit -m "..."
set -euo pipefail
export PYTHONUNBUFFERED=1
[ $# -eq 0 ] || { echo "usage: sim_bridge/chains/guarded_lever_chain.sh (no arguments; WORKERS=2 MESHES=DIR)" >&2; exit 2; }
meshes="${MESHES:-$PWD/../shared/meshes/vgn_train}"  # run_pinned.sh starts it in the project root
workers="${WORKERS:-2}"
size=(--scenes 16 --weights 0.1,1.5 --methods ours,binary --close-on-contact-within-m 0.01)

guarded() {  # guarded SOURCE OUT [OPTION...]: SOURCE's scenes, then Ours and Binary with the guarded approach
  mkdir -p "sim_bridge/results/$2"
  cp -n "sim_bridge/results/$1/scenes.jsonl" "sim_bridge/results/$2/"
  echo "[guarded] $(date -u +%FT%TZ) $2: ours,binary at 0.1,1.5 kg"
  python -m sim_bridge.studies.detection_levers --out "sim_bridge/results/$2" --workers "$workers" \
    --no-progress "${size[@]}" "${@:3}" \
    || echo "[guarded] some rounds of $2 failed (listed above; a rerun retries them); going on"
  python -m sim_bridge.studies.detection_levers --out "sim_bridge/results/$2" --report --no-progress \
    "${size[@]}" "${@:3}" | tail -n 16
}
guarded heldout_v4_sure heldout_v4_guarded_approach --meshes "$meshes" --only models/vgn_heldout_meshes.txt
guarded procedural_v4_sure procedural_v4_guarded_approach
echo "[guarded] $(date -u +%FT%TZ) done"
