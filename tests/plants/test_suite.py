"""Every scenario of diagrams/suite.yaml loads, builds (FEM leaf included),
renders, and shows its fruit partly hidden by its leaf."""
import pytest
import yaml

from lmap_drake.labels import FRUIT, LEAF, DecodeLabels
from lmap_drake.paths import DIAGRAMS_DIR
from lmap_drake.scenario import LoadScenario
from lmap_drake.plants.plant_station import MakePlantStation

SUITE = DIAGRAMS_DIR / "suite.yaml"
NAMES = list(yaml.safe_load(SUITE.read_text()))


def test_twelve_scenarios():
    assert len(NAMES) == 12


@pytest.mark.parametrize("name", NAMES)
def test_scenario_builds_and_renders(name):
    s = LoadScenario(filename=SUITE, scenario_name=name)
    station = MakePlantStation(s)
    ctx = station.CreateDefaultContext()
    cls, _ = DecodeLabels(station.GetOutputPort("camera0.label_image").Eval(ctx).data)
    assert (cls == FRUIT).sum() > 50 and (cls == LEAF).sum() > 500


# --- RandomSuite with the episodes' overrides (lmap-drake eval --scenarios N
# --scenario_text ...) -------------------------------------------------------

def _big_pepper_file(tmp_path):
    import trimesh
    f = tmp_path / "big.stl"     # 9 x 9 x 10 cm, about 420 cm^3: larger than any drawn pepper
    m = trimesh.creation.icosphere(3, 0.045)
    m.apply_scale([1.0, 1.0, 10.0 / 9.0])
    m.export(f)
    return f


def test_random_suite_draws_are_checked_with_the_overrides(tmp_path):
    from lmap_drake.plants.suite import RandomSuite, _WhyNotBuildable
    text = "{plant_scene: {fruit: {mesh_file: %s}}}" % _big_pepper_file(tmp_path)
    plain = RandomSuite(4, seed=2)
    refused = [n for n, cfg in plain.items() if _WhyNotBuildable(cfg, text)]
    assert refused, "seed 2 no longer draws a scene the big pepper cannot be hidden in"
    checked = RandomSuite(4, seed=2, scenario_text=text)
    assert list(checked) == list(plain)          # same names, same count
    assert not any(_WhyNotBuildable(cfg, text) for cfg in checked.values())
    assert [c.leaf.length for c in checked.values()] != [c.leaf.length for c in plain.values()]
    # deterministic, and without overrides the suite is what it was
    again = RandomSuite(4, seed=2, scenario_text=text)
    assert [c.leaf.length for c in again.values()] == [c.leaf.length for c in checked.values()]
    assert [c.leaf.length for c in RandomSuite(4, seed=2, scenario_text="{}").values()] == \
        [c.leaf.length for c in plain.values()]


def test_random_suite_that_cannot_be_built_says_why():
    from lmap_drake.errors import InputError
    from lmap_drake.plants.suite import RandomSuite, SuiteError
    text = "{plant_scene: {occlusion: 0.99, leaf: {length: 0.06, width: 0.03}}}"
    with pytest.raises(SuiteError, match=r"no buildable scene in 3 draws with the overrides "
                                         r"\{plant_scene.*the last: .*occlusion") as err:
        RandomSuite(2, seed=1, max_draws=3, scenario_text=text)
    assert isinstance(err.value, InputError)


def test_random_suite_reports_each_scene_drawn():
    from lmap_drake.plants.suite import RandomSuite
    calls = []
    suite = RandomSuite(2, seed=1, on_scene=lambda: calls.append(len(calls)))
    assert len(calls) == 2 == len(suite)


def _egg_files(folder):
    """Two small test fruits (OBJ, one with a stalk mesh) in ``folder``."""
    import trimesh
    for name, r in (("egg", 0.02), ("plum", 0.023)):
        m = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
        m.apply_scale([r, r, 1.25 * r])
        m.export(folder / f"{name}.obj")
    trimesh.creation.cylinder(radius=0.003, segment=[[0, 0, 0.022], [0, 0.01, 0.05]]).export(
        folder / "egg.peduncle.stl")
    return folder


def test_random_suites_draw_their_peppers_from_a_folder_of_meshes(tmp_path):
    """``fruit_meshes``: each random scene's pepper (every fruit of a random
    multi-fruit plant) is one of the files, stalk included, and the scenes
    still build; without files a seed gives the procedural suite as before."""
    from lmap_drake.plants.fruit_mesh import FruitMeshFolder
    from lmap_drake.plants.suite import RandomMultiSuite, RandomSuite, _WhyNotBuildable
    files = FruitMeshFolder(_egg_files(tmp_path))
    assert [(f.name, getattr(p, "name", p)) for f, p in files.values()] == \
        [("egg.obj", "egg.peduncle.stl"), ("plum.obj", "")]
    pairs = {(str(f), str(p)) for f, p in files.values()}
    single = RandomSuite(3, seed=4, fruit_meshes=files.values())
    assert {(c.fruit.mesh_file, c.fruit.peduncle_file) for c in single.values()} <= pairs
    assert not any(_WhyNotBuildable(c) for c in single.values())
    assert all(c.fruit.mesh_file == "" for c in RandomSuite(3, seed=4).values())
    multi = RandomMultiSuite(1, seed=4, fruit_meshes=files.values())
    (plant,) = multi.values()
    assert {(f.fruit.mesh_file, f.fruit.peduncle_file) for f in plant.multi.fruits} <= pairs
    assert len(plant.multi.fruits) >= 2 and not _WhyNotBuildable(plant)


def test_make_suite_takes_a_mesh_folder_only_with_random_and_checks_it_first(tmp_path):
    import subprocess
    import sys
    from lmap_drake.paths import REPO_ROOT
    script = str(REPO_ROOT / "scripts" / "make_suite.py")

    def run(*args):
        return subprocess.run([sys.executable, script, *args], capture_output=True, text=True,
                              cwd=tmp_path)
    d = _egg_files(tmp_path)
    r = run("--multi", "--fruit_mesh_dir", str(d), "--out", "x.yaml")
    assert r.returncode == 2 and "--fruit_mesh_dir needs --random N" in r.stderr
    (d / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    r = run("--random", "2", "--fruit_mesh_dir", str(d), "--out", "x.yaml")
    assert r.returncode == 2 and "flat.obj" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "x.yaml").exists()
