"""An in-process engine for the bookkeeping tests of ``lmap-drake eval``
(progress, estimates, sweeps): it makes a record from each spec instead of
simulating, so the run, its folders and its tables take no time."""
import pytest


class InProcessEngine:
    """``engines.Engine`` without workers: ``Imap`` yields ``make(spec)``."""
    name = "inprocess"

    def __init__(self, make, slots=2):
        self.make, self.slots, self.calls = make, slots, []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None

    def Imap(self, fn, jobs):
        from lmap_drake.evaluation.run_eval import _EvalEntry
        for i, (spec, suite_file, _text) in enumerate(jobs):
            self.calls.append(spec)
            rec = self.make(spec)
            rec["eval"] = _EvalEntry(spec, suite_file)
            yield i, rec


def FakeRecord(spec, v1=0.9, safe=True, wall=12.0):
    """A finished episode: final visibility ``v1`` (+ the swept lambda / 10)."""
    v1 = min(1.0, v1 + 0.1 * float((spec.get("sweep_values") or {}).get(
        "planner.energy_weight", 0.0)))
    return {"status": "done", "message": "", "chosen_action": {"distance": 0.04},
            "outcome": {"leaf_damage": not safe, "plant_hazard": False,
                        "fruit_collision": False, "visibility_initial": 0.4,
                        "visibility_final": v1},
            "stage_seconds": {}, "wall_seconds": wall}


@pytest.fixture
def inprocess_engine(monkeypatch):
    """Replaces the engines of ``run_eval`` by an ``InProcessEngine``
    making ``FakeRecord``s; returns the engine (its ``calls``)."""
    from lmap_drake.evaluation import run_eval
    engine = InProcessEngine(FakeRecord)
    monkeypatch.setattr(run_eval, "MakeEngine", lambda *a, **k: engine)
    return engine
