"""Drake simulation of the Robotiq 2F-85: grasp simulation, data generation, scenes, the sim bridge node and the clutter-removal benchmark."""
