"""The 2F-85 without the hardware: the register-level emulator (``GripperEmulator``
and its ``FingerPlant``), the pymodbus RTU server on a pty that serves it with line
faults on demand, the ``gripper_emulator`` executable and the ``bench_gripper``
round-trip benchmark. Imports the register map and the driver; the driver imports
nothing from here."""
