"""docs/config.md is generated from leovr/config.py (`tools/gen_docs.py`): the committed file must be
what the models and their comments render to now."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from leovr.config import LeovrConfig, RefineConfig
from leovr.config_doc import DOC, render

ROOT = Path(__file__).resolve().parents[1]


def _rows(doc: str, section: str) -> dict[str, str]:
    """key -> description of one section's table."""
    body = doc.split(f"\n## {section}\n", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in body.splitlines():
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        if len(cells) == 5 and re.fullmatch(r"`\w+`", cells[0]):
            rows[cells[0].strip("`")] = cells[4]
    return rows


def test_committed_config_md_is_rendered_from_the_models():
    assert DOC == ROOT / "docs" / "config.md"
    assert DOC.read_text() == render(), "docs/config.md is stale: run `python tools/gen_docs.py`"


def test_every_refine_setting_is_documented_with_its_comment():
    rows = _rows(render(), "refine")
    assert list(rows) == list(RefineConfig.model_fields)
    assert all(text.strip() for text in rows.values()), [k for k, text in rows.items() if not text.strip()]


def test_every_section_in_the_top_level_order_and_every_setting_described():
    doc = render()
    sections = re.findall(r"^## (\w+)$", doc, re.M)
    assert sections == list(LeovrConfig.model_fields)
    for key, field in LeovrConfig.model_fields.items():
        rows = _rows(doc, key)
        assert list(rows) == list(field.annotation.model_fields)
        assert all(text for text in rows.values()), (key, [k for k, text in rows.items() if not text])


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
