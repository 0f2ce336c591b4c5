"""The paper's experiments (Sec. V): the clutter-removal benchmark (protocol, simulated
cell, rounds, report) and the qualitative check. Imports physics, datagen and world."""
