"""fresh_scenes: a run's methods against Binary over the scenes past the tuning ones."""

from test_run_vs_run import write_run

from sim_bridge.analysis import fresh_scenes

SCENES = ("packed_000", "pile_000", "packed_001", "pile_001")


def test_only_the_scenes_after_the_first_n_are_compared(tmp_path, capsys):
    rounds = []
    for sid in SCENES[:2]:  # the tuning scenes: ours far ahead there
        rounds += [("ours", 1.5, sid, ["success", "success"], "table_clear"),
                   ("binary", 1.5, sid, ["dropped", "dropped"], "consecutive_failures")]
    # the fresh ones: ours 1/2 and 2/2, binary 2/2 and 1/2 -> per scene -50 and +50, mean 0
    rounds += [("ours", 1.5, "packed_001", ["success", "dropped"], "consecutive_failures"),
               ("binary", 1.5, "packed_001", ["success", "success"], "table_clear"),
               ("ours", 1.5, "pile_001", ["success", "success"], "table_clear"),
               ("binary", 1.5, "pile_001", ["success", "no_object"], "consecutive_failures")]
    write_run(tmp_path / "run", rounds, scenes=SCENES)
    assert fresh_scenes.main([str(tmp_path / "run"), "--after", "2"]) == 0
    out = capsys.readouterr().out
    assert "| ours | 1.5 | 2 | 75.0 % | 75.0 % | +0.0 pts |" in out
    assert "diff_ours_vs_binary_1.5_fresh=+0.000" in out and "p_paired_ours_vs_binary_1.5_fresh=1.000" in out
    assert fresh_scenes.main([str(tmp_path / "run"), "--after", "0"]) == 0  # every scene: ours ahead
    assert "diff_ours_vs_binary_1.5_fresh=+0.500" in capsys.readouterr().out


def test_another_method_can_be_the_reference(tmp_path, capsys):
    rounds = []
    for sid in SCENES:  # lever 2/2 everywhere, ours 1/2, binary 0/2
        rounds += [("lever", 1.5, sid, ["success", "success"], "table_clear"),
                   ("ours", 1.5, sid, ["success", "dropped"], "consecutive_failures"),
                   ("binary", 1.5, sid, ["dropped", "dropped"], "consecutive_failures")]
    write_run(tmp_path / "run", rounds, scenes=SCENES)
    assert fresh_scenes.main([str(tmp_path / "run"), "--after", "0", "--methods", "lever", "--reference", "ours"]) == 0
    out = capsys.readouterr().out
    assert "paired against ours" in out and "| lever | 1.5 | 4 | 100.0 % | 50.0 % | +50.0 pts |" in out
    assert "diff_lever_vs_ours_1.5_fresh=+0.500" in out and "vs_binary" not in out
    assert fresh_scenes.main([str(tmp_path / "run"), "--after", "0", "--reference", "nobody"]) == 2
    assert "no method pairs with nobody" in capsys.readouterr().err


def test_nothing_fresh_or_no_report_is_one_clear_error(tmp_path, capsys):
    write_run(tmp_path / "run", [("ours", 0.1, "packed_000", ["success"], "table_clear"),
                                 ("binary", 0.1, "packed_000", ["success"], "table_clear"),
                                 ("ours", 0.1, "pile_000", ["success"], "table_clear"),  # Binary not yet there
                                 ("binary", 0.1, "packed_001", ["success"], "table_clear")])
    for after in ("1", "16"):  # past packed_000 both ran on no scene in common; past 16 on none at all
        assert fresh_scenes.main([str(tmp_path / "run"), "--after", after]) == 2
        assert "no method pairs with binary" in capsys.readouterr().err
    (tmp_path / "run" / "attempts.json").unlink()
    assert fresh_scenes.main([str(tmp_path / "run"), "--after", "1"]) == 2
    assert "run the benchmark's --report" in capsys.readouterr().err
