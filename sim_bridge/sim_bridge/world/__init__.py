"""The simulated robot cell in real time: a Drake world with gravity, the table, a scene,
the 2F-85 (or the baselines' Panda hand: WorldSettings.hand) on an arm stand-in, a depth
camera (`SimWorld`), and the runner that steps it on the wall clock while the Robotiq
emulator drives its fingers (`RealTimeRunner`, `SimFingerPlant`). No rclpy. Imports physics.

Other sub-packages use the names below, not the modules behind them."""

from .camera import camera_intrinsics, camera_pose
from .config import BARE_MESH_DENSITY_KG_M3, R_TOP_DOWN, CameraSettings, SceneConfig, WorldSettings, pose
from .finger_calibration import STROKE_M
from .runner import RealTimeRunner, SimFingerPlant
from .contacts import ObjectState
from .parallel_grip import EMPTY_MARGIN_M, GripVerdict
from .sim_world import SimWorld

__all__ = ["BARE_MESH_DENSITY_KG_M3", "EMPTY_MARGIN_M", "R_TOP_DOWN", "STROKE_M", "CameraSettings", "GripVerdict",
           "ObjectState", "RealTimeRunner", "SceneConfig", "SimFingerPlant", "SimWorld", "WorldSettings",
           "camera_intrinsics", "camera_pose", "pose"]
