"""Gravity-aware grasp detection: TSDF integration, 3D FCN, grasp extraction, training, and the tsdf/detect/execute nodes."""
