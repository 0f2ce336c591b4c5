#!/usr/bin/env bash
# The v3 dataset and models from where they stand to the end, each step resuming where
# it stopped, so that one line per session keeps the CPU busy across the steps:
#   ros_ws/run_pinned.sh COMMIT out/dataset_v3.log -- out/pinned/<COMMIT:12>/ros_ws/dataset_v3_chain.sh
# 1. the grasp tables grow to 256 candidates (models/grasp_tables_v2; commit them);
# 2. 5,000 scenes into out/scenes_v3 (labels checked where the robot executes them);
# 3. the data report (objects=, grasps=, power_fraction=, labels_per_scene_median=);
# 4. the five models of `make models` into out/training_v3/<variant>/model.pt (copy them to
#    models/ and refresh the cards by hand: what ships is a decision);
# 5. `make benchmark` on those model files (--model overrides; the rounds record each file's
#    sha256, so copying them to models/ later keeps the rounds valid): the 48 held-out VGN
#    meshes into out/benchmark_heldout, then unseen procedural objects into out/benchmark.
#    Steps 4 and 5 interleave: Ours and Binary, their held-out rounds, the three other
#    models, their held-out rounds, then the procedural objects.
#    Pin the chain at or after 8e3860f: before it, rerunning `train` on a finished model (as
#    every restart of this chain does) wrote model.pt again with a new sha256, and the
#    benchmark then reran every round of that model. (9663ac9 and later: the benchmark cell
#    without the executor's fingertip-table check, the contact stop counting the rise of the
#    force, the executor backing out after one.) Steps 1-4 resume at once where they are done.
# python -m rather than the make targets: those run `make setup` first (apt, pip, colcon
# build of the checkout), which a pinned long job has no business doing; run_pinned.sh
# has put the pinned packages first on PYTHONPATH.
set -euo pipefail
meshes="${MESHES:-$PWD/../shared/meshes/vgn_train}"  # run_pinned.sh starts it in the project root
workers="${WORKERS:-2}"

echo "[chain] $(date -u +%FT%TZ) tables"
python -m sim_bridge.datagen objects --meshes "$meshes" --exclude models/vgn_heldout_meshes.txt --procedural 100 \
  --limit 220 --grasps-per-object 256 --sim-setting time_step_s=0.001 --sim-setting max_force_n=100 \
  --sim-setting force_ramp_rate_n_s=800 --seed 0 --out models/grasp_tables_v2 --workers "$workers" --no-progress

echo "[chain] $(date -u +%FT%TZ) scenes"
python -m sim_bridge.datagen scenes --objects models/grasp_tables_v2 --meshes "$meshes" --scenes 5000 --seed 0 \
  --out out/scenes_v3 --workers "$workers" --no-progress

echo "[chain] $(date -u +%FT%TZ) report"
python -m sim_bridge.datagen.data_report models/grasp_tables_v2 --scenes out/scenes_v3

train() {  # train VARIANT [OPTION]: one model into out/training_v3/VARIANT (resumes per epoch)
  echo "[chain] $(date -u +%FT%TZ) train $1"
  python -m gravgrasp_detector.training --data out/scenes_v3 --out "out/training_v3/$1" --epochs 15 \
    --threads "$workers" --no-progress --negative-weight=250 "${@:2}"
}
models=()
for pair in ours:ours ours_precision:precision_only binary:binary ours_ey_ez:ey_ez ours_quat:quat; do
  models+=(--model "${pair%%:*}=out/training_v3/${pair#*:}/model.pt")
done
bench_size=(--scenes 16 --weights 0.1,0.5,1.5 --ablation-weights 0.5)  # the Makefile's BENCH_SIZE
heldout() {  # the held-out meshes, with the models trained so far (the others are skipped with a note)
  echo "[chain] $(date -u +%FT%TZ) benchmark held-out meshes"
  python -m sim_bridge.benchmark.clutter_benchmark --meshes "$meshes" --only models/vgn_heldout_meshes.txt \
    --out out/benchmark_heldout --workers "$workers" --no-progress "${bench_size[@]}" "${models[@]}" \
    || echo "[chain] some held-out rounds failed (listed above; a rerun retries them); going on"
}
# Ours and Binary first, and their held-out rounds at once: issue 16's first three targets
# need only these two, so they are known a session or two before the rest.
train ours
train binary --target=binary
heldout
train precision_only --data-subset=precision-only
train ey_ez --rotation=ey-ez
train quat --rotation=quat
heldout  # the three other models; the finished rounds are skipped
echo "[chain] $(date -u +%FT%TZ) benchmark procedural"
python -m sim_bridge.benchmark.clutter_benchmark --out out/benchmark --workers "$workers" --no-progress \
  "${bench_size[@]}" "${models[@]}"
echo "[chain] $(date -u +%FT%TZ) done"
