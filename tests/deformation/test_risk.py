"""deformation.risk: local stretch of the graph (rigid motion = 1, uniform
stretch recovered) and the attachment stretch of predicted pulls."""
import numpy as np
from scipy.spatial.transform import Rotation

from lmap_drake.deformation import Action, PredictDeformations
from lmap_drake.deformation.risk import AttachmentStretch, LocalStretch
from leaf_fixtures import R_TIP, TEST_CONFIG


def _plate():
    g = np.arange(0.0, 0.05, 0.005)
    u, v = np.meshgrid(g, g)
    return np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]


def test_local_stretch_is_one_for_rigid_motion_and_finds_a_uniform_stretch():
    rest = _plate()
    centres = np.arange(len(rest))
    R = Rotation.from_euler("xyz", [30, -20, 50], degrees=True).as_matrix()
    rigid = rest @ R.T + [0.1, -0.2, 0.3]
    np.testing.assert_allclose(LocalStretch(rest, rigid, centres, 0.012), 1.0, atol=1e-9)
    stretched = (rest * [1.1, 1.0, 1.0]) @ R.T
    np.testing.assert_allclose(LocalStretch(rest, stretched, centres, 0.012), 1.1, atol=1e-9)
    lonely = np.vstack([rest, [1.0, 1.0, 1.0]])
    s = LocalStretch(lonely, lonely, np.array([len(rest)]), 0.012)
    assert np.isnan(s).all()


def test_attachment_stretch_grows_with_the_pull_away_from_the_branch(plant):
    leaf, branch = plant
    p = leaf[np.argmax(leaf[:, 0] - 5 * np.abs(leaf[:, 1]))] - [0.01, 0, 0]
    # Tip grasp; the branch is the z axis at the origin: +x pulls away from it.
    acts = [Action(p, R_TIP, [d, 0.0, 0.0]) for d in (0.0, 0.01, 0.02, 0.04)]
    preds = PredictDeformations(leaf, branch, acts, TEST_CONFIG, dense=False)
    s = [AttachmentStretch(q.nodes_W, q.node_kind, q.deformed_nodes_W) for q in preds]
    assert abs(s[0] - 1.0) < 1e-6
    assert s[1] > 1.0 + 1e-4 and s[1] < s[2] < s[3]
