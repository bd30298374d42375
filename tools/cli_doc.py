#!/usr/bin/env python3
"""Write docs/cli.md from the typer app (`leovr.cli_doc.render`).

    python tools/cli_doc.py           # rewrite docs/cli.md
    python tools/cli_doc.py --check   # exit 1 if docs/cli.md is not what it would write
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from leovr.cli_doc import render  # noqa: E402

DOC = ROOT / "docs" / "cli.md"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only check that docs/cli.md is up to date")
    args = parser.parse_args(argv)
    text = render()
    if args.check:
        if DOC.is_file() and DOC.read_text() == text:
            return 0
        print("docs/cli.md is out of date with leovr/cli.py: run `python tools/cli_doc.py` and commit it.", file=sys.stderr)
        return 1
    DOC.write_text(text)
    print(f"wrote docs/cli.md ({len(text.splitlines())} lines)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
