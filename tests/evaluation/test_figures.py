"""Shape-completion pictures: the two views of a case and the case figure."""
import numpy as np
from PIL import Image


def test_shape_views_look_along_the_ray_with_up_and_right_as_the_camera_sees_them():
    """A camera at the origin looking at a fruit 0.6 m along +y, slightly
    below: the ray points at the fruit, up is world +z made orthogonal to
    it, right is +x (looking north, east is on the right)."""
    from lmap_drake.evaluation.figures import ShapeViewAxes
    X_WC = np.eye(4)
    ray, up, right = ShapeViewAxes(X_WC, [0.0, 0.6, -0.1])
    np.testing.assert_allclose(ray, np.array([0, 0.6, -0.1]) / np.hypot(0.6, 0.1))
    assert abs(ray @ up) < 1e-12 and up[2] > 0.98 and up[0] == 0
    np.testing.assert_allclose(right, [1, 0, 0], atol=1e-12)


def test_shape_case_figure_draws_the_truth_and_each_estimate(tmp_path):
    """``ShapeCaseFigure`` writes a PNG from a case's points, the true mesh and
    per-method estimates (one missing), with their metrics in the legend."""
    import trimesh
    from lmap_drake.evaluation.figures import ShapeCaseFigure
    from lmap_drake.types import FruitEstimate, SemanticScene
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.035)
    c = np.array([0.0, 0.6, 0.0])
    gt = np.asarray(ball.vertices) + c
    front = gt[gt[:, 1] < 0.59]
    est = FruitEstimate(vertices_W=gt * 1.1 - 0.1 * c, faces=np.asarray(ball.faces),
                        X_WO=np.eye(4), latent=np.zeros(3), center_W=c,
                        peduncle_axis_W=np.array([0.0, 0.0, 1.0]))
    sem = SemanticScene(fruit_points_W=front, leaf_points_W=front + [0, -0.05, 0.03],
                        X_WC=np.eye(4))
    m = {"chamfer_cm": 0.3, "volume_err_cm3": 12.0, "center_err_cm": 0.2, "angle_err_deg": 4.0}
    path = tmp_path / "case.png"
    ShapeCaseFigure(sem, gt, c, {"ssc": est, "homa": None}, {"ssc": m}, path, title="a ball")
    im = np.asarray(Image.open(path).convert("RGB"))
    assert im.shape[0] > 400 and im.shape[1] > 800
    red = (im[..., 0] > 180) & (im[..., 1] < 80) & (im[..., 2] < 80)   # the SSC outline
    assert red.sum() > 200
