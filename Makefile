# gravgrasp front door. Every target runs `setup` first when needed; each is a thin
# call into the packages' own commands.
SHELL := /bin/bash
.DEFAULT_GOAL := help
ROS := set +u; source ros_ws/env.sh; set -u;
# Three workers on the 2 cores: with two, a sixth of the cores sat idle while tests waited on
# pseudo-terminals, timers and DDS (CI 671 s -> 611 s of tests with three). One test file per
# worker (a file's module fixtures, e.g. a sim world, are built once), in tests/conftest.py's order,
# heavy files first: xdist's default re-sorts files by test count, which hands out the one-test
# heavy files (the soak, 84 s) last, with the other workers idle.
PYTEST_ARGS ?= -n 3 --dist loadfile --no-loadscope-reorder

.PHONY: help setup build test demo lock bench-detect bench-train bench-sim bench-gripper data-report data-objects data-scenes

help:
	@echo "Run and test:"
	@echo "  make demo   - set up everything and run the main job"
	@echo "  make test   - set up everything and run every test"
	@echo "  make setup  - Debian packages, .venv from requirements.lock, colcon build"
	@echo "  make build  - colcon build only (after adding executables or messages)"
	@echo "  make lock   - re-resolve requirements.in into requirements.lock"
	@echo "  make soak          - 10 min: 30 Hz depth into tsdf + detect, /execute_grasp in the sim; RSS, drops, latency"
	@echo "  make chain RECIPE=<file of sim_bridge/chains/> [ARGS=...] [PIN=commit] - a long-job recipe, pinned to a commit, in the background (resumable)"
	@echo "Speed (each prints its figure last):"
	@echo "  make bench-detect  - TSDF->grasps and depth-integration latency (median of 50+)"
	@echo "  make bench-train   - one training step (batch 8): the training forward vs the dense one"
	@echo "  make bench-sim     - grasp evaluations per hour in the Drake 2F-85 simulation"
	@echo "  make bench-gripper - Modbus RTU round trips against the emulated 2F-85"
	@echo "  make bench-round   - a clutter round's CPU under the v4 and the fast execution settings, side by side"
	@echo "  make bench-datagen - label yield: v1 free sampler vs v2 resting-pose sampler, side by side"
	@echo "Data and models (long jobs; resumable):"
	@echo "  make data-objects  - v2 per-object grasp tables (resumable; GRASPS=64 WORKERS=2; many CPU-hours)"
	@echo "  make data-scenes   - v2 training scenes from the tables (resumable; SCENES=5000 WORKERS=2)"
	@echo "  make data-tables-v3 / data-scenes-v4 - v2 tables grown to 320 candidates; the v3 scenes relabelled with them"
	@echo "  make data-report   - summary of TABLES (models/grasp_tables_v3) and REPORT_SCENES (out/scenes_v4: make data-scenes-v4)"
	@echo "  make models        - train the shipped model and the comparison variants (resumable)"
	@echo "  make model-cards   - qualitative PNGs + models/<stem>.md card for every model of 'make models'"
	@echo "  make qualitative   - paper V-A scene through MODEL (models/gravgrasp.pt): TSDF/score/validness slice PNGs"
	@echo "  make calibration   - predicted vs simulated score per grasp mode on MODEL's held-out scenes (SCENES_DIR)"
	@echo "  make data-objects-v1 / data-scenes-v1 - the v1 dataset (of the first models)"
	@echo "The clutter-removal benchmark:"
	@echo "  make benchmark-quick - clutter removal vs weight, 2 scenes x 0.1/1.5 kg, models present (minutes)"
	@echo "  make benchmark     - clutter removal: 16 scenes x 0.1/0.5/1.5 kg, all methods, held-out meshes + procedural (176 rounds each, ~14 h; nohup; resumable)"
	@echo "  make benchmark-baselines - the paper's Fig. 5 baselines: VGN, VN-EdgeGraspNet (Panda) and VGN on the 2F-85 beside the committed rounds (256 rounds, ~10 h; pinned, background, resumable)"
	@echo "  make baselines-figure - SR/CR vs weight of every method, held-out and procedural side by side, and the table, from the rounds so far"
	@echo "Studies and levers (experiments; nothing ships from them):"
	@echo "  make label-settings-study - cheaper label settings checked against the v1 scores"
	@echo "  make symmetry-study - grasps copied to an object's symmetries, simulated against their originals (COPIES=rotation|mirror)"
	@echo "  make perturbation-study - held grasps moved 7.5 / 15 mm across the pads and shallower: how many still hold"
	@echo "  make label-execution-study - a sample of SCENES_OUT's labels executed as the benchmark executes grasps, per mode and weight (PER_MODE=40)"
	@echo "  make refusal-study - the grasps the executor refuses for collision on the held-out benchmark scenes, executed anyway: would they have held?"
	@echo "  make execution-settings-study - recorded attempts replayed under the new execution settings: same outcomes?"
	@echo "  make data-tables-v5 / data-scenes-v5 - v4's tables plus held candidates moved 15 mm (datagen perturb); the v3 scenes relabelled"
	@echo "  make lever-clearance - the label-time clearance lever: Ours retrained with the executor's clearance applied to its labels, 16-scene lever runs (~3.5 h; pinned, background, resumable)"
	@echo "  make lever-guarded - the execution lever: Ours and Binary with the guarded approach on the lever runs' scenes (~2.7 h; pinned, background, resumable)"
	@echo "  make lever-selection METHOD=ours_precision_sure - the selection levers: one registered method beside the committed Ours, Binary, Ours-Precision rounds (~80 min; pinned, background, resumable)"
	@echo "  make lever-decisive METHOD=... [PRODUCT=ours] [SCREEN=binary_scored] - the decisive runs of the chosen lever: 32 scenes on both tuning sets, then PRODUCT (default METHOD) there at 0.1-4 kg and on procedural seed 2000 once, SCREEN at 0.1/1.5 kg on the same 32 scenes (~14 h; pinned, background, resumable)"

setup:
	@ros_ws/setup.sh

build:
	@$(ROS) cd ros_ws && colcon build --symlink-install --event-handlers console_direct- \
	  --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE=$$VIRTUAL_ENV/bin/python

# pytest exits 5 when it collected no test: that is a failure of the suite, not a pass.
test: setup
	@$(ROS) python -m pytest $(PYTEST_ARGS); rc=$$?; \
	  if [ $$rc -eq 5 ]; then echo "make test: pytest collected no tests" >&2; fi; exit $$rc

# Until a trained model ships (models/), the main job shows the stack minus the network:
# DDS + rosbag2 round trips, then the Drake sim bridge, tsdf and execute nodes picking
# a box over Modbus RTU. With models/gravgrasp.pt present it clears a cluttered table.
demo: setup
	@$(ROS) if [ -f models/gravgrasp.pt ]; then ros2 run sim_bridge demo --objects 3 --out out/demo; \
	  else echo "models/gravgrasp.pt not trained yet: running the stack without the network"; \
	  python -m pytest -v -p no:randomly tests/system/test_interfaces.py tests/system/test_execute_in_sim.py; fi

lock:
	@rm -rf .venv-lock && python3.11 -m venv .venv-lock && \
	  .venv-lock/bin/pip install -q -r requirements.in && \
	  .venv-lock/bin/python ros_ws/write_lock.py requirements.lock && rm -rf .venv-lock

bench-detect: setup
	@$(ROS) ros2 run gravgrasp_detector bench_detect

bench-train: setup
	@$(ROS) ros2 run gravgrasp_detector bench_train

bench-sim: setup
	@$(ROS) ros2 run sim_bridge bench_sim

# A clutter round's CPU under v4's and the new execution settings, side by side (minutes).
.PHONY: bench-round execution-settings-study
bench-round: setup
	@$(ROS) python -m sim_bridge.benchmark.bench_round

# Committed rounds replayed attempt by attempt under v4's and the new settings (~1.5 h; resumable).
execution-settings-study: setup
	@$(ROS) python -m sim_bridge.studies.execution_settings_study --workers 2

bench-gripper: setup
	@$(ROS) ros2 run robotiq_driver bench_gripper

# Stability: 10 min of 30 Hz depth through tsdf + detect with /execute_grasp requests
# against the sim bridge; last line soak_ok=1 (CI runs 60 s: tests/system/test_soak.py).
.PHONY: soak
SOAK_S ?= 600
soak: setup
	@$(ROS) ros2 run sim_bridge soak --duration-s $(SOAK_S) --out out/soak

# The UR cell's stack with the ur_rtde stand-in: grasps back to back, the RTDE link dropped
# every 30 s, both cores loaded; arm_soak_ok last (gravgrasp_detector/doc/arm-adapter.md).
.PHONY: soak-arm
SOAK_ARM_S ?= 300
soak-arm: setup
	@$(ROS) python tests/support/arm_soak.py --duration-s $(SOAK_ARM_S) --drop-every-s 30 --out out/soak-arm

# Clutter removal against object weight (paper Sec. V-B/V-C); both resume in their --out directory.
.PHONY: benchmark benchmark-quick
benchmark-quick: setup
	@$(ROS) ros2 run sim_bridge benchmark --quick --out out/benchmark_quick --workers $(WORKERS)

# Benchmark v2: 16 scenes x 0.1/0.5/1.5 kg on two object sets the models never
# trained on, the 48 held-out VGN meshes and unseen procedural objects (procedural seed
# 1000); 176 rounds per object set (Ours, Binary and Ours-Precision at each weight, the two
# rotation ablations at 0.5 kg; sim_bridge/chains/benchmark_chain.sh adds ours_expected: 224), ~2.3 min
# a round on 2 cores (v4): ~14 h in all, resumable. v1's README run was --scenes 8 into out/benchmark.
BENCH_SIZE ?= --scenes 16 --weights 0.1,0.5,1.5 --ablation-weights 0.5
.PHONY: benchmark-heldout benchmark-procedural
benchmark: benchmark-heldout benchmark-procedural
benchmark-heldout: setup
	@$(ROS) ros2 run sim_bridge benchmark --meshes ../shared/meshes/vgn_train --only $(HELD_OUT) \
	  --out out/benchmark_heldout --workers $(WORKERS) $(BENCH_SIZE)
benchmark-procedural: setup
	@$(ROS) ros2 run sim_bridge benchmark --out out/benchmark --workers $(WORKERS) $(BENCH_SIZE)

# The paper's Fig. 5 with its baselines (sim_bridge/doc/baselines.md): vgn and
# vn_edge (Panda hand) at 0.1/0.5/1.5 kg and vgn_2f85 at 0.1/1.5 kg on heldout_v4's and
# procedural_v4's 16 scenes each, beside their committed 2F-85 rounds (copied, not rerun):
# 256 rounds, ~69k CPU-s estimated, ~10 h on 2 free cores. Pinned to PIN in the background
# (log: out/benchmark_baselines.log); resumable: rerun with PIN=<the commit it started on>.
PIN ?= HEAD
# $(call pinned_chain,LOG,RECIPE [ARGS]): sim_bridge/chains/RECIPE of commit PIN, in the background (an
# older commit keeps its recipes in chains/ or sim_bridge/scripts/: a resumed job runs its own)
pinned_chain = c=$$(git rev-parse --verify --quiet "$(PIN)^{commit}") || { echo "PIN=$(PIN) names no commit" >&2; exit 2; }; \
	  r=$$(set -- $(2); echo $$1); for d in sim_bridge/chains chains sim_bridge/scripts; do \
	    git cat-file -e "$$c:$$d/$$r" 2>/dev/null && break; done; \
	  git cat-file -e "$$c:$$d/$$r" 2>/dev/null || { echo "commit $${c:0:12} has no recipe $$r" >&2; exit 2; }; \
	  ros_ws/run_pinned.sh $$c $(1) -- out/pinned/$${c:0:12}/$$d/$(2)
# Any long-job recipe of sim_bridge/chains/ (one per run; each says what it runs and how long), pinned to
# PIN, log out/<RECIPE>.log: make chain RECIPE=locked_hand_chain.sh ARGS=cell PIN=<its commit>
# resumes a stopped one (the recipes' data commands skip what is done).
.PHONY: chain
chain:
	@[ -n "$(RECIPE)" ] || { echo "make chain RECIPE=<a file of sim_bridge/chains/> [ARGS=...] [PIN=commit]: $$(ls sim_bridge/chains | tr '\n' ' ')" >&2; exit 2; }
	@$(call pinned_chain,out/$(basename $(RECIPE)).log,$(RECIPE) $(ARGS))
.PHONY: benchmark-baselines baselines-figure
benchmark-baselines: setup
	@$(call pinned_chain,out/benchmark_baselines.log,baselines_chain.sh)
baselines-figure: setup
	@$(ROS) python -m sim_bridge.benchmark.baselines_figure
.PHONY: lever-clearance lever-guarded lever-selection lever-decisive
METHOD ?= ours_precision_sure
lever-clearance: setup
	@$(call pinned_chain,out/clearance_lever.log,clearance_lever_chain.sh)
lever-guarded: setup
	@$(call pinned_chain,out/guarded_lever.log,guarded_lever_chain.sh)
lever-selection: setup
	@$(call pinned_chain,out/lever_$(METHOD).log,selection_lever_chain.sh $(METHOD))
lever-decisive: setup
	@export SCREEN="$(SCREEN)"; $(call pinned_chain,out/decisive_$(METHOD).log,decisive_chain.sh $(METHOD) $(PRODUCT))

# Dataset v2: per-object tables from candidates sampled per resting pose,
# cheaper label settings (make label-settings-study), the held-out meshes left out.
# The tables are committed (models/grasp_tables_v2); scenes are regenerated from the seed.
GRASPS ?= 64
SCENES ?= 5000
# out/scenes_v2: the 128-candidate tables without the execution check (the shipped v2
# models learned from it); out/scenes_v3: the grown tables, labels checked where the robot
# executes them (sim_bridge/doc/datasets.md, *What a label carries, and the execution check*). The pool is pinned per directory.
SCENES_OUT ?= out/scenes_v3
TABLES ?= models/grasp_tables_v3
REPORT_SCENES ?= out/scenes_v4
WORKERS ?= 2
PROCEDURAL ?= 100
# v2's objects: the first 220 of the round-robin order (all 100 procedural, 120 VGN meshes;
# 203 with a table). CPU goes into more candidates per object (GRASPS=128, 256), which is
# what raises labels per scene, rather than into the other 135 meshes.
OBJECTS ?= 220
COPIES ?= rotation
LABEL_SETTINGS := --sim-setting time_step_s=0.001 --sim-setting max_force_n=100 --sim-setting force_ramp_rate_n_s=800
HELD_OUT := models/vgn_heldout_meshes.txt
data-objects: setup
	@$(ROS) ros2 run sim_bridge datagen objects --meshes ../shared/meshes/vgn_train --exclude $(HELD_OUT) \
	  --procedural $(PROCEDURAL) --limit $(OBJECTS) --grasps-per-object $(GRASPS) $(LABEL_SETTINGS) --seed 0 \
	  --out models/grasp_tables_v2 --workers $(WORKERS)

data-scenes: setup
	@$(ROS) ros2 run sim_bridge datagen scenes --objects models/grasp_tables_v2 --meshes ../shared/meshes/vgn_train \
	  --scenes $(SCENES) --seed 0 --out $(SCENES_OUT) --workers $(WORKERS)

data-report: setup
	@$(ROS) ros2 run sim_bridge data_report $(TABLES) --scenes $(REPORT_SCENES)

# Dataset v4 (more labels per scene): the v2 tables grown in place to TABLES_V3_GRASPS
# candidates (models/grasp_tables_v3, committed; its first 256 rows are v2's) and the v3
# scenes relabelled from their committed recipes with them (the same settled scenes, no
# physics, ~1 CPU-s a scene). sim_bridge/chains/dataset_v4_chain.sh runs both, then training.
TABLES_V3_GRASPS ?= 320
.PHONY: data-tables-v3 data-scenes-v4 data-tables-v5 data-scenes-v5
data-tables-v3: setup
	@$(ROS) ros2 run sim_bridge datagen objects --meshes ../shared/meshes/vgn_train --exclude $(HELD_OUT) \
	  --procedural $(PROCEDURAL) --limit $(OBJECTS) --grasps-per-object $(TABLES_V3_GRASPS) $(LABEL_SETTINGS) \
	  --seed 0 --out models/grasp_tables_v3 --workers $(WORKERS)
data-scenes-v4: setup
	@$(ROS) ros2 run sim_bridge datagen recipes restore models/scene_recipes_v3 out/scenes_v4 \
	  --objects models/grasp_tables_v3 --meshes $(CURDIR)/../shared/meshes/vgn_train --workers $(WORKERS) --relabel
# v5 = v4's tables (copied once) + perturbed rows beside them (sim_bridge/chains/dataset_v5_chain.sh runs both and trains)
PERTURBED_PER_OBJECT ?= 32
data-tables-v5: setup
	@[ -d models/grasp_tables_v5/objects ] || { mkdir -p models/grasp_tables_v5 && \
	  cp -r models/grasp_tables_v3/objects models/grasp_tables_v3/symmetry models/grasp_tables_v5/ && \
	  rm -rf models/grasp_tables_v5/objects/.parts models/grasp_tables_v5/objects/perturbed; }
	@$(ROS) ros2 run sim_bridge datagen perturb --objects models/grasp_tables_v5 --meshes ../shared/meshes/vgn_train \
	  --exclude $(HELD_OUT) --per-object $(PERTURBED_PER_OBJECT) --seed 0 --workers $(WORKERS)
data-scenes-v5: setup
	@$(ROS) ros2 run sim_bridge datagen recipes restore models/scene_recipes_v3 out/scenes_v5 \
	  --objects models/grasp_tables_v5 --meshes $(CURDIR)/../shared/meshes/vgn_train --workers $(WORKERS) --relabel

# Side by side on the same objects: v1's free sampler at v1's label settings and the
# v2 sampler at v2's settings (~10 min on 2 cores). Last line: labels per scene per CPU-hour.
.PHONY: bench-datagen label-settings-study symmetry-study perturbation-study label-execution-study refusal-study data-objects-v1 data-scenes-v1
bench-datagen: setup
	@$(ROS) ros2 run sim_bridge bench_datagen --meshes ../shared/meshes/vgn_train --exclude $(HELD_OUT) \
	  --workers $(WORKERS) --json out/bench_datagen.json

# Which label settings rank grasps as the v1 settings do, at less CPU (~20 min).
label-settings-study: setup
	@$(ROS) python -m sim_bridge.studies.label_settings_study --tables models/grasp_tables_v1 \
	  --meshes ../shared/meshes/vgn_train --workers $(WORKERS)

# Do grasps copied to an object's symmetries hold as the simulated ones do? (240 grasps x 3
# simulations, ~40 min on 2 free cores)
symmetry-study: setup
	@$(ROS) python -m sim_bridge.studies.symmetry_study --tables models/grasp_tables_v2 --copies $(COPIES) \
	  --meshes ../shared/meshes/vgn_train --workers $(WORKERS) --out out/symmetry_study$(if $(filter mirror,$(COPIES)),_mirror).json

# Where does holding stop? Held candidates of the v3 tables moved 7.5 and 15 mm across the
# pads and shallower, closed again (8 objects x 10 candidates x 6 moves, ~10 CPU-min).
# Last line: held_fraction_across_15mm=.
perturbation-study: setup
	@$(ROS) python -m sim_bridge.studies.perturbation_study --tables models/grasp_tables_v3 --meshes ../shared/meshes/vgn_train \
	  --exclude $(HELD_OUT) --workers $(WORKERS) --out out/perturbation_study.json

# Do labels execute? A sample of SCENES_OUT's labels run as the benchmark runs a grasp, per
# mode and weight (PER_MODE labels x 2 weights, ~1 CPU-min each). Last line:
# approach_failure_fraction= (jammed on the approach or lift blocked).
PER_MODE ?= 40
label-execution-study: setup
	@$(ROS) python -m sim_bridge.studies.label_execution_study --scenes $(SCENES_OUT) --objects models/grasp_tables_v2 \
	  --meshes ../shared/meshes/vgn_train --per-mode $(PER_MODE) --weights 1.5,0.1 --workers $(WORKERS) \
	  --out out/label_execution/$(notdir $(SCENES_OUT))

# Is the executor's collision check too strict? Of Ours' top 5 grasps on the first view of
# each held-out benchmark scene, those it refuses for collision, executed anyway (~1 CPU-min
# each), beside the grasp the benchmark ran. Last line: refused_success_fraction=.
refusal-study: setup
	@$(ROS) python -m sim_bridge.studies.refusal_study --bench sim_bridge/results/heldout_v4 --model models/gravgrasp.pt \
	  --weights 1.5,0.1 --workers $(WORKERS) --out sim_bridge/results/refusal_study/heldout_v4

# Dataset v1 (the shipped models' data): free sampler, settled poses.
data-objects-v1: setup
	@$(ROS) ros2 run sim_bridge datagen objects --meshes ../shared/meshes/vgn_train --procedural 200 --sampler free \
	  --grasps-per-object 128 --sim-setting time_step_s=0.001 --seed 0 --out models/grasp_tables_v1 --workers $(WORKERS)

data-scenes-v1: setup
	@$(ROS) ros2 run sim_bridge datagen scenes --objects models/grasp_tables_v1 --meshes ../shared/meshes/vgn_train \
	  --scenes 1200 --seed 0 --out out/scenes_v1 --label-pose settled --no-symmetry --workers $(WORKERS)

# The shipped model and the benchmark's comparison models, all trained on TRAIN_DATA
# (v1: out/scenes_v1, make data-scenes-v1; the shipped v2 models: TRAIN_DATA=out/scenes_v2
# EPOCHS=15 TRAIN_ARGS='--negative-weight=250 --max-scenes=1580', i.e. scenes 0-1579 of the
# 128-candidate tables; the v3 models: TRAIN_DATA=out/scenes_v3 TRAIN_OUT=out/training_v3 EPOCHS=15
# TRAIN_ARGS=--negative-weight=250, what sim_bridge/chains/dataset_v3_chain.sh runs, so that this copies its
# finished models). Each run resumes from TRAIN_OUT/<variant>/checkpoint.pt; on a GPU
# machine `train` runs on CUDA (gravgrasp_detector/doc/training.md, *On a GPU machine*).
# bf16 autocast only where the CPU has AMX (elsewhere it is emulated, slower than fp32).
EPOCHS ?= 20
TRAIN_DATA ?= out/scenes_v1
TRAIN_ARGS ?=
TRAIN_OUT ?= out/training
BF16 := $(shell grep -qw amx_bf16 /proc/cpuinfo 2>/dev/null && echo --bf16)
MODEL_VARIANTS := ours: precision_only:--data-subset=precision-only binary:--target=binary \
  ey_ez:--rotation=ey-ez quat:--rotation=quat
.PHONY: models
models: setup
	@$(ROS) set -e; for spec in $(MODEL_VARIANTS); do \
	  v=$${spec%%:*}; dest=models/gravgrasp$$([ $$v = ours ] || echo _$$v).pt; \
	  ros2 run gravgrasp_detector train --data $(TRAIN_DATA) --out $(TRAIN_OUT)/$$v --epochs $(EPOCHS) \
	    $(BF16) --no-progress $(TRAIN_ARGS) $${spec#*:}; \
	  cp $(TRAIN_OUT)/$$v/model.pt $$dest.tmp && mv $$dest.tmp $$dest && echo "wrote $$dest"; \
	done

# Paper Sec. V-A: cylinder + box, one camera; PNGs of the input TSDF and the score/validness
# cross-sections in out/qualitative/<model stem>/. Look at them; write what you saw in the model card.
MODEL ?= models/gravgrasp.pt
.PHONY: qualitative
qualitative: setup
	@$(ROS) if [ ! -f "$(MODEL)" ]; then echo "make qualitative: $(MODEL) does not exist (no trained model yet; train one or pass MODEL=path.pt)" >&2; exit 2; fi; \
	  ros2 run sim_bridge qualitative --model "$(MODEL)" --out "out/qualitative/$(basename $(notdir $(MODEL)))"

# Predicted vs simulated gravity-rejection score on the scenes MODEL's training held out,
# per grasp mode: out/calibration/<model stem>/calibration.png + .json; last line score_mae_n=.
# SCENES_DIR=out/scenes_v2 (v2 data); CALIBRATION_SPLIT=all for scenes it never trained on.
SCENES_DIR ?= out/scenes_v1
CALIBRATION_SPLIT ?= val
.PHONY: calibration
calibration: setup
	@$(ROS) ros2 run gravgrasp_detector score_calibration --model "$(MODEL)" --data "$(SCENES_DIR)" \
	  --split $(CALIBRATION_SPLIT) --out "out/calibration/$(basename $(notdir $(MODEL)))"

# A card per model of `make models` (models/gravgrasp*.md), each after its qualitative PNGs.
# Keeps the hand-written "What a person saw" paragraphs.
.PHONY: model-cards
# The cards link the slices shipped beside the models (models/qualitative/<stem>/); CARD_ARGS
# names the data, e.g. the v4 models: TRAIN_OUT=out/training_v4
# CARD_ARGS="--tables models/grasp_tables_v3 --recipes models/scene_recipes_v3".
CARD_ARGS ?=
model-cards: setup
	@$(ROS) set -e; for spec in $(MODEL_VARIANTS); do \
	  v=$${spec%%:*}; m=models/gravgrasp$$([ $$v = ours ] || echo _$$v).pt; \
	  if [ ! -f $$m ]; then echo "make model-cards: $$m does not exist (make models)" >&2; exit 2; fi; \
	  q=models/qualitative/$$(basename $$m .pt); ros2 run sim_bridge qualitative --model $$m --out $$q > /dev/null; \
	  ros2 run gravgrasp_detector model_card $(TRAIN_OUT)/$$v --model $$m --qualitative $$q $(CARD_ARGS); \
	done
