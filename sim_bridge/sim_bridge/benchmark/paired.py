"""Two methods compared scene by scene. Attempts in a round are not independent (a round
ends after two failures, and every attempt changes the scene), but every method runs the
same scenes: so the unit is the scene. Per scene, SR = successes / attempts of each method;
the statistic is the mean over scenes of the difference. Its p value is a sign-flip
permutation test (under "no difference" each scene's difference is as likely negated),
exact over all 2^n flips up to EXACT_MAX_SCENES scenes and from RANDOM_FLIPS seeded draws
beyond; its interval a paired bootstrap over scenes. A scene where either method made no
attempt has no SR there and is left out (`scenes` says how many count). For planning the next
run, the spread of the per-scene differences gives the scenes a run needs to see a given one."""

from __future__ import annotations

import itertools
import math

import numpy as np

EXACT_MAX_SCENES = 16
RANDOM_FLIPS = 200_000
BOOTSTRAP_DRAWS = 10_000
SEED = 0  # the same figures on every --report
PLAN_DIFF = 0.10  # the per-scene SR difference a planned run should be able to find (10 points)
Z_ALPHA, Z_POWER = 1.96, 0.84  # two-sided p < 0.05, 80 % power


def scene_rates(rounds: list) -> dict:
    """{(method, mass_kg): {scene_id: SR}} over rounds with at least one attempt."""
    rates = {}
    for r in rounds:
        if r["attempts"]:
            rates.setdefault((r["method"], float(r["mass_kg"])), {})[r["scene_id"]] = (
                r["successes"] / len(r["attempts"]))
    return rates


def sign_flip_p(diffs) -> float:
    """Two-sided p of mean(diffs) under random signs (1.0 when every difference is 0)."""
    d = np.asarray(diffs, float)
    if d.size == 0:
        return math.nan
    observed = abs(d.mean()) - 1e-12  # ties count as at least as extreme
    if d.size <= EXACT_MAX_SCENES:
        signs = np.array(list(itertools.product((1.0, -1.0), repeat=d.size)))
    else:
        signs = np.random.default_rng(SEED).choice((1.0, -1.0), size=(RANDOM_FLIPS, d.size))
    return float(np.mean(np.abs(signs @ d) / d.size >= observed))


def bootstrap_ci(diffs, level: float = 0.95) -> tuple:
    """Percentile interval of mean(diffs) over scenes resampled with replacement."""
    d = np.asarray(diffs, float)
    if d.size == 0:
        return (math.nan, math.nan)
    means = d[np.random.default_rng(SEED).integers(0, d.size, (BOOTSTRAP_DRAWS, d.size))].mean(axis=1)
    tail = 100 * (1 - level) / 2
    return (float(np.percentile(means, tail)), float(np.percentile(means, 100 - tail)))


def scenes_needed(diffs, effect: float = PLAN_DIFF) -> float:
    """Scenes a paired run needs to find a true mean per-scene difference `effect` (SR, 0-1)
    at two-sided p < 0.05 with 80 % power, given the spread of the differences `diffs` seen
    so far (normal approximation: ((Z_ALPHA + Z_POWER) sd / effect)^2, rounded up); NaN
    with fewer than 2 scenes."""
    d = np.asarray(diffs, float)
    if d.size < 2:
        return math.nan
    return float(math.ceil(((Z_ALPHA + Z_POWER) * d.std(ddof=1) / effect) ** 2))


def compare_paired(rounds: list, reference: str = "binary") -> list:
    """Every other method against `reference` at each weight both ran, over the scenes
    both have an SR for: [{method, reference, mass_kg, scenes, diff, ci95, p_value,
    scenes_for_10pts}], diff the mean per-scene SR difference (method - reference),
    scenes_for_10pts what a run would need to find 10 points (scenes_needed)."""
    rates = scene_rates(rounds)
    out = []
    for (method, kg), own in sorted(rates.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        ref = rates.get((reference, kg))
        if method == reference or ref is None:
            continue
        diffs = [own[s] - ref[s] for s in sorted(own.keys() & ref.keys())]
        out.append({"method": method, "reference": reference, "mass_kg": kg, "scenes": len(diffs),
                    "diff": float(np.mean(diffs)) if diffs else math.nan,
                    "ci95": bootstrap_ci(diffs), "p_value": sign_flip_p(diffs),
                    "scenes_for_10pts": scenes_needed(diffs)})
    return out


# The paper's power-grasp effect: Ours against the same network trained on precision grasps
# only (its Table I); the method is the first, the reference the second.
POWER_GRASP_PAIR = ("ours", "ours_precision")


def power_grasp_effect(rounds: list) -> list:
    """compare_paired of Ours against Ours-Precision at each weight both ran (the
    entries of compare_paired, method "ours", reference "ours_precision"); [] when
    either did not run."""
    return compare_paired([r for r in rounds if r["method"] in POWER_GRASP_PAIR], reference=POWER_GRASP_PAIR[1])
