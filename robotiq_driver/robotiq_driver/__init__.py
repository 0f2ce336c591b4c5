"""Robotiq 2F-85 over Modbus RTU: protocol, client, register-level emulator, gripper node."""
