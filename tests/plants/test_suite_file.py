"""``WriteSuiteFile`` (``scripts/make_suite.py``) writes the committed suites
byte for byte, and names its default file when none is given."""
from lmap_drake.paths import DIAGRAMS_DIR
from lmap_drake.plants.suite import WriteSuiteFile


def test_write_suite_file_writes_the_committed_suites(tmp_path):
    assert WriteSuiteFile(tmp_path / "s.yaml") == (12, tmp_path / "s.yaml")
    assert (tmp_path / "s.yaml").read_text() == (DIAGRAMS_DIR / "suite.yaml").read_text()
    assert WriteSuiteFile(tmp_path / "m.yaml", multi=True) == (6, tmp_path / "m.yaml")
    assert (tmp_path / "m.yaml").read_text() == (DIAGRAMS_DIR / "multi_suite.yaml").read_text()


def test_write_suite_file_names_a_random_suite_by_its_seed(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    n, path = WriteSuiteFile(random=2, seed=5)
    assert (n, str(path)) == (2, "out/random_2_seed5.yaml")
    assert (tmp_path / path).read_text().startswith(
        "# 2 random plant scenes, seed 5: scripts/make_suite.py --random 2 --seed 5\n")
