#!/usr/bin/env bash
# The locked hand's long jobs (the 2F-85's self-locking transmission, physics.transmission):
#   A. the physics effect alone: the shipped v4 models (ours, ours_precision, binary) under the
#      self-locking cell at 1.5 and 4 kg on the decisive runs' 32 held-out-mesh scenes
#      (their scenes copied from sim_bridge/results/heldout_v4_decisive, whose back-drivable
#      rounds they pair with): sim_bridge/results/heldout_v4_locked, ~190 rounds, ~10 CPU-h;
#   B. grasp tables v6: models/grasp_tables_v3's tables simulated again with the locked drive
#      at the label settings' ramp (400 N/s to a 200 N cap: v3's 800 N/s to 100 N capped the
#      wraps the lock holds; `datagen rescore`, ~32 CPU-h), then their power grasps made as the paper makes them
#      (`datagen wrap`, 32 per object, ~6 CPU-h), then the mode-payload study on them.
# A and B run side by side, one worker each (CELL_WORKERS=2 or TABLE_WORKERS=2 gives one of them
# both cores while the other is stopped: the workers change no result). One line per session resumes both:
#   ros_ws/run_pinned.sh COMMIT out/locked_hand.log -- out/pinned/<COMMIT:12>/sim_bridge/chains/locked_hand_chain.sh [cell|tables|cell,tables]
# (or make chain RECIPE=locked_hand_chain.sh ARGS=cell PIN=COMMIT). The job begun on a1d39ee0a111,
# from before the recipes had a folder, runs that commit's copy in sim_bridge/scripts/; resume it, part by part, with
#   ros_ws/run_pinned.sh a1d39ee0a111 out/locked_hand.log -- out/pinned/a1d39ee0a111/sim_bridge/scripts/locked_hand_chain.sh cell
# Commit what has finished as it comes (rounds of A; B's tables object by object):
#   git add sim_bridge/results/heldout_v4_locked models/grasp_tables_v6
set -uo pipefail
export PYTHONUNBUFFERED=1
meshes="${MESHES:-$PWD/../shared/meshes/vgn_train}"  # run_pinned.sh starts it in the project root
locked=sim_bridge/results/heldout_v4_locked
tables=models/grasp_tables_v6
say() { echo "[locked] $(date -u +%FT%TZ) $*"; }

cell() {
  if [ ! -d "$locked/scenes" ] && [ ! -f "$locked/scenes.jsonl" ]; then  # scenes/: a run begun on older code
    mkdir -p "$locked" && cp sim_bridge/results/heldout_v4_decisive/scenes.jsonl "$locked/.scenes.jsonl.tmp" \
      && mv "$locked/.scenes.jsonl.tmp" "$locked/scenes.jsonl"
  fi
  for kg in 4.0 1.5; do
    say "A: the locked cell, $kg kg"
    python -m sim_bridge.benchmark.clutter_benchmark --out "$locked" --scenes 32 --weights "$kg" \
      --methods ours,ours_precision,binary --meshes "$meshes" --only models/vgn_heldout_meshes.txt \
      --drive self_locking --workers "${CELL_WORKERS:-1}" --no-progress || say "A: some rounds failed (a rerun retries them)"
  done
  python -m sim_bridge.benchmark.clutter_benchmark --out "$locked" --scenes 32 --weights 1.5,4.0 \
    --methods ours,ours_precision,binary --meshes "$meshes" --only models/vgn_heldout_meshes.txt \
    --drive self_locking --report --no-progress | tail -n 30
  say "A: done"
}

tables_v6() {
  say "B: rescore $tables"
  python -m sim_bridge.datagen rescore --objects models/grasp_tables_v3 --out "$tables" --meshes "$meshes" \
    --sim-setting drive=self_locking --sim-setting force_ramp_rate_n_s=400 --sim-setting max_force_n=200 \
    --workers "${TABLE_WORKERS:-1}" --no-progress || say "B: some tables failed (a rerun retries them)"
  say "B: toward the palm"
  python -m sim_bridge.datagen wrap --objects "$tables" --meshes "$meshes" \
    --per-object 32 --workers "${TABLE_WORKERS:-1}" --no-progress || say "B: some objects failed (a rerun retries them)"
  python -m sim_bridge.studies.mode_payload_study --tables "$tables" --out sim_bridge/results/mode_payload_study_v6.json
  say "B: done"
}

parts="${1:-cell,tables}"  # which of them to run: cell, tables or both
[[ ",$parts," != *,cell,* ]] || cell >> out/locked_hand_cell.log 2>&1 &
[[ ",$parts," != *,tables,* ]] || tables_v6 >> out/locked_hand_tables.log 2>&1 &
wait
say "done: $parts"
