"""Gravity-aware grasp detection for the Robotiq 2F-85, in sub-packages by role (imports
point down only; tests/gravgrasp_detector/test_detector_layering.py checks it):

    ros          the nodes, ROS interface, markers, bag replay, cell files -> execution, calibration, perception
    tools        model cards, score calibration, benchmarks                -> training, perception
    execution    the executor, arm reachability, the UR adapter            -> perception
    training     the train command, scenes, losses, loop (paper Sec. IV)   -> perception
    calibration  hand-eye calibration, view capture                        -> (nothing)
    perception   TSDF, network, rotations, detection, model files, hand
                 clearance (paper Secs. IV-V)                              -> (nothing)

Only ros imports rclpy or ROS message packages. `poses`, `atomic_files` and `problem_log`
are shared plumbing any of them may import; they import no sub-package.
"""
