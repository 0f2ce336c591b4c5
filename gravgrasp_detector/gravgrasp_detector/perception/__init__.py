"""From depth to ranked grasps (paper Secs. IV-V): the TSDF volume, the network and its
rotation representations, grasp extraction, model files, and the open hand's clearance
check. No ROS. Imports only the plumbing at the top (poses, atomic_files, problem_log)."""
