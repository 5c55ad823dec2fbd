"""The URDF generator writes the committed models (``models/``) byte for byte."""
from lmap_drake.paths import MODELS_DIR
from lmap_drake.robot_models import Robotiq2f85Urdf, Ur5Urdf, WriteRobotModels


def test_the_generated_urdfs_are_the_committed_files():
    assert Ur5Urdf() == (MODELS_DIR / "ur5" / "ur5.urdf").read_text()
    assert Robotiq2f85Urdf() == (MODELS_DIR / "robotiq_2f85" / "robotiq_2f85.urdf").read_text()


def test_write_robot_models_writes_both_files_under_the_folder(tmp_path):
    ur5, robotiq = WriteRobotModels(tmp_path / "m")
    assert ur5 == tmp_path / "m" / "ur5" / "ur5.urdf"
    assert robotiq == tmp_path / "m" / "robotiq_2f85" / "robotiq_2f85.urdf"
    assert ur5.read_bytes() == (MODELS_DIR / "ur5" / "ur5.urdf").read_bytes()
    assert robotiq.read_bytes() == (MODELS_DIR / "robotiq_2f85" / "robotiq_2f85.urdf").read_bytes()
