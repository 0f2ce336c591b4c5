"""A model file made in a test: a random network whose grasps a round can execute."""
import torch

from gravgrasp_detector.perception import model_file, networks, tsdf


def save_test_model(path, validness_bias=5.0, target="gravity-score"):
    """Random init, made to propose top-down grasps (closing along task y) at every
    near-surface voxel, so a round executes real attempts."""
    torch.manual_seed(0)
    m = networks.GraspNet(score_scale_n=10.0)
    with torch.no_grad():
        m.head_score_validness.bias[1] = validness_bias
        m.head_rotation.weight.mul_(1e-3)
        m.head_rotation.bias.copy_(torch.tensor([1.0, 0, 0, 0, 0, -1.0]))
    model_file.save_model(path, m, tsdf.TSDFVolume(resolution=40), training_data={"target": target})
    return path
