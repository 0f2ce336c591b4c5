"""What the simulated cell is made of: the scene on the table (`SceneConfig`), the
camera, the arm stand-in's limits and the contact settings (`WorldSettings`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..physics import panda_hand
from ..physics.baseline_files import baseline_file
from ..physics.contact import SimSettings
from ..physics.hands import hand_spec
from ..physics.scenes import ARRANGEMENTS, TABLE_HEIGHT_M

BARE_MESH_DENSITY_KG_M3 = 500.0  # mesh_dir of bare OBJs without object_mass_kg

# Hand pointing down: TCP z (approach) = -task z, closing axis y = -task y.
R_TOP_DOWN = np.diag([1.0, -1.0, -1.0])


def pose(R=np.eye(3), p=(0.0, 0.0, 0.0)) -> np.ndarray:
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, p
    return X


@dataclass
class SceneConfig:
    """What is on the table. `objects` (pairs of ObjectSpec and 4x4 X_task_object) places
    those objects as given (then settles them); otherwise `n_objects` are drawn with
    `seed`: procedural primitives, or URDF/OBJ files from `mesh_dir`, arranged `packed` or
    `pile` and settled (scenes.arrange). `object_mass_kg` > 0 overrides every mass."""

    seed: int = 0
    n_objects: int = 3
    arrangement: str = "packed"
    mesh_dir: str = ""
    object_mass_kg: float = 0.0
    objects: tuple = ()

    def validate(self):
        if self.arrangement not in ARRANGEMENTS:
            raise ValueError(f"arrangement {self.arrangement!r}: use {' or '.join(map(repr, ARRANGEMENTS))}")
        if not self.objects and not 1 <= self.n_objects <= 10:
            raise ValueError(f"n_objects {self.n_objects}: use 1..10")
        if not np.isfinite(self.object_mass_kg) or self.object_mass_kg < 0:
            raise ValueError(f"object_mass_kg {self.object_mass_kg}: use > 0, or 0 for each object's own")


@dataclass
class CameraSettings:
    """A fixed depth camera: optical frame at `position_m` looking at `target_m` (task
    frame), pinhole `width` x `height` px with focal length `focal_px` (VGN's camera)."""

    position_m: tuple = (0.15, -0.125, 0.526)  # 0.55 m from the table centre, 60 deg elevation
    target_m: tuple = (0.15, 0.15, TABLE_HEIGHT_M)
    width: int = 640
    height: int = 480
    focal_px: float = 540.0
    max_depth_m: float = 3.0


@dataclass
class WorldSettings:
    contact: SimSettings = field(default_factory=SimSettings)  # time step, contact model, friction
    camera: CameraSettings = field(default_factory=CameraSettings)
    home_tcp_m: tuple = (0.15, 0.15, 0.55)  # TCP (pointing down, open hand) after load/reset
    # The stand-in's reach: the TCP must stay in this box (task frame) and above the table.
    workspace_min_m: tuple = (-0.15, -0.15, TABLE_HEIGHT_M)
    workspace_max_m: tuple = (0.45, 0.45, 0.80)
    max_speed_mps: float = 0.25  # TCP speed cap (a request above it is slowed down)
    max_angular_speed_rad_s: float = 1.5
    max_contact_force_n: float = 60.0  # rise of the net contact force on the hand (since a motion began) that stops it
    settle_time_s: float = 0.3  # after loading, with the hand at home
    # Freeze objects at rest away from the hand and filter their contacts
    # (resting_objects): a clutter round's steps cost what the hand's neighbourhood does.
    freeze_resting_objects: bool = False
    # The hand (physics.hands): "2f85", the paper's, or "panda", the baselines' (its
    # files from `baselines_dir`; "" = physics.baseline_files' default).
    hand: str = "2f85"
    baselines_dir: str = ""

    def validate(self):
        self.contact.validate()
        hand_spec(self.hand)
        if self.hand == "panda":
            baseline_file(panda_hand.URDF, self.baselines_dir or None)
        lo, hi = np.asarray(self.workspace_min_m, float), np.asarray(self.workspace_max_m, float)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(lo < hi):
            raise ValueError("workspace_min_m must be below workspace_max_m on every axis (3 values each)")
        if not (self.max_speed_mps > 0 and self.max_angular_speed_rad_s > 0 and self.max_contact_force_n > 0):
            raise ValueError("max_speed_mps, max_angular_speed_rad_s and max_contact_force_n must be > 0")
