"""A ``kind: multi`` plant in the simulated station: it builds, renders with
per-instance labels, every leaf is its own FEM body with readable vertices,
and the collision filters leave leaves colliding with what they should."""
import numpy as np
import pytest

from lmap_drake.labels import BRANCH, FRUIT, LEAF, ROBOT, DecodeLabels
from lmap_drake.plants.multi_geometry import LeafLeafPenetration
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.scenario import LoadScenario


@pytest.fixture(scope="module")
def world():
    scenario = LoadScenario(scenario_text="{plant_scene: {kind: multi}}")
    return PlantWorldSim(scenario)


def test_render_has_every_instance_label(world):
    label = np.asarray(world.Images()["label_image"].data)[..., 0]
    cls, inst = DecodeLabels(label)
    m = world.model
    for i in range(len(m.fruits)):
        assert ((cls == FRUIT) & (inst == i)).sum() > 50, f"fruit {i} not in the image"
    for j in range(len(m.leaves)):
        assert ((cls == LEAF) & (inst == j)).sum() > 500, f"leaf {j} not in the image"
    for b in range(len(m.branches)):
        assert ((cls == BRANCH) & (inst == b)).sum() > 20, f"branch {b} not in the image"
    assert not ((cls == FRUIT) & (inst >= len(m.fruits))).any()
    assert (cls == ROBOT).any()


def test_leaves_hang_still_and_apart(world):
    w = world.Fork()
    m = w.model
    assert w.num_leaves == len(m.leaves)
    for j, leaf in enumerate(m.leaves):
        np.testing.assert_allclose(w.LeafVertices(j), leaf.rest_W, atol=1e-9)
    w.Hold(0.3)
    Vs = [w.LeafVertices(j) for j in range(w.num_leaves)]
    for V, leaf in zip(Vs, m.leaves):
        assert np.linalg.norm(V - leaf.rest_W, axis=1).max() < 0.01      # sag under gravity
        np.testing.assert_allclose(V[leaf.fixed], leaf.rest_W[leaf.fixed], atol=2e-4)
    assert LeafLeafPenetration(Vs, [x.tets for x in m.leaves]).max() == 0.0
    s = w.samples[-1]
    assert s.fruit_penetration < 1e-3 and s.petiole_force < 1.0
    # Visibility per fruit in the rendered image follows the requested occlusion.
    vis = [w.Visibility(fruit=i) for i in range(len(m.fruits))]
    occ = [f.occlusion_predicted for f in m.fruits]
    assert np.argmax(vis) == np.argmin(occ) and vis[int(np.argmax(occ))] < 0.4


def test_collision_filters(world):
    """Leaves collide with fruits, the gripper and the branches they do not
    sit on; not with their own shoot; not with each other (the default)."""
    sg = world.scene_graph
    inspector = sg.model_inspector()
    from pydrake.geometry import Role
    ids = {inspector.GetName(g).split("::")[-1]: g
           for g in inspector.GetAllGeometryIds(Role.kProximity)}
    leaf = [world.deformable.GetGeometryId(b) for b in world.leaf_ids]
    m = world.model
    j = next(k for k, x in enumerate(m.leaves) if x.fruit >= 0)
    own = m.leaves[j].shoot
    pads = [g for n, g in ids.items() if "pad" in n.lower() or "finger" in n.lower()]
    assert pads
    filtered = inspector.CollisionFiltered
    assert not any(filtered(leaf[j], ids[f"fruit_{i}_collision"]) for i in range(len(m.fruits)))
    assert not any(filtered(leaf[j], g) for g in pads)
    assert filtered(leaf[j], ids[f"{m.branches[own].name}_0_collision"])
    assert not filtered(leaf[j], ids["stem_0_collision"])
    assert filtered(leaf[0], leaf[1])


def test_visibility_over_several_views_is_the_union_of_their_fruit_pixels(world):
    """Two views that each show one half of a fruit's pixels show all of
    them together; one view alone is its own visibility."""
    from lmap_drake.labels import EncodeLabel
    label = np.asarray(world.Images()["label_image"].data)[..., 0].copy()
    i = 0
    mine = label == EncodeLabel(FRUIT, i)
    cols = np.flatnonzero(mine.any(axis=0))
    half = cols[len(cols) // 2]
    left, right = label.copy(), label.copy()
    bg = EncodeLabel(LEAF, 0)            # hidden behind a leaf in that view
    left[:, half:][mine[:, half:]] = bg
    right[:, :half][mine[:, :half]] = bg
    full = world.Visibility(label, fruit=i)
    assert full > 0.05
    assert world.VisibilityUnion([label], fruit=i) == pytest.approx(full)
    assert world.Visibility(left, fruit=i) < full and world.Visibility(right, fruit=i) < full
    assert world.VisibilityUnion([left, right], fruit=i) == pytest.approx(full)
    assert world.VisibilityUnion([left], fruit=i) == pytest.approx(world.Visibility(left, fruit=i))


def test_fem_threads_do_not_change_the_leaves():
    """Two FEM threads give the leaves bit for bit what one gives (every
    leaf awake, 0.2 s of settling)."""
    from lmap_drake.plants.plant_sim import SetFemThreads
    out = []
    for n in (1, 2):
        scenario = LoadScenario(scenario_text="{plant_scene: {kind: multi, sleep_distance: 0.0, "
                                f"fem_threads: {n}}}}}")
        w = PlantWorldSim(scenario)
        assert w.deformable._parallelism().num_threads() == n
        w.Hold(0.2)
        out.append(np.vstack([w.LeafVertices(j) for j in range(w.num_leaves)]))
    assert np.abs(out[0] - np.vstack([lf.rest_W for lf in w.model.leaves])).max() > 1e-5
    np.testing.assert_array_equal(out[0], out[1])
    assert SetFemThreads(w.plant, 1) == 1
