#!/usr/bin/env python3
"""Write the generated docs: docs/benchmarks.md (from docs/results/*.json), docs/config.md (from the config
models) and docs/cli.md (from the typer app).

    python tools/gen_docs.py           # rewrite all three
    python tools/gen_docs.py --check   # exit 1 if one is not what it would write
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def generated() -> dict[Path, str]:
    """Each generated file and the text it should hold."""
    from leovr.bench.report import render as benchmarks
    from leovr.cli_doc import render as cli
    from leovr.config_doc import render as config
    from leovr.config_doc import render_bench as bench_config

    docs = ROOT / "docs"
    return {
        docs / "benchmarks.md": benchmarks(docs / "results"),
        docs / "config.md": config(),
        docs / "bench_config.md": bench_config(),
        docs / "cli.md": cli(),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only check that the files are up to date")
    args = parser.parse_args(argv)
    stale = []
    for path, text in generated().items():
        name = path.relative_to(ROOT)
        if args.check:
            if not path.is_file() or path.read_text() != text:
                stale.append(str(name))
            continue
        path.write_text(text)
        print(f"wrote {name} ({len(text.splitlines())} lines)")
    if stale:
        print(f"out of date: {', '.join(stale)}: run `python tools/gen_docs.py` and commit the result", file=sys.stderr)
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
