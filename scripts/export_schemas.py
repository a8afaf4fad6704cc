"""Write docs/schema/meta.schema.json from the pydantic models (deterministic output).

Usage: ``python scripts/export_schemas.py [--check]``. With ``--check`` nothing is written and
the exit status is 1 when the committed file differs from a fresh export.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tsog_stream.schemas import meta_json_schema_text

ROOT = Path(__file__).resolve().parent.parent
TARGET = ROOT / "docs" / "schema" / "meta.schema.json"


def main(argv: list[str] | None = None) -> int:
    """Export (or with --check, compare) the meta.json schema; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare instead of writing")
    args = parser.parse_args(argv)
    text = meta_json_schema_text()
    if args.check:
        current = TARGET.read_text(encoding="utf-8") if TARGET.exists() else ""
        if current != text:
            print(f"{TARGET} is stale; run scripts/export_schemas.py", file=sys.stderr)
            return 1
        return 0
    TARGET.parent.mkdir(parents=True, exist_ok=True)
    with TARGET.open("w", encoding="utf-8", newline="\n") as out:
        out.write(text)
    print(f"wrote {TARGET.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
