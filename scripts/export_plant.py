#!/usr/bin/env python3
"""Writes a generated greenhouse plant as a plant folder of mesh files, for
``plant_scene.kind: mesh_plant`` (docs/how-to/bring-your-own-plant.md):

    python scripts/export_plant.py --out out/plant_gh7 --seed 7
    python scripts/export_plant.py --out out/plant_gh7_cards --seed 7 --cards
    python scripts/export_plant.py --out out/plant_s --scenario_file diagrams/greenhouse_suite.yaml \
        --scenario_name gh_one_red_heavy

stems/, leaves/ (open mid-surfaces; ``--cards``: flat textured quads with the
leaf outline in the texture's alpha), fruits/, a ``plant.yaml`` manifest and
``export_info.json`` (the source plant's ground truth). The files' origin is
the plant's ``plant_scene.p_W_branch_base``. The logic is
``lmap_drake.plants.plant_export``.
"""
import argparse
import sys

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.plants.plant_export import ExportScenarioPlant
from lmap_drake.scenario import LoadScenario


def main(argv=None) -> int:
    p = OneLineArgumentParser(description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, help="the plant folder to write")
    p.add_argument("--scenario_file", default=None,
                   help="a scenario file (default: the built-in defaults)")
    p.add_argument("--scenario_name", default="Defaults")
    p.add_argument("--scenario_text", action="append", default=[],
                   help="YAML overrides applied last (repeatable)")
    p.add_argument("--seed", type=int, default=None,
                   help="plant_scene.greenhouse.seed (sets plant_scene.kind: greenhouse)")
    p.add_argument("--cards", action="store_true",
                   help="leaves as textured cards with alpha outlines")
    p.add_argument("--overwrite", action="store_true")
    a = p.parse_args(argv)
    texts = list(a.scenario_text)
    if a.seed is not None:
        texts.append("{plant_scene: {kind: greenhouse, greenhouse: {seed: %d}}}" % a.seed)
    if a.scenario_file:
        scenario = LoadScenario(filename=a.scenario_file, scenario_name=a.scenario_name,
                                scenario_text=texts)
    else:
        scenario = LoadScenario(scenario_text=texts or ["{}"])
    out = ExportScenarioPlant(scenario, a.out, cards=a.cards, overwrite=a.overwrite)
    print(f"wrote {out}; load it with: {{plant_scene: {{kind: mesh_plant, mesh_plant: "
          f"{{folder: {out}, X_W_plant: {{translation: "
          f"{list(scenario.plant_scene.p_W_branch_base)}}}}}}}}}")
    return 0


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="export_plant.py", strip_debug=True))
