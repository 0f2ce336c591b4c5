"""The paper's claims, each a paired per-scene comparison (sim_bridge.benchmark.paper_claims):
the verdicts, the drop from light to heavy, the baselines run used only where the run has no
VN-EdgeGraspNet rounds, and results.md holding exactly what the command prints."""
import json
import re
from pathlib import Path

import pytest

from sim_bridge.benchmark import paper_claims
from sim_bridge.benchmark.paired import scene_rates

ROOT = Path(__file__).resolve().parents[2]


def rounds(method, kg, srs):
    """One round per scene with the given SRs (4 attempts each)."""
    return [{"method": method, "mass_kg": kg, "scene_id": f"s{i:02d}", "successes": round(4 * sr),
             "attempts": [{}] * 4} for i, sr in enumerate(srs)]


def test_the_drop_is_the_others_minus_ours_per_scene():
    rates = scene_rates(rounds("ours", 0.1, [1.0, 0.75]) + rounds("ours", 1.5, [0.75, 0.75])
                        + rounds("binary", 0.1, [1.0, 1.0]) + rounds("binary", 1.5, [0.25, 0.5]))
    result = paper_claims.drop_difference(rates, "binary")
    # scene 0: binary drops 0.75, ours 0.25 -> +0.5; scene 1: binary 0.5, ours 0 -> +0.5
    assert result["scenes"] == 2 and result["diff"] == 0.5


def test_verdicts_read_the_sign_and_p():
    ten = [0.25] * 10  # ten scenes each +25 points: p = 2/1024
    assert paper_claims.verdict(paper_claims.paired(ten)).startswith("**holds**: +25.0 pts")
    assert paper_claims.verdict(paper_claims.paired([-x for x in ten])).startswith("opposite: −25.0 pts")
    assert paper_claims.verdict(paper_claims.paired([0.25, -0.25, 0.5])).startswith("same sign, n.s.")
    assert paper_claims.verdict(paper_claims.paired(ten), on_par=True).startswith("no: ahead")
    assert paper_claims.verdict(paper_claims.paired([0.25, -0.25]), on_par=True).startswith("no difference shown")
    assert paper_claims.verdict(paper_claims.paired([])) == "not run"


def test_vn_edge_comes_from_the_run_itself_when_it_has_it():
    own = (rounds("ours", 0.1, [0.5] * 4) + rounds("ours_precision", 4.0, [0.5] * 4)
           + rounds("vn_edge", 4.0, [0.5] * 4) + rounds("ours", 4.0, [0.5] * 4))
    baselines = rounds("ours_precision", 1.5, [1.0] * 6) + rounds("vn_edge", 1.5, [0.0] * 6)
    cells = dict(paper_claims.claims(own, baselines))
    assert cells["Ours-Precision on par with VN-EdgeGraspNet at 4 kg"].startswith("no difference shown: +0.0 pts")
    assert "Ours-Precision on par with VN-EdgeGraspNet at 1.5 kg" not in cells
    cells = dict(paper_claims.claims([r for r in own if r["method"] != "vn_edge"], baselines))
    assert cells["Ours-Precision on par with VN-EdgeGraspNet at 1.5 kg"].startswith("no: ahead: +100.0 pts")


def test_results_md_holds_what_the_command_prints():
    text = (ROOT / "sim_bridge/doc/results.md").read_text()
    m = re.search(r"<!-- paper-claims: [^>]*-->\n(.*?)\n<!-- /paper-claims -->", text, re.S)
    assert m, "results.md has no <!-- paper-claims --> block"
    assert m.group(1).split("\n") == paper_claims.table_lines(ROOT), \
        "results.md's claims table differs: paste `python -m sim_bridge.benchmark.paper_claims` into it"


def test_other_runs_are_read_when_given_and_a_wrong_count_is_refused(tmp_path, capsys):
    runs = []
    for name, diff in (("a", 1.0), ("b", 0.0)):
        run = tmp_path / name
        run.mkdir()
        records = rounds("ours", 4.0, [diff] * 6) + rounds("ours_precision", 4.0, [0.0] * 6)
        (run / "rounds.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
        runs.append(str(run))
    assert paper_claims.main(["--runs", ",".join(runs)]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if "at 4 kg" in line)
    assert "**holds**: +100.0 pts" in row and "level: +0.0 pts" in row
    with pytest.raises(SystemExit):
        paper_claims.main(["--runs", runs[0]])
    assert "needs 2 run directories" in capsys.readouterr().err


def test_the_power_grasp_claim_reads_not_run_where_no_heavy_round_exists(tmp_path):
    runs = []
    for name, kg in (("a", 0.1), ("b", 4.0)):
        run = tmp_path / name
        run.mkdir()
        records = rounds("ours", kg, [0.5] * 4) + rounds("ours_precision", kg, [0.5] * 4)
        (run / "rounds.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
        runs.append(run)
    lines = paper_claims.table_lines(tmp_path, [str(runs[0])] * 2)
    assert lines[2] == "| Ours ahead of Ours-Precision above 1 kg | not run | not run |"
    lines = paper_claims.table_lines(tmp_path, [str(r) for r in runs])  # one object set has a heavy run
    assert not any("above 1 kg" in line for line in lines)
    assert "| Ours ahead of Ours-Precision at 4 kg | not run | level: +0.0 pts" in "\n".join(lines)
