#!/usr/bin/env bash
# Models v6 and the decisive comparison on the locked hand, once models/grasp_tables_v6 is
# whole (`locked_hand_chain.sh tables`: every v3 table rescored with the self-locking drive,
# and its wraps made). One line per session resumes it (every step skips what is done):
#   make chain RECIPE=models_v6_chain.sh PIN=<the commit it started on>
# 1. out/scenes_v6: the 5,000 v3 scene recipes relabelled with the v6 tables (~45 min, no physics);
#    the data report into models/grasp_tables_v6/data_report.txt, and rescore_drift.txt (~3 CPU-min);
# 2. Ours, Binary and Ours-Precision v6 (the v4 schedule: 15 epochs, negatives at 250, ~1 h each on
#    2 cores) into out/training_v6/<variant>, copied to models/v6/ with the v4 file names (so that
#    `--models-dir models/v6` runs them under the same method names), each with its validation
#    calibration (models/calibration/<file stem>_v6_on_v6_val_scenes.json) and v4's on the same scenes,
#    its qualitative slices and its card (models/v6/<file stem>.md, both calibrations side by side);
# 3. the decisive comparison under the locked cell, paired per scene, on the v4 decisive runs'
#    scenes (so v6 pairs with v4 too): ours, ours_precision, binary at 4, 1.5 and 0.1 kg, 32 scenes
#    of the held-out meshes (sim_bridge/results/heldout_v6_decisive), then of procedural seed 1000
#    (procedural_v6_decisive); VGN and VN-EdgeGraspNet (Panda, its own drive) at 1.5 and 4 kg on the
#    held-out scenes; then the confirmation on procedural seed 2000, once (procedural_v6_s2000_confirm).
#    ~1,000 rounds, ~110 CPU-s each: ~30 CPU-h.
# Commit as it comes: git add models/v6 models/calibration sim_bridge/results/*_v6_*
set -euo pipefail
export PYTHONUNBUFFERED=1
meshes="${MESHES:-$PWD/../shared/meshes/vgn_train}"  # run_pinned.sh starts it in the project root
workers="${WORKERS:-2}"
tables=models/grasp_tables_v6
scenes=out/scenes_v6
models=models/v6
say() { echo "[v6] $(date -u +%FT%TZ) $*"; }

# the tables must be whole: a scene relabelled from a partial set would silently lose objects
missing=$(comm -23 <(ls models/grasp_tables_v3/objects | grep '\.npz$' | sort) <(ls "$tables/objects" | grep '\.npz$' | sort) | wc -l)
[ "$missing" -eq 0 ] || { say "$tables lacks $missing of v3's tables: run locked_hand_chain.sh tables first"; exit 2; }
[ -d "$tables/objects/toward_palm" ] || { say "$tables has no wraps yet (objects/toward_palm): run locked_hand_chain.sh tables first"; exit 2; }

say "scenes v6: the v3 scene recipes relabelled"
python -m sim_bridge.datagen recipes restore models/scene_recipes_v3 "$scenes" --objects "$tables" \
  --meshes "$meshes" --workers "$workers" --no-progress --relabel
if [ ! -f "$tables/data_report.txt" ]; then
  python -m sim_bridge.datagen.data_report "$tables" --scenes "$scenes" --png "$tables/data_report.png" \
    > "$tables/data_report.txt.tmp"
  mv "$tables/data_report.txt.tmp" "$tables/data_report.txt"
fi
if [ ! -f "$tables/rescore_drift.txt" ]; then  # rows whose closing ends otherwise than in v3's code, both ways
  python -m sim_bridge.studies.rescore_drift "$tables" --meshes "$meshes" --out "$tables/rescore_drift.json" \
    > "$tables/rescore_drift.txt.tmp"
  mv "$tables/rescore_drift.txt.tmp" "$tables/rescore_drift.txt"
fi

train() {  # train VARIANT FILE [OPTION]: out/training_v6/VARIANT (resumes per epoch), copied to models/v6/FILE
  if [ ! -f "$models/$2" ]; then
    say "train $1"
    python -m gravgrasp_detector.training.cli --data "$scenes" --out "out/training_v6/$1" --epochs 15 \
      --threads "$workers" --no-progress --negative-weight=250 "${@:3}"
    mkdir -p "$models" && cp "out/training_v6/$1/model.pt" "$models/$2.tmp" && mv "$models/$2.tmp" "$models/$2"
  fi
  local stem="${2%.pt}"
  for m in "v6:$models/$2" "v4:models/$2"; do  # the v6 model and the shipped v4 one, on v6's validation scenes
    name="${stem}_${m%%:*}_on_v6_val_scenes"  # as models/calibration names v4's: gravgrasp_binary_v4_on_v4_val_scenes
    [ -f "models/calibration/$name.json" ] && continue
    say "calibration $name"
    python -m gravgrasp_detector.tools.score_calibration --model "${m#*:}" --data "$scenes" --split val \
      --out "out/calibration/$name"
    mkdir -p models/calibration && cp "out/calibration/$name/calibration.png" "models/calibration/$name.png" \
      && cp "out/calibration/$name/calibration.json" "models/calibration/$name.json"
  done
  local qualitative="$models/qualitative/$stem"  # the paper's Sec. V-A slices, linked from the card
  [ -f "$qualitative/depth.png" ] || python -m sim_bridge.benchmark.qualitative --model "$models/$2" --out "$qualitative"
  python -m gravgrasp_detector.tools.model_card "out/training_v6/$1" --model "$models/$2" --qualitative "$qualitative" \
    --tables "$tables" --recipes models/scene_recipes_v3 \
    --calibration "models/calibration/${stem}_v6_on_v6_val_scenes.json" \
    --calibration "models/calibration/${stem}_v4_on_v6_val_scenes.json"
}
train ours gravgrasp.pt
train binary gravgrasp_binary.pt --target=binary
train precision_only gravgrasp_precision_only.pt --data-subset=precision-only

bench() {  # bench OUT SOURCE WEIGHTS METHODS [OPTION...]: SOURCE's scenes, the locked cell, v6's models
  if [ ! -f "sim_bridge/results/$1/scenes.jsonl" ]; then
    mkdir -p "sim_bridge/results/$1" && cp "sim_bridge/results/$2/scenes.jsonl" "sim_bridge/results/$1/.scenes.jsonl.tmp" \
      && mv "sim_bridge/results/$1/.scenes.jsonl.tmp" "sim_bridge/results/$1/scenes.jsonl"
  fi
  say "$1: $4 at $3 kg"
  python -m sim_bridge.benchmark.clutter_benchmark --out "sim_bridge/results/$1" --scenes 32 --weights "$3" \
    --methods "$4" --models-dir "$models" --drive self_locking --workers "$workers" --no-progress "${@:5}" \
    || say "some rounds of $1 failed (a rerun retries them); going on"
}
report() {  # report OUT METHODS [OPTION...]
  python -m sim_bridge.benchmark.clutter_benchmark --out "sim_bridge/results/$1" --scenes 32 --weights 0.1,1.5,4.0 \
    --methods "$2" --models-dir "$models" --drive self_locking --report --no-progress "${@:3}" | tail -n 40
}
heldout=(--meshes "$meshes" --only models/vgn_heldout_meshes.txt)
ours3=ours,ours_precision,binary
for kg in 4.0 1.5 0.1; do bench heldout_v6_decisive heldout_v4_decisive "$kg" "$ours3" "${heldout[@]}"; done
report heldout_v6_decisive "$ours3" "${heldout[@]}"
for kg in 4.0 1.5 0.1; do bench procedural_v6_decisive procedural_v4_decisive "$kg" "$ours3"; done
report procedural_v6_decisive "$ours3"
bench heldout_v6_decisive heldout_v4_decisive 1.5,4.0 vgn,vn_edge "${heldout[@]}"
report heldout_v6_decisive "$ours3,vgn,vn_edge" "${heldout[@]}"
for kg in 4.0 1.5 0.1; do
  bench procedural_v6_s2000_confirm procedural_s2000_confirm "$kg" "$ours3" --procedural-seed 2000
done
report procedural_v6_s2000_confirm "$ours3" --procedural-seed 2000
python -m sim_bridge.benchmark.paper_claims --runs sim_bridge/results/heldout_v6_decisive,sim_bridge/results/procedural_v6_decisive
say "done: write the answer (sim_bridge/doc/results.md, the README's table, the claims table) from the three reports"
