"""Size limits on every input, checked before anything large is allocated
(documented in docs/reference/exit-codes.md). Exceeding one is bad input
(exit 2) with a one-line message naming the key or file.

Floor module: imports only ``lmap_drake.errors``.
"""
from __future__ import annotations

from pathlib import Path

from lmap_drake.errors import InputError

MAX_IMAGE_SIDE = 4096            # px: a camera's (or a recorded image's) width and height
MAX_SCENARIO_BYTES = 1_000_000   # a scenario / suite / sweep YAML file or --scenario_text
MAX_YAML_DEPTH = 50              # nesting of YAML maps and lists
MAX_YAML_ALIASES = 1000          # uses of YAML aliases (*name) in one document
MAX_YAML_NODES = 200_000         # nodes after expanding aliases (an alias bomb)
MAX_INT = 2**63 - 1              # any integer value (random_seed, counts)
MAX_MESH_FACES = 500_000         # faces of a fruit / peduncle mesh file
MAX_MESH_BYTES = 100_000_000     # bytes of a fruit / peduncle mesh file
MAX_SCENARIOS = 10_000           # eval --scenarios N
MAX_RECORDING_JSON_BYTES = 4_000_000   # a recording's recording.json
MAX_PLAN_JSON_BYTES = 50_000_000       # a run's plan.json (read by replay)


class TooLargeError(InputError, ValueError):
    """An input exceeds one of the limits above; the message names it."""


def ReadBounded(path, limit: int, what: str = "file") -> bytes:
    """The bytes of ``path``, reading at most ``limit + 1`` (so /dev/zero, a
    FIFO or a huge file costs at most that); ``TooLargeError`` naming the
    file when it holds more than ``limit`` bytes."""
    path = Path(path)
    with open(path, "rb") as f:
        data = f.read(limit + 1)
    if len(data) > limit:
        raise TooLargeError(f"{what} {path} is larger than the limit of {limit} bytes")
    return data
