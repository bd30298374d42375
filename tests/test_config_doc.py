"""docs/config.md is generated from leovr/config.py (`tools/gen_docs.py`): the committed file must be
what the models and their comments render to now."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from pydantic import BaseModel

from leovr.config import LeovrConfig, RefineConfig
from leovr.config_doc import DOC, render

ROOT = Path(__file__).resolve().parents[1]


def _rows(doc: str, section: str, level: int = 2) -> dict[str, str]:
    """key -> description of one section's table (up to the next heading: a nested table's own)."""
    body = doc.split(f"\n{'#' * level} {section}\n", 1)[1].split("\n#", 1)[0]
    rows = {}
    for line in body.splitlines():
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        if len(cells) == 5 and re.fullmatch(r"`\w+`", cells[0]):
            rows[cells[0].strip("`")] = cells[4]
    return rows


def test_committed_config_md_is_rendered_from_the_models():
    assert DOC == ROOT / "docs" / "config.md"
    assert DOC.read_text() == render(), "docs/config.md is stale: run `python tools/gen_docs.py`"


def _section_keys(model: type[BaseModel]) -> list[str]:
    """The keys a section's table lists: its fields but the copy of the top-level seed."""
    return [k for k in model.model_fields if k != "seed"]


def test_every_refine_setting_is_documented_with_its_comment():
    rows = _rows(render(), "refine")
    assert list(rows) == _section_keys(RefineConfig)
    assert all(text.strip() for text in rows.values()), [k for k, text in rows.items() if not text.strip()]


def test_every_section_in_the_top_level_order_and_every_setting_described():
    doc = render()
    sections = re.findall(r"^## ([\w ]+)$", doc, re.M)
    assert sections == ["top level", *[k for k in LeovrConfig.model_fields if k != "seed"]]
    assert list(_rows(doc, "top level")) == ["seed"]
    for key, field in LeovrConfig.model_fields.items():
        if key == "seed":
            continue
        rows = _rows(doc, key)
        assert list(rows) == _section_keys(field.annotation)
        assert all(text for text in rows.values()), (key, [k for k, text in rows.items() if not text])


def _nested(model: type[BaseModel], key: str, level: int) -> list[tuple[str, type[BaseModel], int]]:
    """(dotted key, model, heading level) of every nested model below `model`, depth first."""
    found = []
    for name, field in model.model_fields.items():
        if isinstance(field.annotation, type) and issubclass(field.annotation, BaseModel):
            found.append((f"{key}.{name}", field.annotation, level + 1))
            found += _nested(field.annotation, f"{key}.{name}", level + 1)
    return found


def test_every_nested_setting_has_its_own_table_under_its_dotted_key():
    doc = render()
    nested = _nested(RefineConfig, "refine", 2)
    assert [key for key, _, _ in nested] == [
        "refine.frontend",
        "refine.graph",
        "refine.accumulation",
        "refine.motion_stereo",
        "refine.photometric",
        "refine.loop",
        "refine.camera_only",
        "refine.camera_only.graph",
    ]
    for key, model, level in nested:
        rows = _rows(doc, key, level)
        assert list(rows) == list(model.model_fields), key
        assert all(text.strip() for text in rows.values()), (key, [k for k, text in rows.items() if not text.strip()])
        assert f"(#{key.replace('.', '')})" in doc  # the parent's row links to it


def test_comments_are_read_from_above_and_beside_a_field():
    source = '''
class RefineConfig(_Model):
    """Doc."""

    # first line above
    # second line above
    window: int = Field(4, ge=2)  # beside
    causal: bool = False
'''
    from leovr.config_doc import _field_sources

    classes, _ = _field_sources(source)
    assert classes["RefineConfig"]["window"] == ("int", "first line above second line above beside")
    assert classes["RefineConfig"]["causal"] == ("bool", "")


def test_check_mode_passes_on_the_committed_file():
    done = subprocess.run([sys.executable, str(ROOT / "tools" / "gen_docs.py"), "--check"], capture_output=True)
    assert done.returncode == 0, done.stderr.decode()


def test_committed_bench_config_md_is_rendered_from_the_bench_models():
    from leovr.bench.config import BenchConfig
    from leovr.config_doc import BENCH_DOC, render_bench

    doc = render_bench()
    assert BENCH_DOC.read_text() == doc, "docs/bench_config.md is stale: run `python tools/gen_docs.py`"
    assert re.findall(r"^## (\w+)$", doc, re.M) == list(BenchConfig.model_fields)
    for key, field in BenchConfig.model_fields.items():
        rows = _rows(doc, key)
        assert list(rows) == list(field.annotation.model_fields)
