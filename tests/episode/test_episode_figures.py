"""Episode pictures: the segmentation overlay shows the segmenter's classes
in colours that stand out from the plant's own."""
import numpy as np
from PIL import Image

from lmap_drake.episode.figures import OVERLAY_COLORS, Overlay
from lmap_drake.labels import BACKGROUND, BRANCH, FRUIT, LEAF


def test_overlay_tints_each_class_in_a_contrasting_colour_with_outlines():
    rgb = np.zeros((160, 200, 4), np.uint8)   # the legend sits in the top-left corner
    rgb[..., 1] = 140                       # a green scene: leaf and green fruit alike
    cls = np.full((160, 200), BACKGROUND)
    cls[110:130, 110:140] = LEAF
    cls[130:150, 120:140] = FRUIT
    cls[:, 160:164] = BRANCH
    out = Overlay(rgb, cls, title="segmenter: test").astype(int)
    assert out.shape == (160, 200, 3)
    # outlines carry the class colour exactly
    assert tuple(out[130, 130]) == OVERLAY_COLORS[FRUIT]
    assert tuple(out[120, 139]) == OVERLAY_COLORS[LEAF]
    # interiors differ clearly between leaf and fruit although the image is one green
    assert np.abs(out[140, 130] - out[120, 125]).sum() > 150
    # background stays close to the (desaturated) image
    assert np.abs(out[155, 190] - np.array([23, 93, 23])).max() <= 2


def test_each_target_gets_its_prediction_beside_the_view_taken_while_held(tmp_path):
    """Several fruits: plan_target<n>.png puts the predicted leaf (green) on
    the view the plan was made in and on the view taken while held; a target
    without an action gets no picture."""
    from types import SimpleNamespace

    from lmap_drake.deformation.action import Action
    from lmap_drake.episode.figures import SaveTargetPlanFigures
    from lmap_drake.perception.points import Intrinsics, ProjectPoints
    from lmap_drake.planning.result import Candidate
    from lmap_drake.scenario import LoadDefaultScenario
    scenario = LoadDefaultScenario()
    cam = scenario.cameras["camera0"]
    K = Intrinsics.FromCameraConfig(cam)
    X_WC = cam.X_PB.GetDeterministicValue().GetAsMatrix4()
    # a predicted leaf: a 6 x 6 cm patch 0.6 m in front of the camera
    p_WO = X_WC[:3, 3] + 0.6 * X_WC[:3, 2]
    g = np.linspace(-0.03, 0.03, 40)
    patch = p_WO + g[:, None, None] * X_WC[:3, 0] + g[None, :, None] * X_WC[:3, 1]
    patch = patch.reshape(-1, 3)
    action = Action(p_WO, np.eye(3), dp_W=np.array([0.0, 0.0, 0.04]), grasp_id=3,
                    direction_id=1)
    chosen = Candidate(action, 0, energy=1e-5, num_leaf_nodes=10, seen=80,
                       deformed_leaf_W=patch)
    plan = SimpleNamespace(status="ok", method="lmap", chosen=chosen, seen_init=20,
                           seen_max=100, message="")
    views = [SimpleNamespace(rgb=np.full((cam.height, cam.width, 4), 255, np.uint8))
             for _ in range(3)]
    targets = [{"plan": plan, "view_plan": 0, "view_after": 1, "initial_estimate": None,
                "target": {"fruit_id": 2}},
               {"plan": None, "view_plan": 2, "view_after": None, "target": {"fruit_id": 0}}]
    result = SimpleNamespace(views=views, status=SimpleNamespace(targets=targets),
                             world=SimpleNamespace(scenario=scenario))
    assert SaveTargetPlanFigures(result, tmp_path) == ["plan_target0.png"]
    img = np.asarray(Image.open(tmp_path / "plan_target0.png").convert("RGB")).astype(int)
    assert img.shape == (cam.height, 2 * cam.width, 3)
    u, v = np.round(ProjectPoints(p_WO[None], K, X_WC)[0]).astype(int)
    green = lambda px: px[1] > 200 and px[0] < 120 and px[2] < 120
    near = lambda x0: [img[v + dv, x0 + u + du] for dv in range(-4, 5) for du in range(-4, 5)]
    assert any(green(px) for px in near(0))              # on the planning view
    assert any(green(px) for px in near(cam.width))      # and on the held view
    assert tuple(img[cam.height - 10, cam.width + 600]) == (255, 255, 255)   # untouched elsewhere


def test_plant_figure_labels_each_fruit_once_with_every_reveal_and_apart():
    """A fruit revealed twice (its estimate's centre moved 1 cm between
    views) gets one label naming both leaves in order; two fruits at the
    same height 4 cm apart get labels at least the minimum gap apart; a
    fruit far to the side keeps its label 5 cm above it."""
    from lmap_drake.episode.figures import PlantFigureLabels
    targets = [{"center_W": [0.5, 0.0, 0.30], "leaf_id": 2, "what": "twist 60 deg"},
               {"center_W": [0.5, 0.04, 0.30], "leaf_id": 1, "what": "no_feasible_action"},
               {"center_W": [0.51, 0.0, 0.30], "leaf_id": 0, "what": "arc 30 deg (4.0 cm)"},
               {"center_W": [0.5, 0.4, 0.30], "leaf_id": 3, "what": "pull 4 cm"}]
    labels = PlantFigureLabels(targets, min_gap_m=0.045)
    assert [lab["text"] for lab in labels] == [
        "fruit 0: leaf 2: twist 60 deg; then leaf 0: arc 30 deg (4.0 cm)",
        "fruit 1: leaf 1: no_feasible_action",
        "fruit 2: leaf 3: pull 4 cm"]
    a = [lab["anchor_W"] for lab in labels]
    assert abs(a[1][2] - a[0][2]) >= 0.045 - 1e-9
    np.testing.assert_allclose(a[0], [0.5, 0.0, 0.35])
    np.testing.assert_allclose(a[2], [0.5, 0.4, 0.35])


def test_the_force_guards_reading_is_drawn_with_its_limits_and_stops(tmp_path):
    from lmap_drake.episode.figures import SaveForceFigure
    trace = ([(3.0 + 0.02 * k, 0.1 * k, "pull") for k in range(60)]
             + [(9.0 + 0.02 * k, 0.01 * k, "retreat") for k in range(30)])
    path = tmp_path / "wrist_force.png"
    assert SaveForceFigure(trace, 8.0, 3.0, [{"t": 4.18, "rise_N": 5.9, "motion": 1}], path)
    img = np.asarray(Image.open(path).convert("RGB")).astype(int)
    assert img.shape[0] > 200 and img.shape[1] > 500
    # the pull line (matplotlib's blue), the retreat's (orange) and the stop (red) are drawn
    for rgb in ((31, 119, 180), (255, 127, 14), (255, 0, 0)):
        assert (np.abs(img - rgb).sum(axis=-1) < 30).sum() > 20, rgb
    assert not SaveForceFigure([], 8.0, 3.0, [], tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()
