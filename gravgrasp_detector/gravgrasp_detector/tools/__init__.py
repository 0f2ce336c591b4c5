"""Commands about models and speed, not part of a running cell: model cards (model_card),
predicted against simulated scores (score_calibration), and the detection and training
benchmarks (bench_detect, bench_train). No ROS. Imports perception, training and the
plumbing at the top."""
