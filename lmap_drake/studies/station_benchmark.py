"""Realtime factor of the simulated station during a pull (behind
``scripts/bench_station.py``): the default scenario (FEM leaf) approaches
and grasps the leaf (not timed), then a pull of the default direction and
distance is timed with the ground-truth monitors and, on a fork, without.
"""
from __future__ import annotations

import os
import platform
import time

import numpy as np

from lmap_drake.paths import DEFAULT_SCENARIO_FILE
from lmap_drake.planning.motion import MotionError
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.plants.scripted import ApproachAndGrasp, Pull
from lmap_drake.scenario import LoadScenario


def BenchStation(scenario_name: str = "Defaults", duration: float = 2.0,
                 scenario_file=DEFAULT_SCENARIO_FILE, leaf: int = -1,
                 scenario_text: str = "{}") -> dict:
    """``realtime_factor``: wall seconds per simulated second of a
    ``duration`` s pull (monitors sampled every ``outcome.sample_period``);
    ``realtime_factor_simulation_only``: the same with the monitors off;
    ``cpu_seconds_per_simulated_second`` (and ``_simulation_only``): the
    process's CPU time instead of wall time (load-independent, on one
    thread; FEM threads add theirs).
    ``leaf``: the FEM leaf grasped (``kind: multi`` / ``greenhouse``; on a
    greenhouse plant leaf 0 is the first target's main occluder); -1: the
    first FEM leaf whose tip grasp the arm can reach (IK)."""
    scenario = LoadScenario(filename=scenario_file, scenario_name=scenario_name,
                            scenario_text=scenario_text)
    world = PlantWorldSim(scenario, progress=lambda m: print(f"[bench] {m}", flush=True))
    world.Hold(0.3)
    tried = [leaf] if leaf >= 0 else list(range(len(world.leaf_refs)))
    for k, j in enumerate(tried):
        try:
            ApproachAndGrasp(world, scenario.plant_scene.pull, leaf=j)
            leaf = j
            break
        except MotionError as err:        # planned before anything moves
            if k == len(tried) - 1:
                raise
            print(f"[bench] leaf {j}: {err}; trying leaf {tried[k + 1]}", flush=True)
    pull = scenario.plant_scene.pull
    fork = world.Fork()
    t0, c0 = time.perf_counter(), time.process_time()
    Pull(world, pull.direction_W, pull.distance, duration)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    fork.Sample = lambda: None  # monitors off
    fork.samples = []
    t1, c1 = time.perf_counter(), time.process_time()
    d = np.asarray(pull.direction_W, float)
    Pull(fork, d, pull.distance, duration)
    wall_sim, cpu_sim = time.perf_counter() - t1, time.process_time() - c1
    return {"realtime_factor": wall / duration,
            "realtime_factor_simulation_only": wall_sim / duration,
            # CPU seconds of this process per simulated second: what the
            # realtime factor would be on an otherwise idle core (the wall
            # figures above grow with the machine's load)
            "cpu_seconds_per_simulated_second": cpu / duration,
            "cpu_seconds_per_simulated_second_simulation_only": cpu_sim / duration,
            "simulated_seconds": duration,
            "time_step": scenario.plant_config.time_step,
            "leaf_tets": int(sum(len(r.tets) for r in world.leaf_refs)),
            "fem_leaves": len(world.leaf_refs),
            "grasped_leaf": leaf,
            "static_leaves": len(getattr(world.model, "static_leaves", [])),
            "scenario": f"{scenario_file}:{scenario_name}",
            "scenario_text": scenario_text,
            "machine": f"{platform.machine()}, {os.cpu_count()} cpus"}
