#!/usr/bin/env bash
# Dataset v4: the v3 scenes relabelled from grown grasp tables, for issue 15's labels per
# scene (v3: median 142 < 150). One line per session resumes it:
#   ros_ws/run_pinned.sh COMMIT out/dataset_v4.log -- out/pinned/<COMMIT:12>/ros_ws/dataset_v4_chain.sh
# 1. models/grasp_tables_v3 (committed; a copy of v2 to start from) grows from 256 to 384
#    candidates per object: the same seed and blocks, so the first 256 are v2's own.
#    Measured before starting (out/study, 50 of the 5,000 v3 scenes relabelled with tables cut
#    to n candidates): median labels 56 / 90 / 118 / 134 at 64 / 128 / 192 / 256, so 384 should
#    give ~15-20 % more. ~1.9 CPU-s a candidate, ~10 CPU-h for all objects; each object's
#    table is rewritten when its 16 new blocks are done: commit them as they come
#      git add models/grasp_tables_v3 && git commit -m "Grasp tables v3: ..."
#    (blocks in flight live in models/grasp_tables_v3/objects/.parts, ignored by git).
set -euo pipefail
meshes="${MESHES:-$PWD/../shared/meshes/vgn_train}"  # run_pinned.sh starts it in the project root
workers="${WORKERS:-2}"

echo "[chain] $(date -u +%FT%TZ) tables v3: grow to 384 candidates"
python -m sim_bridge.datagen objects --meshes "$meshes" --exclude models/vgn_heldout_meshes.txt --procedural 100 \
  --limit 220 --grasps-per-object 384 --sim-setting time_step_s=0.001 --sim-setting max_force_n=100 \
  --sim-setting force_ramp_rate_n_s=800 --seed 0 --out models/grasp_tables_v3 --workers "$workers" --no-progress
echo "[chain] $(date -u +%FT%TZ) done"
