"""Size limits on every input, checked before anything large is allocated
(documented in docs/reference/exit-codes.md). Exceeding one is bad input
(exit 2) with a one-line message naming the key or file.

Just above the floor: imports only PyYAML and ``lmap_drake.errors``.
"""
from __future__ import annotations

from pathlib import Path

import yaml

from lmap_drake.errors import InputError

MAX_IMAGE_SIDE = 4096            # px: a camera's (or a recorded image's) width and height
MAX_SCENARIO_BYTES = 1_000_000   # a scenario / suite / sweep YAML file or --scenario_text
MAX_YAML_DEPTH = 50              # nesting of YAML maps and lists
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


_Parser = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def _YamlInt(value: str) -> int | None:
    """The integer a plain YAML scalar stands for, else None."""
    node = yaml.ScalarNode("tag:yaml.org,2002:str", value)
    if yaml.resolver.Resolver().resolve(yaml.ScalarNode, value, (True, False)) \
            != "tag:yaml.org,2002:int":
        return None
    return yaml.constructor.SafeConstructor().construct_yaml_int(node)


def CheckYamlLimits(text: str, where: str) -> None:
    """Refuses (``TooLargeError`` naming ``where`` and the key path) YAML
    text over ``MAX_SCENARIO_BYTES``, nested deeper than ``MAX_YAML_DEPTH``,
    expanding (aliases included) to more than ``MAX_YAML_NODES`` nodes, or
    holding an integer beyond ``MAX_INT``. Reads events only: no recursion,
    nothing expanded. Malformed YAML raises ``yaml.YAMLError``."""
    size = len(text.encode("utf-8", "surrogatepass"))
    if size > MAX_SCENARIO_BYTES:
        raise TooLargeError(f"{where} is larger than the limit of {MAX_SCENARIO_BYTES} bytes "
                            f"({size} bytes)")
    stack: list[dict] = []        # open maps / lists: path, kind, key, expect_key, size
    anchors: dict[str, int] = {}  # anchor -> expanded node count
    total = 0

    def path() -> str:
        parts = []
        for f in stack:
            if f["kind"] == "map":
                if f["key"] is not None and not f["expect_key"]:
                    parts.append(("." if parts else "") + str(f["key"]))
            else:
                parts.append(f"[{f['index']}]")
        return "".join(parts) or "the top level"

    def done(n: int, anchor) -> None:
        nonlocal total
        total += n
        if anchor is not None:
            anchors[anchor] = n
        if total > MAX_YAML_NODES:
            raise TooLargeError(f"{where}: {path()} expands to more than {MAX_YAML_NODES} "
                                f"YAML nodes (aliases included; the limit is "
                                f"lmap_drake.limits.MAX_YAML_NODES)")
        if stack:
            f = stack[-1]
            f["size"] += n
            if f["kind"] == "map":
                f["expect_key"] = not f["expect_key"]
            else:
                f["index"] += 1

    for ev in yaml.parse(text, Loader=_Parser):
        if isinstance(ev, yaml.CollectionStartEvent):
            if len(stack) >= MAX_YAML_DEPTH:
                raise TooLargeError(f"{where}: {path()} is nested deeper than "
                                    f"{MAX_YAML_DEPTH} levels")
            kind = "map" if isinstance(ev, yaml.MappingStartEvent) else "seq"
            stack.append({"kind": kind, "key": None, "expect_key": True, "index": 0,
                          "size": 1, "anchor": ev.anchor})
        elif isinstance(ev, yaml.CollectionEndEvent):
            f = stack.pop()
            # a finished collection counts its own expanded size once
            total -= f["size"] - 1
            done(f["size"], f["anchor"])
        elif isinstance(ev, yaml.ScalarEvent):
            is_key = bool(stack) and stack[-1]["kind"] == "map" and stack[-1]["expect_key"]
            if is_key:
                stack[-1]["key"] = ev.value
            elif ev.tag is None and ev.implicit[0]:
                v = _YamlInt(ev.value)
                if v is not None and abs(v) > MAX_INT:
                    raise TooLargeError(f"{where}: {path()} = {ev.value[:30]} is beyond the "
                                        f"integer limit of {MAX_INT} (2^63 - 1)")
            done(1, ev.anchor)
        elif isinstance(ev, yaml.AliasEvent):
            is_key = bool(stack) and stack[-1]["kind"] == "map" and stack[-1]["expect_key"]
            if is_key:
                stack[-1]["key"] = f"*{ev.anchor}"
            done(anchors.get(ev.anchor, 1), None)
