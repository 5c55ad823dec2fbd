"""JoinFruitFragments on synthetic depth images: a fruit cut by a thin
occluder in front is one instance again; fruit pieces apart by a gap, a
depth jump, more than one fruit's size, or specks are not joined."""
import numpy as np

from lmap_drake.labels import BRANCH, FRUIT, LEAF
from lmap_drake.perception.fruit_fragments import DropFruitSpecks, JoinFruitFragments
from lmap_drake.perception.points import Intrinsics
from lmap_drake.perception.config import PerceptionConfig
from lmap_drake.perception.segmentation import InstancesFromComponents, MakeSegmenter
from perception_scenes import Render

K = Intrinsics(320, 240, 228.0, 228.0, 160.0, 120.0)
V, U = np.mgrid[0:240, 0:320]


def Sphere(depth, cls, u0, v0, z0, r, cid=FRUIT):
    """Paints the camera-facing half of a sphere (centre depth z0, radius r
    m) at pixel (u0, v0) into ``depth`` / ``cls`` where it is nearer."""
    x = (U - u0) * z0 / K.fx
    y = (V - v0) * z0 / K.fy
    h2 = r * r - x * x - y * y
    z = np.where(h2 > 0, z0 - np.sqrt(np.maximum(h2, 0)), np.inf)
    near = z < depth
    depth[near], cls[near] = z[near], cid


def Scene():
    depth = np.full((240, 320), np.inf)
    cls = np.zeros((240, 320), np.int64)
    Sphere(depth, cls, 160, 120, 0.55, 0.035)
    return depth, cls


def FruitInstances(cls, depth):
    inst = JoinFruitFragments(cls, InstancesFromComponents(cls, depth, 0.02), depth, K, 0.02)
    return sorted(np.unique(inst[cls == FRUIT]).tolist()), inst


def test_a_fruit_cut_by_a_stem_in_front_is_one_instance():
    depth, cls = Scene()
    strip = (np.abs(U - 160) <= 2) & (cls == FRUIT)
    depth[strip], cls[strip] = 0.48, BRANCH           # a 5 px (1.2 cm) stem in front
    assert len(np.unique(InstancesFromComponents(cls, depth, 0.02)[cls == FRUIT])) == 2
    ids, inst = FruitInstances(cls, depth)
    assert ids == [0]
    before = InstancesFromComponents(cls, depth, 0.02)
    assert np.array_equal(inst[cls != FRUIT], before[cls != FRUIT])   # other classes as they were
    # pixels the network called leaf on the fruit's own surface: the same
    depth, cls = Scene()
    cls[strip] = LEAF
    assert FruitInstances(cls, depth)[0] == [0]


def test_pieces_apart_by_a_gap_a_jump_a_size_or_specks_stay_apart():
    # background (no return) between the pieces: two fruits, not one
    depth, cls = Scene()
    strip = (np.abs(U - 160) <= 2) & (cls == FRUIT)
    depth[strip], cls[strip] = np.inf, 0
    assert FruitInstances(cls, depth)[0] == [0, 1]
    # a leaf behind the pieces shows through: a gap, not an occluder
    depth[strip], cls[strip] = 0.62, LEAF
    assert FruitInstances(cls, depth)[0] == [0, 1]
    # the pieces' facing borders 3 cm apart in depth: two surfaces
    depth, cls = Scene()
    left = (cls == FRUIT) & (U < 158)
    depth[left] += 0.03
    strip = (np.abs(U - 160) <= 2) & (cls == FRUIT)
    depth[strip], cls[strip] = 0.48, BRANCH
    assert FruitInstances(cls, depth)[0] == [0, 1]
    # two large fruits side by side behind one stem: more than one fruit's size
    depth = np.full((240, 320), np.inf)
    cls = np.zeros((240, 320), np.int64)
    Sphere(depth, cls, 125, 120, 0.55, 0.045)
    Sphere(depth, cls, 195, 120, 0.55, 0.045)
    stem = (np.abs(U - 160) <= 2) & (cls == FRUIT)
    depth[stem], cls[stem] = 0.48, BRANCH
    assert len(FruitInstances(cls, depth)[0]) == 2
    # a speck beside the fruit behind a stem is no piece of it
    depth, cls = Scene()
    speck = (np.abs(U - 178) <= 1) & (np.abs(V - 120) <= 1)       # 9 px at the fruit's depth
    depth[speck], cls[speck] = 0.55, FRUIT
    stem = (np.abs(U - 175) <= 1) & (np.abs(V - 120) <= 6)
    depth[stem], cls[stem] = 0.48, BRANCH
    assert len(FruitInstances(cls, depth)[0]) == 2


def test_the_small_render_seen_by_the_two_worlds_weights_has_one_fruit():
    """The view of ``perception_scenes.Render``: the stem and a leaf's rim
    cross the fruit; ``segnet_two_worlds.pt`` calls the pixels where they
    meet leaf or branch, which cuts the fruit's pixels in two (84 + 64)."""
    view = Render()
    cfg = PerceptionConfig(segnet_weights="models/segnet/segnet_two_worlds.pt")
    seg = MakeSegmenter(cfg, view.K).Segment(view.rgb, view.depth)
    pieces = InstancesFromComponents(seg.class_map, np.asarray(view.depth, float), 0.02)
    fruit = seg.class_map == FRUIT
    assert len(np.unique(pieces[fruit])) == 2
    big = [(n, conf) for c, i, n, conf in seg.Instances() if c == FRUIT and n >= 100]
    assert len(big) == 1 and big[0][0] == fruit.sum() and big[0][1] > 0.8


def test_fruit_specks_become_their_next_most_probable_class():
    """A fruit instance under ``min_pixels`` farther than ``reach`` from a
    larger one takes, pixel by pixel, the most probable class other than
    fruit; one as small but near a larger fruit (a piece of it beyond a
    leaf) and the larger one stay fruit."""
    cls = np.full((100, 100), LEAF, np.int64)
    inst = np.full((100, 100), -1, np.int64)
    cls[2:10, 2:10], inst[2:10, 2:10] = FRUIT, 0        # 64 pixels
    cls[12:14, 2:5], inst[12:14, 2:5] = FRUIT, 1        # 6 pixels, 3 px (3 mm) below it
    cls[90:92, 90:93], inst[90:92, 90:93] = FRUIT, 2    # 6 pixels, 11 cm away
    depth = np.full((100, 100), 0.6)
    fx = 600.0                                           # 1 mm per pixel at 0.6 m
    prob = np.zeros((4, 100, 100))                       # background, branch, leaf, fruit
    prob[FRUIT] = 0.6
    prob[LEAF], prob[BRANCH] = 0.3, 0.1
    prob[BRANCH, 90, 90:93] = 0.35                       # its first row: more branch than leaf
    before = cls.copy()
    assert DropFruitSpecks(cls, inst, prob, 20, depth, fx, reach=0.08)
    assert (cls[2:10, 2:10] == FRUIT).all() and (cls[12:14, 2:5] == FRUIT).all()
    assert (cls[90, 90:93] == BRANCH).all() and (cls[91, 90:93] == LEAF).all()
    assert (cls != before).sum() == 6
    assert not DropFruitSpecks(cls, inst, prob, 20, depth, fx, reach=0.08)   # none left
    assert not DropFruitSpecks(before.copy(), inst, prob, 6, depth, fx, reach=0.08)  # 6 is not < 6
    # seen from twice as far the speck lies 23 cm from the fruit (11 cm at 0.6 m)
    far = before.copy()
    assert DropFruitSpecks(far, inst, prob, 20, 2 * depth, fx, reach=0.15)
    assert (far[90:92, 90:93] != FRUIT).all()
