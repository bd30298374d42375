"""The configuration reference docs/config.md, rendered from the pydantic models in leovr/config.py (with
leovr/config_base.py and leovr/refine_config.py, whose models it re-exports).

A table of the top-level settings (the seed), then one section per top-level model of `LeovrConfig`, in its
order; per setting its name, type, default and the comment it carries in the source; a setting that is a nested
model (`refine.graph`) links to its own table, under a sub-heading after its section's. pydantic keeps no
comments, so they are read from those files themselves (`tokenize`): the comment lines directly above a field and
the comment at the end of its line.
`tools/gen_docs.py` writes the file; `tests/test_config_doc.py` checks it is current.
"""

from __future__ import annotations

import ast
import io
import math
import re
import tokenize
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from leovr import config, config_base, refine_config

SOURCES = tuple(Path(m.__file__) for m in (config_base, refine_config, config))
DOC = Path(__file__).resolve().parents[1] / "docs" / "config.md"
BENCH_DOC = DOC.with_name("bench_config.md")

_BOUNDS = (("ge", ">="), ("gt", ">"), ("le", "<="), ("lt", "<"))


def _comments(source: str) -> tuple[dict[int, str], set[int]]:
    """Comment text by line number, and the lines that hold nothing but a comment."""
    text: dict[int, str] = {}
    alone: set[int] = set()
    lines = source.splitlines()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            row, col = tok.start
            text[row] = tok.string.lstrip("#").strip()
            if not lines[row - 1][:col].strip():
                alone.add(row)
    return text, alone


def _field_sources(source: str) -> tuple[dict[str, dict[str, tuple[str, str]]], dict[str, str]]:
    """Per class: field name -> (annotation as written, comment); and the module's type aliases."""
    tree = ast.parse(source)
    text, alone = _comments(source)
    aliases = {
        node.targets[0].id: ast.get_source_segment(source, node.value) or ast.unparse(node.value)
        for node in tree.body
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)
    }
    classes: dict[str, dict[str, tuple[str, str]]] = {}
    for node in tree.body:
        if not isinstance(node, ast.ClassDef):
            continue
        fields = {}
        for item in node.body:
            if not (isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name)):
                continue
            above = []
            row = item.lineno - 1
            while row in alone:
                above.insert(0, text[row])
                row -= 1
            inline = [text[r] for r in range(item.lineno, item.end_lineno + 1) if r in text and r not in alone]
            annotation = ast.get_source_segment(source, item.annotation) or ast.unparse(item.annotation)
            fields[item.target.id] = (annotation, " ".join(above + inline))
        classes[node.name] = fields
    return classes, aliases


def _yaml_value(value: Any) -> str:
    """A default as it is written in a YAML config."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and math.isinf(value):
        return ".inf" if value > 0 else "-.inf"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_yaml_value(v) for v in value) + "]"
    return str(value)


def _bounds(field: Any) -> str:
    found = []
    for meta in field.metadata:
        for attr, sign in _BOUNDS:
            bound = getattr(meta, attr, None)
            if bound is not None:
                found.append(f"{sign} {_yaml_value(bound)}")
    return ", ".join(found)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def _linked(comment: str) -> str:
    """A comment's decision-record paths as links relative to docs/config.md."""
    return re.sub(r"docs/decisions/([\w.-]+\.md)", r"[\1](decisions/\1)", comment)


def _type(annotation: str, aliases: dict[str, str]) -> str:
    return aliases.get(annotation, annotation)


def _nested(field: Any) -> type[BaseModel] | None:
    """The model class of a setting that is a table of its own (a nested model), else None."""
    kind = field.annotation
    return kind if isinstance(kind, type) and issubclass(kind, BaseModel) else None


def _from_top_level(field: Any) -> bool:
    """A section's copy of a setting given once, at the top level (the seed): listed there, not in the section."""
    return isinstance(field.json_schema_extra, dict) and bool(field.json_schema_extra.get("top_level"))


def _anchor(key: str) -> str:
    """The link target GitHub gives a heading: lower case, dots dropped."""
    return key.lower().replace(".", "")


def _row(name: str, field: Any, annotation: str, comment: str, aliases: dict) -> str:
    """One setting's table row: key, type, default, range and its comment."""
    return (
        f"| `{name}` | `{_cell(_type(annotation, aliases))}` | `{_cell(_yaml_value(field.default))}` "
        f"| {_bounds(field)} | {_linked(_cell(comment))} |"
    )


def _section(key: str, model: type[BaseModel], classes: dict, aliases: dict, level: int = 2) -> list[str]:
    """One heading and table per model; a nested model's row links to its own table, which follows under
    a sub-heading named by its dotted key (`refine.graph`)."""
    lines = [f"{'#' * level} {key}", ""]
    doc = " ".join((model.__doc__ or "").split())
    lines += [f"`{model.__name__}`: {_linked(doc)}" if doc else f"`{model.__name__}`", ""]
    lines += ["| key | type | default | range | what it does |", "|---|---|---|---|---|"]
    nested = []
    for name, field in model.model_fields.items():
        if _from_top_level(field):
            continue
        owner = next(c for c in model.__mro__ if name in classes.get(c.__name__, {}))
        annotation, comment = classes[owner.__name__][name]
        sub = _nested(field)
        if sub is not None:
            nested.append((f"{key}.{name}", sub))
            default = f"[{key}.{name}](#{_anchor(f'{key}.{name}')})"
            lines.append(f"| `{name}` | `{sub.__name__}` | {default} |  | {_linked(_cell(comment))} |")
            continue
        lines.append(_row(name, field, annotation, comment, aliases))
    lines.append("")
    for sub_key, sub in nested:
        lines += _section(sub_key, sub, classes, aliases, min(level + 1, 6))
    return lines


def _render(root: type[BaseModel], sources: list[str], intro: list[str]) -> str:
    """One section per top-level key of `root`, after `intro`, from the models' comments in `sources`."""
    classes: dict[str, dict[str, tuple[str, str]]] = {}
    aliases: dict[str, str] = {}
    for text in sources:
        more_classes, more_aliases = _field_sources(text)
        classes |= more_classes
        aliases |= more_aliases
    sections = [(key, field) for key, field in root.model_fields.items() if _nested(field) is not None]
    out = [*intro, "", "Sections: " + " · ".join(f"[{key}](#{key})" for key, _ in sections), ""]
    top = [(key, field) for key, field in root.model_fields.items() if _nested(field) is None]
    if top:
        out += ["## top level", "", "| key | type | default | range | what it does |", "|---|---|---|---|---|"]
        for name, field in top:
            out.append(_row(name, field, *classes[root.__name__][name], aliases))
        out.append("")
    for key, field in sections:
        out += _section(key, field.annotation, classes, aliases)
    return "\n".join(out).rstrip("\n") + "\n"


NESTED = [
    "A nested table's keys go under its key in the YAML file: `refine.graph.pixel_sigma` is",
    "`refine: {graph: {pixel_sigma: 1.0}}`, and the keys left out keep their defaults.",
]


def render(source: str | None = None) -> str:
    """docs/config.md as it should read for the config models (`source`: one text holding them all; None: the
    three source files)."""
    intro = [
        "# Configuration reference",
        "",
        "Generated by `python tools/gen_docs.py` from the models and comments in leovr/config.py, config_base.py "
        "and refine_config.py; do not edit by hand.",
        "Every key can be set in a YAML file passed with `-c` (configs/default.yaml holds every section; the seed is "
        "set once, at the top level); options given",
        "on the command line override it. Why the main defaults are what they are: "
        "[docs/decisions](decisions/README.md).",
        *NESTED,
        "The benchmarks' settings are apart: [bench_config.md](bench_config.md).",
    ]
    sources = [source] if source is not None else [p.read_text() for p in SOURCES]
    return _render(config.LeovrConfig, sources, intro)


def render_bench() -> str:
    """docs/bench_config.md: the settings of `leovr bench` (leovr/bench/config.py)."""
    from leovr.bench import config as bench_config

    intro = [
        "# Benchmark settings",
        "",
        "Generated by `python tools/gen_docs.py` from the models and comments in leovr/bench/config.py; do not edit "
        "by hand.",
        "`leovr bench NAME -c FILE` reads a YAML file of these sections (configs/bench.yaml holds every one); the "
        "command's",
        "options override it. The product's own settings: [config.md](config.md).",
    ]
    sources = [p.read_text() for p in SOURCES] + [Path(bench_config.__file__).read_text()]
    return _render(bench_config.BenchConfig, sources, intro)
