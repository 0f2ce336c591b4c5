"""Where the camera is: hand-eye calibration with a ChArUco board (hand_eye) and the choice
of which images become calibration views (capture). No ROS: the calibrate_camera node in
ros/ feeds them live messages or a bag. Imports only the plumbing at the top."""
