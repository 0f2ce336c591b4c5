from setuptools import find_packages, setup

PACKAGE = "robotiq_driver"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    description="Robotiq 2F-85 over Modbus RTU: protocol, client, register-level emulator, gripper node.",
    license="BSD-3-Clause",
    entry_points={
        # Each executable is started as: ros2 run robotiq_driver <name>
        "console_scripts": [
            "gripper = robotiq_driver.gripper_node:main",
            "gripper_emulator = robotiq_driver.emulator.cli:main",
            "gripper_cli = robotiq_driver.gripper_cli:main",
            "bench_gripper = robotiq_driver.emulator.bench_gripper:main",
        ],
    },
)
