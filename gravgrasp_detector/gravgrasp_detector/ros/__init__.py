"""The ROS edge: the tsdf, detect, execute, ur_arm, calibrate_camera and stack nodes (thin
adapters around the core below), what they share (interface: pose messages, parameter
descriptors, run_node), grasp markers, bag writing and replay, and the cell parameter files
(cell_config reads and checks them, cell_file edits them). The only sub-package that imports
rclpy or ROS message packages. Imports perception, execution, calibration and the plumbing."""
