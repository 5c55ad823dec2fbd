#!/usr/bin/env python3
"""Realtime factor of the simulated station during a pull.

    python scripts/bench_station.py --out bench_station.json

Builds the default scenario (FEM leaf), approaches and grasps the leaf (not
timed), then times a 2 s pull of the default direction and distance:
``realtime_factor`` = wall seconds per simulated second (including the
ground-truth monitors sampled every ``outcome.sample_period``), and the same
for the bare simulator (``realtime_factor_simulation_only``, monitors off).
"""
import argparse
import json
import platform
import time

import numpy as np

from lmap_drake.paths import DEFAULT_SCENARIO_FILE
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.plants.scripted import ApproachAndGrasp, Pull
from lmap_drake.scenario import LoadScenario


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True)
    p.add_argument("--scenario_name", default="Defaults")
    p.add_argument("--duration", type=float, default=2.0)
    a = p.parse_args()
    scenario = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name=a.scenario_name)
    world = PlantWorldSim(scenario, progress=lambda m: print(f"[bench] {m}", flush=True))
    world.Hold(0.3)
    ApproachAndGrasp(world, scenario.plant_scene.pull)
    pull = scenario.plant_scene.pull
    fork = world.Fork()
    t0 = time.perf_counter()
    Pull(world, pull.direction_W, pull.distance, a.duration)
    wall = time.perf_counter() - t0
    fork.Sample = lambda: None  # monitors off
    fork.samples = []
    t1 = time.perf_counter()
    d = np.asarray(pull.direction_W, float)
    Pull(fork, d, pull.distance, a.duration)
    wall_sim = time.perf_counter() - t1
    result = {"realtime_factor": wall / a.duration,
              "realtime_factor_simulation_only": wall_sim / a.duration,
              "simulated_seconds": a.duration,
              "time_step": scenario.plant_config.time_step,
              "leaf_tets": int(len(world.model.leaf_tets)),
              "machine": f"{platform.machine()}, {__import__('os').cpu_count()} cpus"}
    with open(a.out, "w") as f:
        json.dump(result, f, indent=2)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    import sys

    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="bench_station.py", strip_debug=True))  # one-line errors; --debug
