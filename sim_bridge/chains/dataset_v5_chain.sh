#!/usr/bin/env bash
# Dataset v5: the v4 labels plus grasps at the edge of holding (`datagen perturb`), to test
# whether validness learns where a grasp stops holding. One line per session resumes it:
#   ros_ws/run_pinned.sh COMMIT out/dataset_v5.log -- out/pinned/<COMMIT:12>/sim_bridge/chains/dataset_v5_chain.sh
# Why: v4's 11.5 % more labels of the same kind bought nothing on validation, and the
# benchmark's confident misses sit ~15 mm from poses that hold (sim_bridge README, *Why did an
# attempt fail?*; perturbation_study: 15 mm across the pads 71 % still hold, shallower 66 %).
# 1. models/grasp_tables_v5: v4's tables (models/grasp_tables_v3, copied: git stores the same
#    files once) plus objects/perturbed/<name>.npz, PER_OBJECT held candidates per object moved
#    15 mm across the pads or shallower and closed on again (~3.5 CPU-s each: 32 per object,
#    ~6,500 candidates, ~2.5 h on 2 cores). Commit them as they come
#      git add models/grasp_tables_v5 && git commit -m "Grasp tables v5: ..."
# 2. out/scenes_v5: the 5,000 v3 scenes relabelled with those tables (~45 min, no physics);
# 3. the data report;
# 4. Ours v5 (the v3 schedule) into out/training_v5/ours, then its validation calibration
#    and v4 Ours' on the same v5 validation scenes (out/calibration/gravgrasp_{v5,v4}_on_v5_val_scenes),
#    and v5's on v4's validation scenes: validness precision at the same recall and top-1
#    picks decide whether v5 replaces v4;
# 5. Binary v5 (the baseline must see the same labels if Ours v5 ships).
set -euo pipefail
export PYTHONUNBUFFERED=1
meshes="${MESHES:-$PWD/../shared/meshes/vgn_train}"  # run_pinned.sh starts it in the project root
workers="${WORKERS:-2}"
per_object="${PER_OBJECT:-32}"
tables=models/grasp_tables_v5

if [ ! -d "$tables/objects" ]; then
  echo "[chain] $(date -u +%FT%TZ) $tables: a copy of models/grasp_tables_v3's tables"
  mkdir -p "$tables.tmp"
  cp -r models/grasp_tables_v3/objects models/grasp_tables_v3/symmetry "$tables.tmp/"
  rm -rf "$tables.tmp/objects/.parts" "$tables.tmp/objects/perturbed"
  mv "$tables.tmp" "$tables"
fi
echo "[chain] $(date -u +%FT%TZ) perturbed grasps: $per_object per object"
python -m sim_bridge.datagen perturb --objects "$tables" --meshes "$meshes" --exclude models/vgn_heldout_meshes.txt \
  --per-object "$per_object" --seed 0 --workers "$workers" --no-progress

echo "[chain] $(date -u +%FT%TZ) scenes v5: the v3 scenes relabelled"
python -m sim_bridge.datagen recipes restore models/scene_recipes_v3 out/scenes_v5 --objects "$tables" \
  --meshes "$meshes" --workers "$workers" --no-progress --relabel

echo "[chain] $(date -u +%FT%TZ) report"
python -m sim_bridge.datagen.data_report "$tables" --scenes out/scenes_v5

train() {  # train VARIANT [OPTION]: into out/training_v5/VARIANT (resumes per epoch)
  echo "[chain] $(date -u +%FT%TZ) train $1"
  python -m gravgrasp_detector.training.cli --data out/scenes_v5 --out "out/training_v5/$1" --epochs 15 \
    --threads "$workers" --no-progress --negative-weight=250 "${@:2}"
}
calibrate() {  # calibrate MODEL SCENES NAME: validation calibration (kept once done)
  [ -f "out/calibration/$3/calibration.json" ] && return
  echo "[chain] $(date -u +%FT%TZ) calibration $3"
  python -m gravgrasp_detector.tools.score_calibration --model "$1" --data "$2" --split val --out "out/calibration/$3"
}
train ours
calibrate out/training_v5/ours/model.pt out/scenes_v5 gravgrasp_v5_on_v5_val_scenes
calibrate models/gravgrasp.pt out/scenes_v5 gravgrasp_v4_on_v5_val_scenes
# and on v4's own validation labels: v5 must not lose what v4 had (v4 there: models/calibration/)
calibrate out/training_v5/ours/model.pt out/scenes_v4 gravgrasp_v5_on_v4_val_scenes
train binary --target=binary
echo "[chain] $(date -u +%FT%TZ) done"
