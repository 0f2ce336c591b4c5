"""Offline data generation (paper Sec. III): candidate sampling, resting poses, the
per-object stage, training scenes, voxel labels, the report, the CLI
(`python -m sim_bridge.datagen objects|scenes ...`) and its benchmarks. Imports physics."""
