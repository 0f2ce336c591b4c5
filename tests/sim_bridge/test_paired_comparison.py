"""The per-scene paired comparison (sim_bridge/benchmark/paired.py) that decides Ours
against Binary: exact sign-flip p values on small cases, scenes without attempts left
out, and the committed v4 held-out rounds giving the figures the docs quote."""
import json
import math
import pathlib

import numpy as np
import pytest

from sim_bridge.benchmark import paired, run_files

ROOT = pathlib.Path(__file__).resolve().parents[2]


def rnd(method, scene, successes, attempts, kg=0.1):
    return {"method": method, "mass_kg": kg, "scene_id": scene, "successes": successes,
            "attempts": [{}] * attempts}


def test_sign_flip_p_is_exact_on_small_cases():
    # 3 equal differences: only the 2 flips with all signs alike reach |mean| = 1, of 8
    assert paired.sign_flip_p([1.0, 1.0, 1.0]) == pytest.approx(2 / 8)
    assert paired.sign_flip_p([0.0, 0.0]) == 1.0
    # 0.5, 0.25: |mean| >= 0.375 only with both signs alike
    assert paired.sign_flip_p([0.5, 0.25]) == pytest.approx(0.5)
    # beyond EXACT_MAX_SCENES: seeded draws, the same value every time, close to the exact 2/2^20
    many = [1.0] * (paired.EXACT_MAX_SCENES + 4)
    assert paired.sign_flip_p(many) == paired.sign_flip_p(many) < 1e-4


def test_scenes_without_an_attempt_are_left_out_and_the_difference_is_per_scene():
    rounds = [rnd("ours", "a", 2, 2), rnd("binary", "a", 1, 2),  # +0.5
              rnd("ours", "b", 0, 2), rnd("binary", "b", 2, 2),  # -1.0
              rnd("ours", "c", 3, 3), rnd("binary", "c", 0, 0),  # binary made no attempt: out
              rnd("ours", "d", 1, 1)]                              # binary did not run it: out
    (c,) = paired.compare_paired(rounds)
    assert c["method"] == "ours" and c["reference"] == "binary" and c["scenes"] == 2
    assert c["diff"] == pytest.approx(-0.25) and c["p_value"] == pytest.approx(1.0)
    assert c["ci95"][0] <= c["diff"] <= c["ci95"][1]


def test_the_committed_v4_rounds_give_the_figures_the_docs_quote():
    rounds = run_files.rounds_file(ROOT / "sim_bridge/results/heldout_v4").records()
    found = {(c["method"], c["mass_kg"]): c for c in paired.compare_paired(rounds)}
    ours_01, ours_15, precision_15 = found["ours", 0.1], found["ours", 1.5], found["ours_precision", 1.5]
    assert ours_01["scenes"] == 16 and round(100 * ours_01["diff"], 1) == -17.6 and round(ours_01["p_value"], 3) == 0.014
    assert round(100 * ours_15["diff"], 1) == 12.3 and round(ours_15["p_value"], 2) == 0.22
    assert round(100 * precision_15["diff"], 1) == 21.3 and precision_15["p_value"] < 0.05
    committed = json.loads((ROOT / "sim_bridge/results/heldout_v4/comparisons.json").read_text())
    assert {(c["method"], c["mass_kg"]): round(c["paired"]["p_value"], 6) for c in committed} == {
        k: round(v["p_value"], 6) for k, v in found.items()}


def test_the_scenes_a_run_needs_grow_with_the_spread_of_the_per_scene_differences():
    # sd 0.35 (the decisive held-out run at 1.5 kg): ((1.96 + 0.84) 0.35 / 0.10)^2 = 96.04 -> 97
    spread = [0.35, -0.35] * 8
    sd = float(np.std(spread, ddof=1))
    assert paired.scenes_needed(spread) == math.ceil((2.8 * sd / 0.10) ** 2)
    assert paired.scenes_needed([x / 2 for x in spread]) < paired.scenes_needed(spread) / 3.9  # a quarter, rounded up
    assert paired.scenes_needed(spread, effect=0.20) < paired.scenes_needed(spread)
    assert math.isnan(paired.scenes_needed([0.2]))
    (c,) = paired.compare_paired([rnd("ours", "a", 2, 2), rnd("binary", "a", 1, 2),
                                  rnd("ours", "b", 0, 2), rnd("binary", "b", 2, 2)])
    assert c["scenes_for_10pts"] == paired.scenes_needed([0.5, -1.0])


def test_the_power_grasp_effect_is_ours_against_ours_precision_and_leaves_binary_out():
    rounds = [rnd("ours", "a", 2, 2, 4.0), rnd("ours_precision", "a", 0, 2, 4.0),  # +1.0
              rnd("ours", "b", 2, 2, 4.0), rnd("ours_precision", "b", 1, 2, 4.0),  # +0.5
              rnd("binary", "a", 0, 2, 4.0), rnd("binary", "b", 0, 2, 4.0),
              rnd("ours", "a", 1, 1, 0.1)]  # Ours-Precision did not run 0.1 kg: no entry
    (c,) = paired.power_grasp_effect(rounds)
    assert (c["method"], c["reference"], c["mass_kg"], c["scenes"]) == ("ours", "ours_precision", 4.0, 2)
    assert c["diff"] == pytest.approx(0.75) and c["p_value"] == pytest.approx(0.5)  # 2 of 4 flips as far
    assert paired.power_grasp_effect([r for r in rounds if r["method"] != "ours_precision"]) == []


def test_the_committed_decisive_rounds_give_the_power_grasp_effect_the_docs_quote():
    # results.md of the decisive held-out run: Ours − Ours-Precision at 4 kg, 32 scenes
    rounds = run_files.rounds_file(ROOT / "sim_bridge/results/heldout_v4_decisive").records()
    found = {c["mass_kg"]: c for c in paired.power_grasp_effect(rounds)}
    assert found[4.0]["scenes"] == 32 and round(100 * found[4.0]["diff"], 1) == -4.0
