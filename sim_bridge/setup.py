from setuptools import find_packages, setup

PACKAGE = "sim_bridge"

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
    description="Drake simulation of the Robotiq 2F-85: grasp simulation, data generation, scenes, the sim bridge node and the clutter-removal benchmark.",
    license="BSD-3-Clause",
    entry_points={
        # Each executable is started as: ros2 run sim_bridge <name>. The studies and the
        # analysis tools are not installed: python -m sim_bridge.studies.<name> / .analysis.<name>
        "console_scripts": [
            "evaluate_grasp = sim_bridge.physics.evaluate_grasp_cli:main",
            "bench_sim = sim_bridge.physics.bench_sim:main",
            "datagen = sim_bridge.datagen.cli:main",
            "data_report = sim_bridge.datagen.data_report:main",
            "sim = sim_bridge.ros.sim_node:main",
            "demo = sim_bridge.ros.clutter_demo:main",
            "benchmark = sim_bridge.benchmark.clutter_benchmark:main",
            "qualitative = sim_bridge.benchmark.qualitative:main",
            "soak = sim_bridge.ros.soak:main",
            "bench_datagen = sim_bridge.datagen.bench_datagen:main",
        ],
    },
)
