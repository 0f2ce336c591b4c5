"""Training the grasp network on generated scenes (paper Sec. IV): the `train` command
(cli), its options (config), the scene files and label selection (scenes, scene_archive),
the losses and metrics (losses) and the loop with its checkpoints (loop). No ROS.
Imports perception and the plumbing at the top."""
