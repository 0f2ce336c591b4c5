"""Detectors besides the project's own model files: the paper's published baselines, one
module each, turning a view's TSDF into ranked grasps for the benchmark. Their files
(other people's weights) are read from the baselines directory outside the project's
tree (physics.baseline_files), never copied into it."""
