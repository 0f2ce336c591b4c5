"""The symmetry study's verdict from raw results (no simulation): copies that match
their originals are kept, copies that do not are not, whatever the control does."""
import json

import numpy as np

from sim_bridge.studies import symmetry_study


def raw_results(copy_noise_n, n=60, seed=3):
    rng = np.random.default_rng(seed)
    original = rng.uniform(5, 90, size=(n, 6))
    copy = np.clip(original + rng.normal(0, copy_noise_n, size=(n, 6)), 0, 100)
    control = np.clip(original + rng.normal(0, 4.0, size=(n, 6)), 0, 100)
    grasps = [(f"obj{i // 6}", i % 6) for i in range(n)]
    kinds = ["procedural" if i < n // 2 else "mesh" for i in range(n)]
    return grasps, kinds, np.ones((n, 3), bool), [original, copy, control]


def test_copies_as_close_as_the_control_are_kept():
    report = symmetry_study.summarize(*raw_results(copy_noise_n=1.0), cap=100.0, seed=0)
    assert report["kept"] and report["symmetric_copy"]["spearman_f_g"] > report["control_1mm"]["spearman_f_g"]
    assert {"symmetric_copy_mesh", "control_1mm_mesh", "symmetric_copy_procedural"} <= report.keys()
    lo, hi = report["spearman_f_g_copy_minus_control_90ci"]
    assert lo <= hi


def test_copies_unlike_their_originals_are_not_kept():
    grasps, kinds, held, scores = raw_results(copy_noise_n=1.0)
    scores[1] = scores[1][np.random.default_rng(0).permutation(len(grasps))]  # copies of other grasps
    assert not symmetry_study.summarize(grasps, kinds, held, scores, cap=100.0, seed=0)["kept"]
    held[:, 1] = np.arange(len(grasps)) % 4 != 0  # and a quarter dropped
    assert not symmetry_study.summarize(grasps, kinds, held, raw_results(1.0)[3], 100.0, 0)["kept"]


def test_summarize_again_from_a_saved_study(tmp_path, capsys):
    grasps, kinds, held, scores = raw_results(copy_noise_n=2.0)
    first = symmetry_study.summarize(grasps, kinds, held, scores, 100.0, 0)
    saved = tmp_path / "study.json"
    saved.write_text(json.dumps(first))
    assert symmetry_study.main(["--summarize", str(saved), "--out", str(tmp_path / "again.json")]) == 0
    again = json.loads((tmp_path / "again.json").read_text())
    assert again["symmetric_copy"] == first["symmetric_copy"] and again["kept"] == first["kept"]
    assert capsys.readouterr().out.strip().splitlines()[-1].startswith("symmetry_spearman_f_g=")
