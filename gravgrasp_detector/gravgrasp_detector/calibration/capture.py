"""Which camera images become calibration views: those taken while the arm stood still
at a new pose. No rclpy: the calibrate_camera node feeds it live messages or a bag.

An image (by its stamp) is taken when the flange poses of the last `still_s` before it
all agree within `still_mm` / `still_deg` (the arm rested: no motion blur, and the pose
belongs to the image), the newest pose is at most `max_pose_age_s` older than the image,
and that pose is at least `min_move_mm` or `min_turn_deg` away from every view taken so
far (one view per rest pose). So a person can jog the arm from pose to pose and let it
rest; nothing needs to be triggered.
"""
from __future__ import annotations

import bisect
import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation


@dataclasses.dataclass
class CaptureSettings:
    still_s: float = 0.5
    still_mm: float = 0.5
    still_deg: float = 0.2
    max_pose_age_s: float = 0.1
    min_move_mm: float = 20.0
    min_turn_deg: float = 5.0


def _apart(A, B) -> tuple[float, float]:
    return (float(np.linalg.norm(A[:3, 3] - B[:3, 3]) * 1000),
            float(np.degrees(Rotation.from_matrix(A[:3, :3].T @ B[:3, :3]).magnitude())))


class StillPoseCapture:
    def __init__(self, settings: CaptureSettings | None = None):
        self.settings = settings or CaptureSettings()
        self._times: list[float] = []
        self._poses: list[np.ndarray] = []
        self.views: list[tuple[float, object, np.ndarray]] = []   # (stamp s, image, X_task_flange)
        self._rejected: list[np.ndarray] = []  # rest poses whose image had no board

    def add_pose(self, stamp_s: float, X_task_flange) -> None:
        at = bisect.bisect(self._times, stamp_s)
        self._times.insert(at, stamp_s)
        self._poses.insert(at, np.asarray(X_task_flange, float))
        # keep a bounded history (a minute at 30 Hz is plenty)
        if len(self._times) > 2000:
            del self._times[:500], self._poses[:500]

    def pose_at(self, stamp_s: float):
        """The flange pose for an image at stamp_s, or (None, why not)."""
        s = self.settings
        hi = bisect.bisect_right(self._times, stamp_s)
        if hi == 0:
            return None, "no flange pose before the image yet"
        if stamp_s - self._times[hi - 1] > s.max_pose_age_s:
            return None, (f"the newest flange pose is {stamp_s - self._times[hi - 1]:.2f} s older than the image "
                          "(is ur_arm publishing flange_pose, and are the clocks the same?)")
        lo = bisect.bisect_left(self._times, stamp_s - s.still_s)
        if self._times[lo] > stamp_s - s.still_s + s.max_pose_age_s:
            return None, "the arm has not been still long enough"
        newest = self._poses[hi - 1]
        for X in self._poses[lo:hi]:
            mm, deg = _apart(X, newest)
            if mm > s.still_mm or deg > s.still_deg:
                return None, "the arm is moving"
        return newest, ""

    def offer_image(self, stamp_s: float, image) -> str | None:
        """Take the image as a view (returns None) or say why not."""
        X, why = self.pose_at(stamp_s)
        if X is None:
            return why
        for taken in [v[2] for v in self.views] + self._rejected:
            mm, deg = _apart(X, taken)
            if mm < self.settings.min_move_mm and deg < self.settings.min_turn_deg:
                return "already have a view at this pose: move the arm on"
        self.views.append((stamp_s, image, X))
        return None

    def reject_last(self) -> None:
        """The last view is unusable (no board in it): drop it, and ignore further images
        at that rest pose."""
        if self.views:
            self._rejected.append(self.views.pop()[2])
