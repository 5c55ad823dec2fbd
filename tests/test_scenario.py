import pytest

from lmap_drake.paths import DEFAULT_SCENARIO_FILE
from lmap_drake.scenario import DumpScenario, LoadScenario, Scenario, ScenarioError


@pytest.mark.parametrize("name", ["Defaults", "OneOfEverything"])
def test_named_scenarios_load(name):
    s = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name=name)
    assert isinstance(s, Scenario)
    assert "camera0" in s.cameras


def test_one_of_everything_differs_from_defaults():
    d = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults")
    o = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="OneOfEverything")
    assert o.random_seed == 7 and d.random_seed == 0
    assert o.cameras["camera0"].width == 320 and d.cameras["camera0"].width == 640
    assert o.robot.kp != d.robot.kp
    assert o.perception.segmenter == "color_depth"
    assert o.planner.distances == [0.02, 0.04]
    assert d.perception.segmenter == "segnet" and d.camera_noise.enabled and not d.lights
    assert o.camera_noise.depth_unit == 0.001 and o.lights[0].intensity == 0.8


def test_camera_noise_is_validated():
    with pytest.raises(ScenarioError, match=r"camera_noise\.thin_dropout"):
        LoadScenario(scenario_text="{camera_noise: {thin_dropout: 1.5}}")
    with pytest.raises(ScenarioError, match=r"camera_noise\.grazing_start_deg"):
        LoadScenario(scenario_text="{camera_noise: {grazing_start_deg: 88.0}}")


def test_unknown_key_names_key_and_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("Mine:\n  robot:\n    initial_qq: [0, 0, 0, 0, 0, 0]\n")
    with pytest.raises(ScenarioError) as err:
        LoadScenario(filename=bad, scenario_name="Mine")
    assert "Mine.robot.initial_qq" in str(err.value)
    assert str(bad) in str(err.value)


def test_unknown_key_in_override_text():
    with pytest.raises(ScenarioError, match=r"cameras\.camera0\.fx"):
        LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_text="{cameras: {camera0: {fx: 1}}}")


def test_override_text_applies_last():
    s = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="OneOfEverything",
                     scenario_text="{random_seed: 11, robot: {gripper_kp: 123.0}}")
    assert s.random_seed == 11 and s.robot.gripper_kp == 123.0
    assert s.cameras["camera0"].width == 320  # untouched by the override


def test_missing_file_and_name(tmp_path):
    with pytest.raises(ScenarioError, match="not found"):
        LoadScenario(filename=tmp_path / "nope.yaml")
    with pytest.raises(ScenarioError, match="Nope.*OneOfEverything"):
        LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Nope")


def test_bad_values_are_rejected():
    with pytest.raises(ScenarioError, match="initial_q"):
        LoadScenario(scenario_text="{robot: {initial_q: [0, 1]}}")
    with pytest.raises(ScenarioError, match="segmenter"):
        LoadScenario(scenario_text="{perception: {segmenter: magic}}")
    with pytest.raises(ScenarioError, match="force_action"):
        LoadScenario(scenario_text="{planner: {force_action: [3, 2]}}")
    with pytest.raises(ScenarioError, match="force_action"):
        LoadScenario(scenario_text="{planner: {force_action: [3.5, 2, 0.04]}}")
    with pytest.raises(ScenarioError, match="force_action.*lmap"):
        LoadScenario(scenario_text="{planner: {method: upward, force_action: [3, 2, 0.04]}}")
    ok = LoadScenario(scenario_text="{planner: {force_action: [3, 2, 0.04]}}")
    assert list(ok.planner.force_action) == [3, 2, 0.04]
    # this session's keys: twists, the torsion ratio, targets, the self-filter
    for text, key in (("{planner: {twist_angles_deg: [200]}}", r"planner\.twist_angles_deg"),
                      ("{planner: {petiole_torsion_ratio: -1}}",
                       r"planner\.petiole_torsion_ratio"),
                      ("{planner: {max_pull_distance: -0.01}}", r"planner\.max_pull_distance"),
                      ("{planner: {action_families: [pull, screw]}}",
                       r"planner\.action_families"),
                      ("{planner: {targets: some}}", r"planner\.targets"),
                      ("{planner: {min_usable_grasps: -1}}", r"planner\.min_usable_grasps"),
                      ("{perception: {robot_filter_distance: -0.1}}",
                       r"perception\.robot_filter_distance"),
                      ("{shape: {ssc: {fruit_volume_cm3: 0.00015}}}",
                       r"shape\.ssc\.fruit_volume_cm3.*m\^3"),
                      ("{shape: {ssc: {fruit_volume_cm3: 150000}}}",
                       r"shape\.ssc\.fruit_volume_cm3")):
        with pytest.raises(ScenarioError, match=key):
            LoadScenario(scenario_text=text)


def test_dump_round_trips(tmp_path):
    s = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="OneOfEverything")
    DumpScenario(s, tmp_path / "s.yaml")
    text = (tmp_path / "s.yaml").read_text()
    (tmp_path / "wrapped.yaml").write_text(
        "Dumped:\n" + "".join("  " + line + "\n" for line in text.splitlines()))
    t = LoadScenario(filename=tmp_path / "wrapped.yaml", scenario_name="Dumped")
    assert t.robot.kp == s.robot.kp
    assert t.cameras["camera0"].focal.x == s.cameras["camera0"].focal.x
    assert t.plant_scene.fruit_color.rgba.tolist() == s.plant_scene.fruit_color.rgba.tolist()


def test_scenario_text_list_is_applied_in_order():
    s = LoadScenario(scenario_text=["{planner: {energy_weight: 0.5, num_grasps: 3}}",
                                    "{planner: {energy_weight: 0.0}}"])
    assert s.planner.energy_weight == 0.0 and s.planner.num_grasps == 3
    with pytest.raises(ScenarioError, match="bogus"):
        LoadScenario(scenario_text=["{}", "{planner: {bogus: 1}}"])


def test_a_value_of_the_wrong_type_names_its_key(tmp_path):
    cases = {"{shape: {reuse_tolerance: abc}}": r"shape\.reuse_tolerance = 'abc'",
             "{planner: {ready_distances: [0.08, x]}}": r"planner\.ready_distances\[1\] = 'x'",
             "{camera_noise: {enabled: maybe}}": r"camera_noise\.enabled = 'maybe'"}
    for text, key in cases.items():
        with pytest.raises(ScenarioError, match=key):
            LoadScenario(scenario_text=text)
    # Numbers PyYAML reads as strings but Drake reads as numbers are not flagged.
    assert LoadScenario(scenario_text="{shape: {reuse_tolerance: 1e-3}}").shape.reuse_tolerance == 1e-3
    path = tmp_path / "s.yaml"
    path.write_text("mine:\n  shape: {reuse_tolerance: abc}\n")
    with pytest.raises(ScenarioError, match=r"s\.yaml.*mine\.shape\.reuse_tolerance = 'abc'"):
        LoadScenario(filename=path, scenario_name="mine")
