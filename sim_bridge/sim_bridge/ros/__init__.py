"""The ROS edge of the simulation: the sim bridge node, the clearing demo and the soak
run. The only sub-package that talks to ROS. Imports world and benchmark."""
