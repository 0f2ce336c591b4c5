from setuptools import find_packages, setup

PACKAGE = "gravgrasp_detector"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/cells", ["cells/sim.yaml", "cells/ur5e_2f85_realsense.yaml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    description="Gravity-aware grasp detection: TSDF integration, 3D FCN, grasp extraction, training, and the tsdf/detect/execute nodes.",
    license="BSD-3-Clause",
    entry_points={
        # Each executable is started as: ros2 run gravgrasp_detector <name>
        "console_scripts": [
            "tsdf = gravgrasp_detector.ros.tsdf_node:main",
            "detect = gravgrasp_detector.ros.detect_node:main",
            "bench_detect = gravgrasp_detector.tools.bench_detect:main",
            "bench_train = gravgrasp_detector.tools.bench_train:main",
            "bag_play = gravgrasp_detector.ros.bag_replay:main",
            "train = gravgrasp_detector.training.cli:main",
            "model_card = gravgrasp_detector.tools.model_card:main",
            "execute = gravgrasp_detector.ros.execute_node:main",
            "stack = gravgrasp_detector.ros.stack_node:main",
            "ur_arm = gravgrasp_detector.ros.ur_arm_node:main",
            "calibrate_camera = gravgrasp_detector.ros.calibrate_node:main",
            "score_calibration = gravgrasp_detector.tools.score_calibration:main",
        ],
    },
)
