"""Drake simulation of the Robotiq 2F-85, in sub-packages by role (imports point down only;
tests/sim_bridge/test_layering.py checks it):

    studies    one-off measurements behind settings and claims   -> benchmark, world, datagen, physics
    ros        the sim bridge node, the demo, the soak run        -> benchmark, world, physics
    benchmark  clutter removal, qualitative check (paper Sec. V)  -> world, datagen, physics
    world      the simulated cell and its real-time runner        -> physics
    datagen    grasp tables, training scenes, labels (Sec. III)   -> physics
    physics    contact, actuators, hand, objects, grasp sim (III) -> (nothing)

Nothing imports `studies`: the pipeline runs without them.
`parallel` is shared plumbing any of them may import (crash-safe writes: gravgrasp_detector.atomic_files).
"""
