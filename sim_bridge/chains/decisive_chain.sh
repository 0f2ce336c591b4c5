#!/usr/bin/env bash
# Issue 42's decisive runs for the chosen lever METHOD (a registered method; the rule that
# chose it: sim_bridge/doc/levers.md), against Binary, the shipped Ours and Ours-Precision:
#   sim_bridge/results/heldout_v4_decisive (the 48 held-out meshes) and
#   procedural_v4_decisive (procedural seed 1000): 32 scenes, the lever runs' 16 (their
#     committed rounds copied: paired_run) and 16 new ones;
#   procedural_s2000_confirm: procedural seed 2000, which no choice saw, 32 scenes, once,
#     PRODUCT and Binary at 0.1 and 1.5 kg (the confirmation run), and METHOD.
# In the order that decides first (each step resumes; the copied rounds are not rerun):
#   1. METHOD and Binary at 0.1 and 1.5 kg, 32 scenes, held-out then procedural (128 new rounds)
#   then the product, PRODUCT (METHOD if the runs above adopt it, else the shipped `ours`;
#   levers.md says which), on the same 32 scenes:
#   2. PRODUCT at 0.1 and 1.5 kg (nothing new when it is METHOD)
#   3. the seed-2000 confirmation: PRODUCT and Binary at 0.1 and 1.5 kg
#   3b. with SCREEN (methods, comma-separated), the next lever screened where Binary's 32 scenes
#      are: SCREEN at 0.1 and 1.5 kg, held-out then procedural (levers.md's rule: screen on 32
#      scenes of both sets, decide on ~100); its rows are in the final report, and a restart's
#      step 1-2 reports leave them out until 3b writes its report again
#   4. PRODUCT and Binary at 4 kg, Ours-Precision at 1.5 and 4 kg
#   5. PRODUCT at 0.5 kg on the first 16 scenes (Binary's, Ours' and Ours-Precision's are copied)
#   6. METHOD on seed 2000, when it is not PRODUCT: the unbiased estimate of a lever not adopted
#      (it was step 2 until the lever failed step 1; its first rounds are kept)
# ~1.4 min a round on 2 cores, ~12 h in all: one line per session resumes it
# (`make lever-decisive METHOD=... [PRODUCT=...] [SCREEN=...] PIN=<the commit it started on>`):
#   ros_ws/run_pinned.sh COMMIT out/decisive_METHOD.log -- out/pinned/<COMMIT:12>/sim_bridge/chains/decisive_chain.sh METHOD [PRODUCT]
# Commit the rounds as they come: git add sim_bridge/results/*_decisive sim_bridge/results/procedural_s2000_confirm
set -euo pipefail
export PYTHONUNBUFFERED=1
[ $# -eq 1 ] || [ $# -eq 2 ] || { echo "usage: sim_bridge/chains/decisive_chain.sh METHOD [PRODUCT] (the chosen lever, e.g. ours_sure; the method steps 2-5 run, default METHOD; WORKERS=2 MESHES=DIR SCREEN=METHODS)" >&2; exit 2; }
method="$1"
product="${2:-$1}"
meshes="${MESHES:-$PWD/../shared/meshes/vgn_train}"  # run_pinned.sh starts it in the project root
workers="${WORKERS:-2}"
heldout=(--meshes "$meshes" --only models/vgn_heldout_meshes.txt)
screen="${SCREEN:-}"
everyone="ours,binary,ours_precision,$method${screen:+,$screen}"

copy() {  # copy SOURCE OUT METHODS: SOURCE's scenes and the rounds of METHODS into OUT
  [ -d "sim_bridge/results/$1" ] || return 0
  python -m sim_bridge.studies.detection_levers paired_run --source "sim_bridge/results/$1" --out "sim_bridge/results/$2" --methods "$3"
}
bench() {  # bench OUT SCENES WEIGHTS METHODS [OPTION...]
  echo "[decisive] $(date -u +%FT%TZ) $1: $4 at $3 kg, $2 scenes"
  python -m sim_bridge.studies.detection_levers --out "sim_bridge/results/$1" --workers "$workers" --no-progress \
    --scenes "$2" --weights "$3" --methods "$4" "${@:5}" \
    || echo "[decisive] some rounds of $1 failed (listed above; a rerun retries them); going on"
}
report() {  # report OUT METHODS WEIGHTS [OPTION...]: the run's report, then its 16 scenes no choice saw
  python -m sim_bridge.studies.detection_levers --out "sim_bridge/results/$1" --report --no-progress \
    --scenes 32 --weights "$3" --methods "$2" "${@:4}" | tail -n 24
  [[ "$1" != *_decisive ]] || python -m sim_bridge.analysis.fresh_scenes "sim_bridge/results/$1" --after 16 \
    --methods "$2" | tail -n 12 || true
}

# the committed 16-scene rounds of the same scenes (only those of methods the copy names)
copy heldout_v4_sure heldout_v4_decisive "ours,binary"
copy heldout_v4 heldout_v4_decisive "ours,binary,ours_precision"  # with 0.5 kg
copy heldout_v4_4kg heldout_v4_decisive "ours,binary"
copy procedural_v4_sure procedural_v4_decisive "ours,binary"
copy procedural_v4 procedural_v4_decisive "ours,binary"
copy baselines_procedural procedural_v4_decisive "ours_precision"
for set in heldout procedural; do  # METHOD's lever-run rounds, from the run that measured it
  for lever_run in "${set}_v4_sure" "${set}_v4_${method#ours_}"; do
    grep -qs "\"method\":\"$method\"" "sim_bridge/results/$lever_run/rounds.jsonl" \
      && copy "$lever_run" "${set}_v4_decisive" "$method"
  done
done

bench heldout_v4_decisive 32 0.1,1.5 "$method,binary" "${heldout[@]}"
bench procedural_v4_decisive 32 0.1,1.5 "$method,binary"
report heldout_v4_decisive "$method,binary" 0.1,1.5 "${heldout[@]}"
report procedural_v4_decisive "$method,binary" 0.1,1.5
bench heldout_v4_decisive 32 0.1,1.5 "$product" "${heldout[@]}"
bench procedural_v4_decisive 32 0.1,1.5 "$product"
chosen="$method"; [ "$product" = "$method" ] || chosen="$method,$product"  # a report keeps only the methods it names
report heldout_v4_decisive "$chosen,binary" 0.1,1.5 "${heldout[@]}"
report procedural_v4_decisive "$chosen,binary" 0.1,1.5
bench procedural_s2000_confirm 32 0.1,1.5 "$product,binary" --procedural-seed 2000
report procedural_s2000_confirm "$product,binary" 0.1,1.5 --procedural-seed 2000  # not METHOD's few rounds yet
if [ -n "$screen" ]; then
  bench heldout_v4_decisive 32 0.1,1.5 "$screen" "${heldout[@]}"
  bench procedural_v4_decisive 32 0.1,1.5 "$screen"
  report heldout_v4_decisive "$chosen,$screen,binary" 0.1,1.5 "${heldout[@]}"
  report procedural_v4_decisive "$chosen,$screen,binary" 0.1,1.5
fi
bench heldout_v4_decisive 32 4.0 "$product,binary" "${heldout[@]}"
bench heldout_v4_decisive 32 1.5,4.0 ours_precision "${heldout[@]}"
bench procedural_v4_decisive 32 4.0 "$product,binary"
bench procedural_v4_decisive 32 1.5,4.0 ours_precision
bench heldout_v4_decisive 16 0.5 "$product" "${heldout[@]}"
bench procedural_v4_decisive 16 0.5 "$product"
report heldout_v4_decisive "$everyone" 0.1,0.5,1.5,4.0 "${heldout[@]}"
report procedural_v4_decisive "$everyone" 0.1,0.5,1.5,4.0
bench procedural_s2000_confirm 32 0.1,1.5 "$method" --procedural-seed 2000
report procedural_s2000_confirm "$chosen,binary" 0.1,1.5 --procedural-seed 2000
echo "[decisive] $(date -u +%FT%TZ) done"
