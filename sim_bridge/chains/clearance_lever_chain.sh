#!/usr/bin/env bash
# The label-time clearance lever: Ours retrained with the executor's open-hand clearance
# applied to its labels (sim_bridge/doc/label-clearance-lever.md), then a 16-scene lever
# run of it beside the committed Ours and Binary rounds of the same scenes. Its committed
# runs were made at 5a8d591, where the lever was a training option (--label-clearance).
# One line per session resumes it (every step resumes where it stopped):
#   ros_ws/run_pinned.sh COMMIT out/clearance_lever.log -- out/pinned/<COMMIT:12>/sim_bridge/chains/clearance_lever_chain.sh
# 1. out/scenes_v4: the 5,000 v4 training scenes restored from the committed recipes and
#    tables (no physics; ~1 CPU-s a scene, ~45 min on 2 cores);
# 2. out/scenes_v4_clearance: those scenes with the labels the executor refuses moved to
#    the negatives (~4 min; resumes per scene); out/training_v4/ours_clearance: the shipped
#    Ours' command (models/gravgrasp.md) on them, 15 epochs (~1 h on 2 cores; resumes per epoch);
# 3. sim_bridge/results/heldout_v4_clearance (the 48 held-out meshes) and
#    procedural_v4_clearance (procedural seed 1000): the scenes and the Ours and Binary
#    rounds of heldout_v4_sure / procedural_v4_sure copied (paired_run), then only
#    `ours_clearance` runs, at 0.1 and 1.5 kg (32 rounds a set, ~40 min each on 2 cores);
#    its report pairs the three per scene. Commit the rounds as they come:
#      git add sim_bridge/results/*_v4_clearance && git commit -m "..."
# Both tuning sets, as the issue asks; a fresh seed only for the final choice.
set -euo pipefail
export PYTHONUNBUFFERED=1
[ $# -eq 0 ] || { echo "usage: sim_bridge/chains/clearance_lever_chain.sh (no arguments; WORKERS=2 MESHES=DIR)" >&2; exit 2; }
meshes="${MESHES:-$PWD/../shared/meshes/vgn_train}"  # run_pinned.sh starts it in the project root
workers="${WORKERS:-2}"
run=out/training_v4/ours_clearance
model="ours_clearance=$run/model.pt"
heldout=(--meshes "$meshes" --only models/vgn_heldout_meshes.txt)

echo "[clearance] $(date -u +%FT%TZ) scenes v4: restore"
python -m sim_bridge.datagen recipes restore models/scene_recipes_v3 out/scenes_v4 --objects models/grasp_tables_v3 \
  --meshes "$meshes" --workers "$workers" --no-progress --relabel

echo "[clearance] $(date -u +%FT%TZ) scenes v4 with the clearance at label time"
python -m sim_bridge.studies.label_clearance_lever out/scenes_v4 --write out/scenes_v4_clearance
echo "[clearance] $(date -u +%FT%TZ) train $run"
python -m gravgrasp_detector.training.cli --data out/scenes_v4_clearance --out "$run" --epochs 15 \
  --threads "$workers" --no-progress --negative-weight=250

lever() {  # lever SOURCE OUT [OPTION...]: pair with SOURCE's Ours and Binary, run ours_clearance, report
  python -m sim_bridge.studies.detection_levers paired_run --source "sim_bridge/results/$1" --out "sim_bridge/results/$2" \
    --methods ours,binary
  echo "[clearance] $(date -u +%FT%TZ) $2: ours_clearance at 0.1,1.5 kg"
  python -m sim_bridge.studies.detection_levers --out "sim_bridge/results/$2" --workers "$workers" \
    --no-progress --scenes 16 --weights 0.1,1.5 --methods ours_clearance --model "$model" "${@:3}" \
    || echo "[clearance] some rounds of $2 failed (listed above; a rerun retries them); going on"
  python -m sim_bridge.studies.detection_levers --out "sim_bridge/results/$2" --report --no-progress \
    --scenes 16 --weights 0.1,1.5 --methods ours,binary,ours_clearance --model "$model" "${@:3}" | tail -n 12
}
lever heldout_v4_sure heldout_v4_clearance "${heldout[@]}"
lever procedural_v4_sure procedural_v4_clearance
echo "[clearance] $(date -u +%FT%TZ) done"
