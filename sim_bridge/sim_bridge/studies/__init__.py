"""Studies: one-off measurements that decided a setting of the pipeline or checked a claim
about it (label settings, symmetric copies, table size, where holding stops, fingertip
check, do labels execute, refused grasps, execution settings). Each is a script with its
own `main` and writes a report under results/ or out/; the sim_bridge/doc/*-study.md pages
give the answers. Kept apart so the pipeline does not depend on them: they import physics,
datagen, world and benchmark; nothing imports them (tests/sim_bridge/test_layering.py)."""
