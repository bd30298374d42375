#!/usr/bin/env python3
"""Write docs/config.md from the configuration models in leovr/config.py (`leovr.config_doc.render`).

    python tools/config_doc.py           # rewrite docs/config.md
    python tools/config_doc.py --check   # exit 1 if docs/config.md is not what it would write
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from leovr.config_doc import DOC, render  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    """Write the file, or with --check compare it with what would be written."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only check that docs/config.md is up to date")
    args = parser.parse_args(argv)
    text = render()
    if args.check:
        if DOC.is_file() and DOC.read_text() == text:
            return 0
        print(f"{DOC.relative_to(ROOT)} is out of date with leovr/config.py: run `python tools/config_doc.py` "
              "and commit the result.", file=sys.stderr)
        return 1
    DOC.write_text(text)
    print(f"wrote {DOC.relative_to(ROOT)} ({len(text.splitlines())} lines)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
