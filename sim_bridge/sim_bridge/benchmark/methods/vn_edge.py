"""VN-EdgeGraspNet (Huang et al., ICRA 2023) with its published weights as a detector: a
view's TSDF -> ranked grasps for the Panda hand. Edge sampling and grasp construction
follow the paper and the authors' clutter test (test_clutter_grasp.py and
simulator/utility.py of github.com/HaojHuang/Edge-Grasp-Network, read, not copied);
sampling and radius search are plain torch. Conventions and what differs:
sim_bridge/doc/vn-edge-baseline.md.

An edge joins an apex point a (one of 32, farthest-point sampled) to a contact point c
within 5 cm of it. Its grasp: the fingers close along c's normal n (the pose's y), the
hand approaches along t, the part of (c - a) orthogonal to n (the pose's z), and the
contact sits 0.065 m along t from the authors' grasp frame: 7 mm short of the Panda's
fingertips. Edges are kept when t points no more than ~6 degrees upwards, |c - a| lies
in (3, 38) mm, c lies (0, 40) mm deeper than a along t, and seven points of the hand lie
above the table; the network scores up to 1500 of them.

Grasp frame. The authors' pose is the Panda hand's PyBullet body frame (their
T_body_tcp is the identity), the hand link's centre of mass, 0.04 m along z from the
URDF `panda_hand` frame. The project's Panda TCP (physics.panda_hand.HAND_TO_TCP_M,
VGN's) is 0.062 m from it, so T_task_tcp = the authors' pose moved 0.022 m along its z.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
import torch.nn.functional as F

from gravgrasp_detector.perception import hand_clearance
from gravgrasp_detector.execution.executor import ExecutionLimits
from gravgrasp_detector.perception.detection import Grasp

from ...physics.panda_hand import HAND_TO_TCP_M
from ...physics.scenes import TABLE_HEIGHT_M
from ..sim_cell import HAND_GEOMETRY
from .method import Detector
from .vn_edge_cloud import CloudOptions, edge_point_cloud, edge_volume, surface_points, workspace_bounds
from .vn_edge_net import CHECKPOINT_DIR, EPOCH, KNN_K, PARTS, VNEdgeNet, load_vn_edge

# in the baselines directory: the file whose sha256 names the detector, and the other three
MODEL_FILE = f"{CHECKPOINT_DIR}/classifier_model-ckpt-{EPOCH}.pt"
COMPANION_FILES = tuple(f"{CHECKPOINT_DIR}/{part}-ckpt-{EPOCH}.pt" for part in PARTS if part != "classifier_model")
HAND_COM_Z_M = 0.04  # the URDF's panda_hand inertial origin: PyBullet's body frame
POSE_TO_TCP_M = HAND_TO_TCP_M - HAND_COM_Z_M  # 0.022
CONTACT_DEPTH_M = 0.072 - 0.007  # authors' pose -> contact along z: fingertip (0.072) less 7 mm
# seven points of the open hand in the authors' pose frame (the back of the hand, its four
# corners, two points 9 cm to either side at the fingertips' depth) that must lie above
# the table + 4 mm
HAND_POINTS_M = np.array([[0.0, 0.0, -0.02], [0.012, -0.09, 0.015], [-0.012, -0.09, 0.015], [0.012, 0.09, 0.015],
                          [-0.012, 0.09, 0.015], [0.005, 0.09, 0.078], [0.005, -0.09, 0.078]])
TABLE_CLEARANCE_M = 0.004


@dataclasses.dataclass(frozen=True)
class EdgeOptions:
    """The authors' clutter-test constants (lengths in metres)."""

    apexes: int = 32  # --sample_number
    ball_radius_m: float = 0.05
    max_ball_points: int = 1024  # radius search's max_num_neighbors
    min_edge_m: float = 0.003
    max_edge_m: float = 0.038
    max_depth_m: float = 0.04
    max_approach_up: float = 0.1  # approach . up below this (a shade above horizontal)
    min_edges: int = 10  # fewer kept edges: no detection
    max_edges: int = 1500  # more: a random 1500 are scored
    seed: int = 0  # every detection draws from a fresh generator with this seed
    max_grasps: int | None = None  # None: every scored edge
    cloud: CloudOptions = CloudOptions()


@dataclasses.dataclass
class VNEdgeGrasp(Grasp):
    """A project Grasp (pose T_task_tcp of the Panda hand; validness and rank_key the
    network's success probability; score_n NaN) with the edge's contact point (task
    frame). The authors' test opens the hand fully whatever the edge."""

    contact_m: np.ndarray = dataclasses.field(kw_only=True)


# edge sampling (plain torch)


def farthest_points(points, n: int, first: int):
    """Indices of `n` farthest-point samples of (N, 3) points starting at index `first`,
    sorted and without repeats (fewer than n when there are fewer distinct points)."""
    chosen = [first]
    distance = ((points - points[first]) ** 2).sum(1)
    for _ in range(n - 1):
        chosen.append(int(torch.argmax(distance)))
        distance = torch.minimum(distance, ((points - points[chosen[-1]]) ** 2).sum(1))
    return torch.unique(torch.tensor(chosen))


def ball_members(points, apexes, radius_m: float, max_points: int):
    """(ball, point) index pairs: the points closer than radius_m to each apex, ball by
    ball, each ball's points in index order (its nearest max_points when more)."""
    d2 = torch.cdist(points[apexes], points) ** 2
    inside = d2 < radius_m ** 2
    over = inside.sum(1) > max_points
    if over.any():  # rare at 4.5 mm spacing: a 5 cm ball of one surface holds ~400 points
        kth = torch.kthvalue(d2[over], max_points, dim=1).values
        inside[over] &= d2[over] <= kth[:, None]
    ball, point = torch.nonzero(inside, as_tuple=True)
    return ball, point


def knn_within_balls(positions, ball, k: int = KNN_K):
    """(N, k): each ball point's k nearest points of its own ball (rows of `positions`,
    `ball` sorted), itself included; a ball of fewer than k points repeats the point
    itself, which changes no maximum over the neighbours."""
    neighbours = torch.arange(len(positions))[:, None].repeat(1, k)
    bounds = torch.searchsorted(ball, torch.arange(int(ball.max()) + 2))
    for s, e in zip(bounds[:-1].tolist(), bounds[1:].tolist()):
        p = positions[s:e]
        n = min(k, e - s)
        neighbours[s:e, :n] = torch.topk(torch.cdist(p, p), n, dim=1, largest=False).indices + s
    return neighbours


# grasps from edges


def edge_geometry(relative, normals):
    """(approach t (E, 3): (c - a) less its part along n, unit; depth (E,): how much
    deeper c lies than a along t)."""
    x = F.normalize(torch.cross(normals, F.normalize(relative, dim=1), dim=1), dim=1)
    t = F.normalize(torch.cross(x, normals, dim=1), dim=1)
    return t, (relative * t).sum(1)


@dataclasses.dataclass
class Edges:
    """Every (apex, ball point) pair: the network reads all of them (the balls), scores
    the kept ones. Rows are ball by ball."""

    ball: torch.Tensor  # (M,) the apex's row in `apexes`
    member: torch.Tensor  # (M,) the contact's index in the cloud
    relative: torch.Tensor  # (M, 3) contact - apex
    normals: torch.Tensor  # (M, 3) the contact's normal
    approach: torch.Tensor  # (M, 3) t, towards the object
    depth: torch.Tensor  # (M,)
    apexes: torch.Tensor  # (A,) cloud indices


def sample_edges(points, normals, apexes, options=EdgeOptions()) -> Edges:
    """The edges of a cloud (points, normals: (N, 3) float32 tensors) from `apexes`."""
    ball, member = ball_members(points, apexes, options.ball_radius_m, options.max_ball_points)
    relative, contact_normals = points[member] - points[apexes[ball]], normals[member]
    return Edges(ball, member, relative, contact_normals, *edge_geometry(relative, contact_normals), apexes)


def kept_edges(edges: Edges, options=EdgeOptions()):
    """(M,) bool: an approach no more than max_approach_up upwards, a length in
    (min_edge_m, max_edge_m), a depth in (0, max_depth_m)."""
    length = edges.relative.norm(dim=1)
    return ((-edges.approach[:, 2] > -options.max_approach_up) & (length > options.min_edge_m)
            & (length < options.max_edge_m) & (edges.depth > 0) & (edges.depth < options.max_depth_m))


def edge_poses(apex, normals, approach, depth):
    """The authors' grasp poses (E, 4, 4): z = approach, y = the contact normal made
    orthogonal to it, origin CONTACT_DEPTH_M - depth behind the apex along z."""
    x = F.normalize(torch.cross(normals, approach, dim=1), dim=1)
    y = F.normalize(torch.cross(approach, x, dim=1), dim=1)
    pose = torch.zeros(len(apex), 4, 4, dtype=apex.dtype)
    pose[:, :3, 0], pose[:, :3, 1], pose[:, :3, 2] = x, y, approach
    pose[:, :3, 3] = apex - (CONTACT_DEPTH_M - depth)[:, None] * approach
    pose[:, 3, 3] = 1.0
    return pose


def above_table(poses, table_z_m=TABLE_HEIGHT_M):
    """(E,) whether every HAND_POINTS_M of each pose lies above table_z_m + 4 mm."""
    points = torch.as_tensor(HAND_POINTS_M, dtype=poses.dtype)
    z = points @ poses[:, 2, :3].T + poses[:, 2, 3]  # (7, E)
    return (z > table_z_m + TABLE_CLEARANCE_M).all(0)


def to_tcp(pose):
    """The authors' pose -> T_task_tcp of the project's Panda TCP."""
    tcp = np.array(pose, dtype=np.float64)
    tcp[:3, 3] += POSE_TO_TCP_M * tcp[:3, 2]
    return tcp


@torch.inference_mode()
def score_edges(net: VNEdgeNet, edges: Edges, rows):
    """Logits (E,) of the edges at `rows`, the network reading every ball."""
    neighbours = knn_within_balls(edges.relative, edges.ball)
    # the network reads the authors' approach sign: away from the object
    return net(edges.relative, edges.normals, edges.ball, len(edges.apexes), neighbours, rows,
               -edges.approach[rows])


@torch.inference_mode()
def detect_on_cloud(net: VNEdgeNet, points, normals, rng: np.random.Generator, options=EdgeOptions(),
                    table_z_m=TABLE_HEIGHT_M) -> list:
    """A down-sampled cloud (points, normals: (N, 3), task frame) -> VNEdgeGrasps, best
    first."""
    points, normals = torch.as_tensor(points, dtype=torch.float32), torch.as_tensor(normals, dtype=torch.float32)
    edges = sample_edges(points, normals, farthest_points(points, options.apexes, int(rng.integers(len(points)))),
                         options)
    kept = torch.nonzero(kept_edges(edges, options))[:, 0]
    if len(kept) < options.min_edges:
        return []
    poses = edge_poses(points[edges.apexes[edges.ball[kept]]], edges.normals[kept], edges.approach[kept],
                       edges.depth[kept])
    clear = above_table(poses, table_z_m)
    kept, poses = kept[clear], poses[clear]
    if len(kept) == 0:
        return []
    if len(kept) > options.max_edges:
        generator = torch.Generator().manual_seed(int(rng.integers(2 ** 63)))
        pick = torch.sort(torch.randperm(len(kept), generator=generator)[:options.max_edges]).values
        kept, poses = kept[pick], poses[pick]
    probability = torch.sigmoid(score_edges(net, edges, kept)).numpy()
    contacts = points[edges.member[kept]].numpy().astype(np.float64)
    grasps = []
    for i in np.argsort(-probability, kind="stable")[:options.max_grasps]:
        p = float(probability[i])
        grasps.append(VNEdgeGrasp(pose=to_tcp(poses[i].numpy()), score_n=float("nan"), validness=p, rank_key=p,
                                  voxel_index=(), contact_m=contacts[i]))
    return grasps


def make_vn_edge_detector(net: VNEdgeNet, options=EdgeOptions()):
    """The benchmark's detect callable: (grid, voxel_size_m, origin) -> ranked VNEdgeGrasps."""

    def detect(tsdf):
        grid, voxel_size_m, origin = tsdf
        rng = np.random.default_rng(options.seed)
        origin = np.asarray(origin, dtype=np.float64)
        size_m = np.asarray(grid).shape[0] * voxel_size_m
        bounds = tuple(b + origin for b in workspace_bounds(size_m, TABLE_HEIGHT_M - origin[2], options.cloud))
        cloud = edge_point_cloud(surface_points(grid, voxel_size_m, origin), rng, bounds, options.cloud)
        if cloud is None:
            return []
        grasps = detect_on_cloud(net, *cloud, rng, options)
        for g in grasps:
            g.voxel_index = tuple(int(i) for i in np.floor((g.pose[:3, 3] - origin) / voxel_size_m))
        return grasps
    return detect


# the benchmark's method (methods.METHODS["vn_edge"])


def clearing_grasps(grasps, tsdf, max_grasps: int) -> list:
    """The first max_grasps of `grasps` (best first) whose open Panda hand, swept from the
    pre-grasp, holds no occupied voxel of `tsdf` (the executor's own check): checked 64
    at a time, as the authors' edges run to 1500."""
    grid, voxel_size_m, origin = tsdf
    points = hand_clearance.occupied_points(np.asarray(grid), voxel_size_m, np.asarray(origin))
    cleared = []
    for start in range(0, len(grasps), 64):
        batch = grasps[start:start + 64]
        hit = hand_clearance.hands_collide(np.array([g.pose for g in batch]), points, voxel_size_m,
                                           ExecutionLimits.pregrasp_distance_m, HAND_GEOMETRY["panda"])
        cleared += [g for g, h in zip(batch, hit) if not h]
        if len(cleared) >= max_grasps:
            break
    return cleared[:max_grasps]


def make_detector(path, protocol) -> Detector:
    """VN-EdgeGraspNet with the checkpoints at `path` (MODEL_FILE, the others beside it)
    as the benchmark's Detector, reading edge_volume(), under the protocol's max_grasps
    and, when on, its clear_hand (clearing_grasps). Its score is a success probability:
    target "binary"."""
    net = load_vn_edge(path)
    if not protocol.clear_hand:
        return Detector(make_vn_edge_detector(net, EdgeOptions(max_grasps=protocol.max_grasps)), edge_volume(),
                        "binary")
    detect_all = make_vn_edge_detector(net)
    return Detector(lambda tsdf: clearing_grasps(detect_all(tsdf), tsdf, protocol.max_grasps), edge_volume(),
                    "binary")
