#!/usr/bin/env bash
# Dataset v4: the v3 scenes relabelled from grown grasp tables, for issue 15's labels per
# scene (v3: median 142 < 150). One line per session resumes it:
#   ros_ws/run_pinned.sh COMMIT out/dataset_v4.log -- out/pinned/<COMMIT:12>/sim_bridge/chains/dataset_v4_chain.sh
# 1. models/grasp_tables_v3 (committed; a copy of v2 to start from) grows from 256 to 320
#    candidates per object (CANDIDATES=384 grows it further later: the same seed and blocks,
#    so the first 256 are v2's own and 320 then 384 gives what 384 at once would).
#    Measured before starting (out/study, 50 of the 5,000 v3 scenes relabelled with tables cut
#    to n candidates): median labels 56 / 90 / 118 / 134 at 64 / 128 / 192 / 256 (elasticity
#    0.44 at the top), so 320 should give ~10 % more (v3's median 142 -> ~155, issue 15 asks
#    150) at half the cost of 384: ~8,600 new candidates (384: ~17,300) at ~1.0 CPU-s each
#    alone on the cores (2.3 s wall each while the benchmark shared them), ~1.3 h on 2 cores;
#    the relabel then tells within the same session whether 384 is needed. Each object's
#    table is rewritten when its new blocks are done: commit them as they come
#      git add models/grasp_tables_v3 && git commit -m "Grasp tables v3: ..."
#    (blocks in flight live in models/grasp_tables_v3/objects/.parts, ignored by git).
# 2. out/scenes_v4: the 5,000 v3 scenes (models/scene_recipes_v3) relabelled with those tables,
#    no physics (`recipes restore --relabel`, ~1 CPU-s a scene); nothing else to commit: the
#    recipes and the tables rebuild it on any machine.
# 3. the data report (objects=, grasps=, power_fraction=, labels_per_scene_median=);
# 4. all five models on it, the same schedule as v3, into out/training_v4/<variant> (~25 min
#    each alone on the 2-core EPYC; copy them to models/ with their cards by hand, and commit
#    them: a retrained model has another sha256, and the benchmark redoes every round of a
#    model it has not seen);
# 5. the benchmark of the shipped models: sim_bridge/chains/benchmark_chain.sh v4 (its own line per
#    session, as it runs for days; it needs the models copied to models/ first).
set -euo pipefail
export PYTHONUNBUFFERED=1  # the log shows each epoch when it ends, not in 4 KiB bursts
meshes="${MESHES:-$PWD/../shared/meshes/vgn_train}"  # run_pinned.sh starts it in the project root
workers="${WORKERS:-2}"
candidates="${CANDIDATES:-320}"

echo "[chain] $(date -u +%FT%TZ) tables v3: grow to $candidates candidates"
python -m sim_bridge.datagen objects --meshes "$meshes" --exclude models/vgn_heldout_meshes.txt --procedural 100 \
  --limit 220 --grasps-per-object "$candidates" --sim-setting time_step_s=0.001 --sim-setting max_force_n=100 \
  --sim-setting force_ramp_rate_n_s=800 --seed 0 --out models/grasp_tables_v3 --workers "$workers" --no-progress

echo "[chain] $(date -u +%FT%TZ) scenes v4: the v3 scenes relabelled"
python -m sim_bridge.datagen recipes restore models/scene_recipes_v3 out/scenes_v4 --objects models/grasp_tables_v3 \
  --meshes "$meshes" --workers "$workers" --no-progress --relabel

echo "[chain] $(date -u +%FT%TZ) report"
python -m sim_bridge.datagen.data_report models/grasp_tables_v3 --scenes out/scenes_v4

shipped() {  # shipped VARIANT FILE: models/FILE is the model that out/training_v4/VARIANT trained
  [ -f "models/$2" ] && python -c "import sys; from gravgrasp_detector import model_file
cmd = model_file.load_model(sys.argv[1])[1].get('training_data', {}).get('command', '')
sys.exit(0 if f'--out {sys.argv[2]} ' in cmd + ' ' else 1)" "models/$2" "out/training_v4/$1"
}
train() {  # train VARIANT FILE [OPTION]: one model into out/training_v4/VARIANT (resumes per epoch)
  if shipped "$1" "$2"; then echo "[chain] $1: models/$2 is its model (shipped): not retrained"; return; fi
  echo "[chain] $(date -u +%FT%TZ) train $1"
  python -m gravgrasp_detector.training.cli --data out/scenes_v4 --out "out/training_v4/$1" --epochs 15 \
    --threads "$workers" --no-progress --negative-weight=250 "${@:3}"
}
variants=(ours:gravgrasp.pt binary:gravgrasp_binary.pt:--target=binary
          precision_only:gravgrasp_precision_only.pt:--data-subset=precision-only
          ey_ez:gravgrasp_ey_ez.pt:--rotation=ey-ez quat:gravgrasp_quat.pt:--rotation=quat)
train_variants() {  # train_variants VARIANT...: those of `variants`, in that order
  for v in "${variants[@]}"; do IFS=: read -r variant file option <<< "$v"
    [[ " $* " == *" $variant "* ]] && train "$variant" "$file" $option; done; return 0
}
train_variants ours binary precision_only ey_ez quat
echo "[chain] $(date -u +%FT%TZ) done: copy the models to models/, then sim_bridge/chains/benchmark_chain.sh v4"
