"""Write docs/schema/*.schema.json from the pydantic models (deterministic output).

Usage: ``python scripts/export_schemas.py [--check]``. With ``--check`` nothing is written and
the exit status is 1 when a committed file differs from a fresh export.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tsog_stream.schemas import meta_json_schema_text, sh_bands_json_schema_text
from tsog_stream.schemas.manifest import manifest_json_schema_text

ROOT = Path(__file__).resolve().parent.parent
SCHEMAS = {
    ROOT / "docs" / "schema" / "meta.schema.json": meta_json_schema_text,
    ROOT / "docs" / "schema" / "manifest.schema.json": manifest_json_schema_text,
    ROOT / "docs" / "schema" / "sh-bands.schema.json": sh_bands_json_schema_text,
}


def main(argv: list[str] | None = None) -> int:
    """Export (or with --check, compare) the meta.json schema; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare instead of writing")
    args = parser.parse_args(argv)
    stale = 0
    for target, export in SCHEMAS.items():
        text = export()
        if args.check:
            current = target.read_text(encoding="utf-8") if target.exists() else ""
            if current != text:
                print(f"{target} is stale; run scripts/export_schemas.py", file=sys.stderr)
                stale = 1
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        with target.open("w", encoding="utf-8", newline="\n") as out:
            out.write(text)
        print(f"wrote {target.relative_to(ROOT)}")
    return stale


if __name__ == "__main__":
    raise SystemExit(main())
