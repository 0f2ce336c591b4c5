"""`python -m sim_bridge.datagen objects|scenes|recipes ...` (the same as `ros2 run sim_bridge datagen`)."""

from sim_bridge.datagen.cli import main

if __name__ == "__main__":
    main()
