"""Generated reference pages for the documentation site (a MkDocs hook).

``mkdocs build`` calls ``on_files``, which adds two pages that are never
written by hand:

* ``reference/scenario.md``: every scenario key, found by walking the type
  hints of ``lmap_drake.scenario.Scenario`` recursively (``dataclasses.fields``
  and ``typing.get_type_hints``), so the page follows the config classes
  wherever they live; with its type, its default (from ``Scenario()``) and
  its doc: the comment beside the field, else the sentence of the class
  docstring that names it. Drake-bound structs (``CameraConfig``,
  ``SimulatorConfig``, ...) list their ``__fields__`` with defaults and
  link Drake's documentation.
* ``reference/cli.md``: the ``lmap-drake`` commands and options, read from
  the argparse parser that ``lmap_drake.cli`` builds (caught as it parses,
  before any command runs).

``ScenarioKeys()`` and the ``*Markdown()`` functions are also used by
``tests/test_docs.py``.
"""
from __future__ import annotations

import argparse
import ast
import collections.abc
import dataclasses as dc
import enum
import inspect
import io
import re
import sys
import textwrap
import tokenize
import types
import typing
from pathlib import Path

import numpy as np
from pydrake.math import RollPitchYaw

REPO_ROOT = Path(__file__).resolve().parents[2]
if str(REPO_ROOT) not in sys.path:          # the checkout being documented
    sys.path.insert(0, str(REPO_ROOT))

from lmap_drake import cli, scenario as scenario_module  # noqa: E402  (after the path)

# Drake value types: shown as one key (their YAML spelling is in the table).
_VALUE_TYPES = {"Transform": "`{translation: [x, y, z], rotation: !Rpy {deg: [r, p, y]}, "
                             "base_frame: name}`",
                "Rgba": "`{rgba: [r, g, b, a]}`",
                "Rotation": "`!Rpy {deg: [r, p, y]}`"}
_DRAKE_DOC = "https://drake.mit.edu/pydrake/{module}.html#{module}.{qualname}"


@dc.dataclass
class Key:
    """One row of the scenario reference."""
    path: str            # dotted key path; `[]` marks a list item, `<name>` a map key
    type: str
    default: str
    doc: str
    owner: str           # the class that declares it


@dc.dataclass
class Section:
    """One config class met on the walk, with its keys."""
    path: str
    cls: type
    doc: str
    link: str = ""
    keys: list[Key] = dc.field(default_factory=list)


def _TypeName(t) -> str:
    origin = typing.get_origin(t)
    if origin is typing.Union or (origin is not None and str(origin) == "<class 'types.UnionType'>"):
        args = typing.get_args(t)
        return " | ".join(_TypeName(a) for a in args)
    try:
        if isinstance(t, types.UnionType):
            return " | ".join(_TypeName(a) for a in typing.get_args(t))
    except AttributeError:
        pass
    if origin is not None:
        args = typing.get_args(t)
        name = getattr(origin, "__name__", str(origin))
        if origin in (collections.abc.Mapping, dict):
            name = "Mapping"
        return f"{name}[{', '.join(_TypeName(a) for a in args)}]" if args else name
    if t is type(None):
        return "None"
    return getattr(t, "__name__", str(t).replace("typing.", ""))


def _Unwrap(t):
    """``Optional[X]`` -> X (other unions stay)."""
    args = [a for a in typing.get_args(t) if a is not type(None)]
    origin = typing.get_origin(t)
    if (origin is typing.Union or type(t).__name__ == "UnionType") and len(args) == 1:
        return args[0]
    return t


def _IsDrakeStruct(t) -> bool:
    return (isinstance(t, type) and hasattr(t, "__fields__")
            and t.__module__.startswith("pydrake") and t.__name__ not in _VALUE_TYPES)


def _DrakeLink(t) -> str:
    module = t.__module__
    return _DRAKE_DOC.format(module=module, qualname=t.__qualname__)


def _Default(v) -> str:
    if dc.is_dataclass(v) and not isinstance(v, type):
        return f"a {type(v).__name__}"
    if isinstance(v, enum.Enum):
        return v.name
    name = type(v).__name__
    if name == "Rgba":
        return f"rgba {[round(x, 3) for x in (v.r(), v.g(), v.b(), v.a())]}"
    if name == "Transform":
        try:
            X = v.GetDeterministicValue()
            rpy = np.rad2deg(RollPitchYaw(X.rotation()).vector())
            base = f", base_frame {v.base_frame}" if v.base_frame else ""
            return (f"translation {[round(float(x), 4) for x in X.translation()]}, "
                    f"rpy deg {[round(float(x), 2) for x in rpy]}{base}")
        except Exception:       # a random Transform
            return "Transform"
    if isinstance(v, (list, tuple)) and v and (dc.is_dataclass(v[0]) or hasattr(v[0], "__fields__")):
        return f"{len(v)} entries"
    if isinstance(v, collections.abc.Mapping):
        return "{" + ", ".join(str(k) for k in v) + "}"
    if hasattr(v, "tolist"):
        v = v.tolist()
    if isinstance(v, str):
        return f'"{v}"'
    if hasattr(type(v), "__fields__") and type(v).__module__.startswith("pydrake"):
        return name
    text = repr(v)
    return text if len(text) <= 80 else text[:77] + "..."


def _Comments(cls) -> dict[str, str]:
    """Per field: the comment on its line or the comment lines above it, or
    a string literal right after it (an attribute docstring)."""
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    lines = source.splitlines()
    comments: dict[int, str] = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            comments[tok.start[0]] = tok.string.lstrip("#").strip()
    out: dict[str, str] = {}
    body = ast.parse(source).body[0].body
    for i, node in enumerate(body):
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            continue
        name = node.target.id
        parts = []
        above = []
        ln = node.lineno - 1
        while ln >= 1 and ln in comments and lines[ln - 1].lstrip().startswith("#"):
            above.insert(0, comments[ln])
            ln -= 1
        parts += above
        for ln in range(node.lineno, (node.end_lineno or node.lineno) + 1):
            if ln in comments and not lines[ln - 1].lstrip().startswith("#"):
                parts.append(comments[ln])
        if i + 1 < len(body):
            nxt = body[i + 1]
            if isinstance(nxt, ast.Expr) and isinstance(getattr(nxt, "value", None), ast.Constant) \
                    and isinstance(nxt.value.value, str):
                parts.append(" ".join(nxt.value.value.split()))
        if parts:
            out[name] = " ".join(parts)
    return out


_SENTENCE = re.compile(r"(?<=[.!?])\s+(?=[A-Z`(])")


def _Mention(doc: str, name: str) -> str:
    """The first sentence of ``doc`` that names ``name`` as ``name``."""
    if not doc:
        return ""
    pattern = re.compile(r"``" + re.escape(name) + r"``|``[^`]*\b" + re.escape(name) + r"\b[^`]*``")
    sentences = [s for para in re.split(r"\n\s*\n", doc)
                 for s in _SENTENCE.split(" ".join(para.split()))]
    for sentence in sentences:
        if pattern.search(sentence):
            return sentence
    for sentence in sentences:          # a family: ``branch_*``, ``peduncle_*``
        for prefix in re.findall(r"``(\w+)\*``", sentence):
            if name.startswith(prefix):
                return sentence
    return ""


def _Rst(text: str) -> str:
    """Docstring markup to Markdown: ``x`` -> `x`."""
    return text.replace("``", "`")


def _Cell(text: str) -> str:
    """A Markdown table cell; paths inside the checkout are shown relative."""
    text = text.replace(str(REPO_ROOT) + "/", "")
    return text.replace("|", "\\|").replace("\n", " ")


def WalkScenario():
    """Walks ``Scenario`` from its type hints. Returns the sections met, in
    order; every leaf key belongs to exactly one."""
    Scenario = scenario_module.Scenario
    sections: list[Section] = []
    seen: set[str] = set()

    def doc_of(cls) -> str:
        d = inspect.getdoc(cls) or ""
        return "" if d.startswith(f"{cls.__name__}(") else d

    def walk_dataclass(cls, instance, path: str):
        section = Section(path, cls, doc_of(cls))
        sections.append(section)
        hints = typing.get_type_hints(cls)
        comments = _Comments(cls)
        children = []
        for f in dc.fields(cls):
            t = hints.get(f.name, f.type)
            value = getattr(instance, f.name)
            key = f"{path}.{f.name}" if path else f.name
            doc = comments.get(f.name) or _Mention(section.doc, f.name)
            if not add(section, key, t, value, _Rst(doc), cls.__name__):
                children.append((key, t, value))
        for key, t, value in children:
            recurse(key, t, value)

    def walk_drake(cls, instance, path: str):
        section = Section(path, cls, (inspect.getdoc(cls) or "").split("\n\n")[0],
                          link=_DrakeLink(cls))
        sections.append(section)
        children = []
        for f in cls.__fields__:
            value = getattr(instance, f.name)
            key = f"{path}.{f.name}"
            doc = (getattr(getattr(cls, f.name, None), "__doc__", "") or "").split("\n\n")[0]
            if not add(section, key, f.type, value, _Rst(" ".join(doc.split())), cls.__name__):
                children.append((key, f.type, value))
        for key, t, value in children:
            recurse(key, t, value)

    def add(section: Section, key: str, t, value, doc: str, owner: str) -> bool:
        """Adds a leaf row; False when the key is a section of its own."""
        t = _Unwrap(t)
        if _Structured(t):
            return False
        seen.add(key)
        section.keys.append(Key(key, _TypeName(t), _Default(value), doc, owner))
        return True

    def _Structured(t) -> bool:
        if dc.is_dataclass(t) or _IsDrakeStruct(t):
            return True
        origin = typing.get_origin(t)
        args = typing.get_args(t)
        if origin in (list, collections.abc.Sequence) and args:
            a = _Unwrap(args[0])
            return dc.is_dataclass(a)
        if origin in (dict, collections.abc.Mapping) and len(args) == 2:
            a = _Unwrap(args[1])
            return dc.is_dataclass(a) or _IsDrakeStruct(a)
        return False

    def recurse(key: str, t, value):
        t = _Unwrap(t)
        origin = typing.get_origin(t)
        args = typing.get_args(t)
        if dc.is_dataclass(t):
            walk_dataclass(t, value, key)
        elif _IsDrakeStruct(t):
            walk_drake(t, value, key)
        elif origin in (list, collections.abc.Sequence):
            item_t = _Unwrap(args[0])
            item = value[0] if value else item_t()
            walk_dataclass(item_t, item, f"{key}[]")
        elif origin in (dict, collections.abc.Mapping):
            item_t = _Unwrap(args[1])
            item = next(iter(value.values())) if value else item_t()
            if dc.is_dataclass(item_t):
                walk_dataclass(item_t, item, f"{key}.<name>")
            else:
                walk_drake(item_t, item, f"{key}.<name>")

    walk_dataclass(Scenario, Scenario(), "")
    return sections


def ScenarioKeys() -> list[str]:
    """Every leaf key path of the reference, in page order."""
    return [k.path for s in WalkScenario() for k in s.keys]


def ScenarioMarkdown() -> str:
    sections = WalkScenario()
    out = ["# Scenario keys", "",
           "<!-- generated by docs/hooks/reference.py from the config dataclasses: "
           "do not edit -->", "",
           "Every key a scenario file may set, generated from the config dataclasses "
           "that `lmap_drake.scenario.Scenario` is made of and their docstrings. "
           "A scenario file holds named scenarios at top level; each is a `Scenario`. "
           "Units: metres, seconds, radians unless a key's name says otherwise "
           "(`*_deg`, `*_cm`); rotations are written `!Rpy {deg: [...]}`. "
           "`[]` in a key path stands for every item of a list, `<name>` for every "
           "entry of a map (the default camera is `camera0`). "
           "Keys set in YAML are checked when the scenario is loaded (unknown keys, "
           "types, ranges): see [exit codes](exit-codes.md).", "",
           f"{sum(len(s.keys) for s in sections)} keys in {len(sections)} sections.", ""]
    out.append("| section | class | keys |")
    out.append("| --- | --- | --- |")
    for s in sections:
        anchor = _Anchor(s.path or "top level")
        out.append(f"| [`{s.path or '(top level)'}`](#{anchor}) | `{s.cls.__name__}` "
                   f"| {len(s.keys)} |")
    out.append("")
    for s in sections:
        out.append(f"## `{s.path}`" if s.path else "## top level")
        out.append("")
        origin = f"`{s.cls.__name__}`"
        if s.link:
            origin += f", a Drake struct: see [Drake's documentation]({s.link})"
        else:
            origin += f" (`{s.cls.__module__}`)"
        out.append(f"Class {origin}.")
        out.append("")
        if s.doc:
            doc = _Rst(s.doc)
            if s.link:
                doc = " ".join(doc.split())
            out.append(doc)
            out.append("")
        if not s.keys:
            out.append("(Only sub-sections, below.)")
            out.append("")
            continue
        out.append("| key | type | default | doc |")
        out.append("| --- | --- | --- | --- |")
        for k in s.keys:
            type_text = k.type
            for value_type, spelling in _VALUE_TYPES.items():
                if type_text == value_type:
                    type_text = f"{value_type} {spelling}"
            out.append(f"| `{_Cell(k.path)}` | {_Cell(type_text)} | `{_Cell(k.default)}` "
                       f"| {_Cell(k.doc)} |")
        out.append("")
    out += ["## Renamed keys", "",
            "Keys of older scenario files that moved; files that use them still load "
            "(the key is moved to its new place; setting both the old and the new key "
            "is an error naming both).", "",
            "| old key | new key |", "| --- | --- |"]
    out += [f"| `{old}` | `{new}` |" for old, new in scenario_module.MOVED_KEYS.items()]
    return "\n".join(out) + "\n"


def _Anchor(title: str) -> str:
    """The id MkDocs' toc extension gives a heading (default slugify)."""
    text = re.sub(r"[^\w\s-]", "", title.lower()).strip()
    return re.sub(r"[-\s]+", "-", text)


class _Parser(BaseException):
    """Carries the parser out of ``lmap_drake.cli`` before any command runs."""

    def __init__(self, parser):
        super().__init__("parser")
        self.parser = parser


def CliParser() -> argparse.ArgumentParser:
    """The ``lmap-drake`` parser, caught at ``parse_args`` (nothing runs)."""
    for name in ("BuildParser", "MakeParser", "Parser"):   # a builder, if the CLI has one
        build = getattr(cli, name, None)
        if callable(build):
            parser = build()
            if isinstance(parser, argparse.ArgumentParser):
                return parser
    caught = []
    original = argparse.ArgumentParser.parse_args

    def catch(self, *args, **kwargs):
        caught.append(self)
        raise _Parser(self)
    argparse.ArgumentParser.parse_args = catch
    try:
        entry = getattr(cli, "_main", None) or cli.main
        try:
            entry(["--help"])
        except (_Parser, SystemExit):
            pass
    finally:
        argparse.ArgumentParser.parse_args = original
    if not caught:
        raise RuntimeError("lmap_drake.cli did not build an argparse parser")
    return caught[0]


def _OptionRows(parser: argparse.ArgumentParser) -> list[str]:
    rows = ["| option | default | help |", "| --- | --- | --- |"]
    for a in parser._actions:
        if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        if a.option_strings:
            names = ", ".join(a.option_strings)
            if a.nargs != 0 and not isinstance(a, (argparse._StoreTrueAction,
                                                    argparse._StoreFalseAction,
                                                    argparse._StoreConstAction)):
                names += f" {a.metavar or a.dest.upper()}"
        else:
            names = a.metavar or a.dest.upper()
        if a.choices:
            names += " {" + ",".join(map(str, a.choices)) + "}"
        default = "" if a.default in (None, False, argparse.SUPPRESS) or a.nargs == 0 \
            else f"`{a.default}`"
        help_text = (a.help or "").replace("%(default)s", str(a.default))
        rows.append(f"| `{_Cell(names)}` | {_Cell(default)} | {_Cell(help_text)} |")
    return rows


def CliMarkdown() -> str:
    parser = CliParser()
    out = ["# Command line: `lmap-drake`", "",
           "<!-- generated by docs/hooks/reference.py from the argparse parser of "
           "lmap_drake.cli: do not edit -->", "",
           "Installed as the console script `lmap-drake` (`make run` calls "
           "`lmap-drake run $(ARGS)`); `python -m lmap_drake.cli` is the same. "
           "Errors are one line on stderr; `--debug` adds the traceback. "
           "Exit codes: [exit codes](exit-codes.md).", ""]
    out += ["## Global options", ""] + _OptionRows(parser) + [""]
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {c.dest: c.help for c in sub._choices_actions}
    for name, p in sub.choices.items():
        out += [f"## `lmap-drake {name}`", "", helps.get(name, "") or "", "",
                "```text", p.format_usage().strip(), "```", ""]
        out += _OptionRows(p) + [""]
    return "\n".join(out) + "\n"


def on_files(files, config):
    """MkDocs hook: add the generated reference pages."""
    from mkdocs.structure.files import File
    for uri, make in (("reference/scenario.md", ScenarioMarkdown),
                      ("reference/cli.md", CliMarkdown)):
        files.append(File.generated(config, uri, content=make()))
    return files


if __name__ == "__main__":          # print a page: python docs/hooks/reference.py [cli]
    print(CliMarkdown() if sys.argv[1:] == ["cli"] else ScenarioMarkdown())
