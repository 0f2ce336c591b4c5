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
        # Each executable is started as: ros2 run sim_bridge <name>
        "console_scripts": [
            "evaluate_grasp = sim_bridge.evaluate_grasp_cli:main",
            "bench_sim = sim_bridge.bench_sim:main",
            "datagen = sim_bridge.datagen:main",
            "data_report = sim_bridge.data_report:main",
            "sim = sim_bridge.sim_node:main",
            "demo = sim_bridge.clutter_demo:main",
            "benchmark = sim_bridge.clutter_benchmark:main",
            "qualitative = sim_bridge.qualitative:main",
            "soak = sim_bridge.soak:main",
            "bench_datagen = sim_bridge.bench_datagen:main",
            "label_settings_study = sim_bridge.label_settings_study:main",
            "symmetry_study = sim_bridge.symmetry_study:main",
        ],
    },
)
