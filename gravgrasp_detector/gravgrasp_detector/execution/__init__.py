"""Executing a grasp with an arm and the 2F-85: the executor's checks and motion sequence
(executor), whether the arm can reach a pose (reachability), and the Universal Robots adapter
(ur_arm with its settings, controller codes and forward kinematics). No ROS: the execute
and ur_arm nodes in ros/ wrap them. Imports perception and the plumbing at the top."""
