"""docs/cli.md is generated from the typer app: the committed file matches it and names every command."""

from __future__ import annotations

from pathlib import Path

from leovr.cli_doc import render

ROOT = Path(__file__).resolve().parents[1]


def test_the_committed_cli_reference_matches_the_command_line():
    text = render()
    assert (ROOT / "docs" / "cli.md").read_text() == text, "docs/cli.md is stale: run python tools/gen_docs.py"
    for command in ("refine", "poses", "train", "bench real", "bench refine", "viz", "batch"):
        assert f"## `leovr {command}`" in text
    assert "--causal" in text
