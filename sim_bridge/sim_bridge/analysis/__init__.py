"""Analysis of committed benchmark rounds: replay a round, diagnose a pick, compare two
runs or the scenes no choice saw, the lever table, copy paired rounds between runs, a
round's time profile. Tools for the studies and for a person reading results; the
benchmark pipeline (sim_bridge.benchmark) never imports them (tests/sim_bridge/test_layering.py).
Each runs as `python -m sim_bridge.analysis.<tool>`; the lever methods they may name are
registered by sim_bridge.studies.detection_levers."""
