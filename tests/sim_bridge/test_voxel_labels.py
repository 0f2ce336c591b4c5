import numpy as np

from sim_bridge.datagen.voxel_labels import dense_labels, voxel_labels


def pose(p, R=np.eye(3)):
    X = np.eye(4)
    X[:3, :3] = R
    X[:3, 3] = p
    return X


def test_tcp_voxel_index_and_best_grasp_per_voxel():
    R = np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]], float)  # e_x=(0,0,1), e_z=(0,1,0)
    X = np.stack([
        pose([0.151, 0.0, 0.2999]),   # voxel (20, 0, 39), score 3
        pose([0.1549, 0.0074, 0.295], R),  # same voxel, score 7: wins
        pose([0.31, 0.1, 0.1]),       # outside the cube: ignored
        pose([0.02, 0.02, 0.02]),     # voxel (2, 2, 2), NaN score: ignored
        pose([0.0, 0.0, 0.0]),        # voxel (0, 0, 0)
    ])
    labels = voxel_labels(X, [3.0, 7.0, 9.0, np.nan, 1.5])
    assert labels["index"].tolist() == [[0, 0, 0], [20, 0, 39]]
    np.testing.assert_allclose(labels["score"], [1.5, 7.0])
    assert labels["grasp"].tolist() == [4, 1]
    np.testing.assert_allclose(labels["e_x"][1], [0, 0, 1])
    np.testing.assert_allclose(labels["e_z"][1], [0, 1, 0])
    score, valid, e_x, e_z = dense_labels(labels)
    assert valid.sum() == 2 and valid[20, 0, 39] == 1 and score[20, 0, 39] == 7.0
    np.testing.assert_allclose(e_z[:, 20, 0, 39], [0, 1, 0])


def test_no_grasps_gives_empty_labels():
    labels = voxel_labels(np.zeros((0, 4, 4)), [])
    assert labels["index"].shape == (0, 3) and labels["score"].shape == (0,)
