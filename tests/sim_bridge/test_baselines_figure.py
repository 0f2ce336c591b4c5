"""The paper's Fig. 5 with its baselines (sim_bridge.benchmark.baselines_figure) on a tiny
synthetic results tree: partial results are shown as they are (rounds counted per cell,
"—" without rounds, "not run" where a method is not planned), rounds of another model
file are left out and counted, the paired differences are Ours − method per scene, VGN's
anchor is split by arrangement, and a missing run is one sentence."""


import pytest

from gravgrasp_detector.perception.model_file import file_sha256
from sim_bridge.benchmark import baselines_figure as bf
from sim_bridge.benchmark import run_files

SCENES = ("packed_000", "pile_000")


def write_round(run, method, kg, scene, successes, attempts, sha, n_objects=5):
    run_files.rounds_file(run).put({
        "method": method, "mass_kg": kg, "scene_id": scene, "model_sha256": sha, "n_objects": n_objects,
        "successes": successes, "attempts": [{"success": i < successes} for i in range(attempts)],
        "left_before_start": [], "fell_off": []})


def make_run(root, name):
    run = root / name
    run.mkdir(parents=True)
    (run / "config.json").write_text("{}")
    run_files.scenes_file(run).put(*({"scene_id": s} for s in SCENES))
    return run


@pytest.fixture
def tree(tmp_path):
    models, baselines = tmp_path / "models", tmp_path / "baselines"
    (baselines / "vgn").mkdir(parents=True)
    models.mkdir()
    for f, data in (("gravgrasp.pt", b"ours"), ("gravgrasp_binary.pt", b"binary")):
        (models / f).write_bytes(data)
    (baselines / "vgn" / "vgn_conv.pth").write_bytes(b"vgn")  # vn_edge's files absent: its rounds all count
    sha = {"ours": file_sha256(models / "gravgrasp.pt"), "binary": file_sha256(models / "gravgrasp_binary.pt"),
           "vgn": file_sha256(baselines / "vgn" / "vgn_conv.pth")}
    heldout, procedural = make_run(tmp_path, "heldout"), make_run(tmp_path, "procedural")
    write_round(heldout, "ours", 0.1, "packed_000", 3, 4, sha["ours"])
    write_round(heldout, "ours", 0.1, "pile_000", 2, 3, sha["ours"])
    write_round(heldout, "binary", 0.1, "packed_000", 2, 4, sha["binary"])
    write_round(heldout, "binary", 0.1, "pile_000", 3, 3, sha["binary"])
    write_round(heldout, "ours", 0.5, "packed_000", 5, 5, "a-retrained-model")  # stale: left out
    write_round(heldout, "vgn", 0.1, "pile_000", 1, 3, sha["vgn"])  # partial: one of two scenes
    write_round(heldout, "vgn_2f85", 1.5, "packed_000", 0, 2, sha["vgn"])
    write_round(heldout, "vn_edge", 0.5, "pile_000", 2, 2, "whatever")  # no file here to check against
    write_round(procedural, "ours", 0.1, "packed_000", 4, 4, sha["ours"])
    args = ["--heldout", str(heldout), "--procedural", str(procedural), "--models-dir", str(models),
            "--baselines", str(baselines), "--out-dir", str(tmp_path / "out")]
    return tmp_path, args


def rows(lines, first_cells):
    return [[c.strip() for c in line.strip("|").split("|")] for line in lines
            if line.startswith("| " + first_cells)]


def tables(tmp_path) -> tuple:
    """(the SR/CR table's lines, the paired table's lines, all lines)."""
    lines = (tmp_path / "out" / "baselines_table.md").read_text().splitlines()
    split = next(i for i, line in enumerate(lines) if line.startswith("Ours − method"))
    chain = next(i for i, line in enumerate(lines) if line.startswith("Where the gain comes from"))
    return lines[:split], lines[split:chain], lines


def test_partial_results_are_shown_with_their_round_counts(tree, capsys):
    tmp_path, args = tree
    assert bf.main(args) == 0
    table, _, lines = tables(tmp_path)
    assert capsys.readouterr().out.startswith("\n".join(lines))
    assert (tmp_path / "out" / "baselines_fig5.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    (ours,) = rows(table, "held-out meshes | Ours (2F-85)")
    # SR 0.1/0.5/1.5, CR 0.1/0.5/1.5; pooled over both scenes; the stale 0.5 kg round left out
    assert ours[2:] == ["71.4 % (5/7; 2/2)", "— (0/2)", "— (0/2)", "50.0 % (5/10; 2/2)", "— (0/2)", "— (0/2)"]
    (vgn,) = rows(table, "held-out meshes | VGN (Panda)")
    assert vgn[2] == "33.3 % (1/3; 1/2)" and vgn[5] == "20.0 % (1/5; 1/2)"
    (vgn_2f85,) = rows(table, "held-out meshes | VGN's grasps (2F-85)")
    assert vgn_2f85[2:5] == ["— (0/2)", "not run", "0.0 % (0/2; 1/2)"]
    (vn_edge,) = rows(table, "held-out meshes | VN-EdgeGraspNet (Panda)")
    assert vn_edge[3] == "100.0 % (2/2; 1/2)"
    (proc_ours,) = rows(table, "procedural objects | Ours (2F-85)")
    assert proc_ours[2] == "100.0 % (4/4; 1/2)"
    assert rows(table, "procedural objects | Binary (2F-85)")[0][2] == "— (0/2)"
    assert any("1 in held-out meshes rounds" in line for line in lines)


def test_the_paired_difference_is_ours_minus_the_method_per_scene(tree):
    tmp_path, args = tree
    bf.main(args)
    _, table, _ = tables(tmp_path)
    paired = rows(table, "held-out meshes | Binary (2F-85)")
    # per scene Ours − Binary: packed 3/4 − 2/4 = +25, pile 2/3 − 3/3 = −33.3: mean −4.2;
    # two scenes: every sign flip is as extreme, p = 1
    (binary,) = paired
    assert binary[2].startswith("-4.2 (") and binary[2].endswith("; p = 1; 2)")
    (vgn,) = rows(table, "held-out meshes | VGN (Panda)")
    assert vgn[2].startswith("+33.3 (") and vgn[2].endswith("; 1)")  # pile only: 2/3 − 1/3
    (vgn_2f85,) = rows(table, "held-out meshes | VGN's grasps (2F-85)")
    assert vgn_2f85[2:] == ["—", "not run", "—"]  # no scene both ran at 1.5 kg


def test_vgns_anchor_is_per_arrangement(tree):
    tmp_path, args = tree
    bf.main(args)
    table = (tmp_path / "out" / "baselines_table.md").read_text()
    assert ("- held-out meshes: packed — (0/0; 0 rounds; GIGA 74.5 %), pile 33.3 % (1/3; 1 rounds; GIGA 60.7 %)"
            in table)


def test_a_missing_run_is_one_sentence(tree, capsys):
    tmp_path, args = tree
    args[1] = str(tmp_path / "not_yet")
    assert bf.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "make benchmark-baselines" in err and "not_yet" in err
    assert not (tmp_path / "out").exists()


def test_the_chain_splits_the_gain_step_by_step_per_scene(tree):
    """Each step is later − earlier over the scenes both ran: Binary → Ours is the paired
    table's Ours − Binary; a step with no scene in common is a gap."""
    tmp_path, args = tree
    bf.main(args)
    _, _, lines = tables(tmp_path)
    start = next(i for i, line in enumerate(lines) if line.startswith("Where the gain comes from"))
    chain = lines[start:]
    (labels,) = rows(chain, "held-out meshes | Binary (2F-85) → Ours (2F-85)")
    assert labels[2] == "the labels"
    assert labels[3].startswith("-4.2 (") and labels[3].endswith("; p = 1; 2)")  # 0.1 kg, as Ours − Binary
    (whole,) = rows(chain, "held-out meshes | VGN (Panda) → Ours (2F-85)")
    assert whole[3].startswith("+33.3 (") and whole[3].endswith("; 1)")  # pile only: 2/3 − 1/3
    (hand,) = rows(chain, "held-out meshes | VGN (Panda) → VGN's grasps (2F-85)")
    assert hand[3:] == ["—", "—"]  # VGN at 0.1 kg, its grasps on the 2F-85 at 1.5 kg only
    assert [r[1] for r in rows(chain, "procedural objects |")] == [
        "VGN (Panda) → VGN's grasps (2F-85)", "VGN's grasps (2F-85) → Binary (2F-85)",
        "Binary (2F-85) → Ours (2F-85)", "VGN (Panda) → Ours (2F-85)"]


def test_the_default_runs_are_the_working_directorys(tmp_path, monkeypatch, capsys):
    """Relative to where it runs (the project root), not to the code: the chain runs the code
    of a pinned worktree (ros_ws/run_pinned.sh) on the checkout's results."""
    monkeypatch.chdir(tmp_path)
    assert bf.main([]) == 2
    assert capsys.readouterr().err.startswith("baselines_figure: sim_bridge/results/baselines_heldout holds no")
