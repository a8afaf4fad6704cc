"""Write tests/data/held_digests.json: the SHA-256 of every held case's bytes (the cases and
when to rewrite them are in tests/test_bytes_held.py's docstring: only after an intended
format change, with a changelog entry in docs/spec.md).

Usage: ``.venv/bin/python scripts/hold_digests.py [--check | --add]``. Each case is made in a
fresh temporary folder. The file holds digests per machine numerics (``numerics()``); a plain
run replaces every machine's with this one's (after a format change: the other machines'
digests are then recorded on them with ``--add``); ``--add`` records this machine's beside the
others (run it in a worktree of a commit whose digests held); with ``--check`` nothing is
written and the exit status is 1 when any case's digests differ from this machine's in the file
(each differing case is named, with its old and new sizes).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_bytes_held import CASES, DIGESTS, Digests, held_digests, numerics, recorded_all


def made() -> dict[str, Digests]:
    """Every case's digests, made now."""
    digests = {}
    for name in sorted(CASES):
        with tempfile.TemporaryDirectory(prefix="tsog-held-") as folder:
            digests[name] = held_digests(name, Path(folder))
        sizes = ", ".join(f"{artifact} {d['bytes']} B" for artifact, d in digests[name].items())
        print(f"{name}: {sizes}")
    return digests


def differences(old: dict[str, Digests], new: dict[str, Digests]) -> list[str]:
    """One line per case that differs between the file and a fresh run."""
    lines = []
    for name in sorted(old.keys() | new.keys()):
        before, after = old.get(name), new.get(name)
        if before == after:
            continue
        if before is None or after is None:
            lines.append(f"{name}: {'new' if before is None else 'gone'}")
            continue
        for artifact in sorted(before.keys() | after.keys()):
            if before.get(artifact) != after.get(artifact):
                sizes = [d.get(artifact, {}).get("bytes") for d in (before, after)]
                lines.append(f"{name} {artifact}: {sizes[0]} -> {sizes[1]} bytes, digest differs")
    return lines


def main() -> int:
    """Make the digests, then write them or compare them with the file."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    how = parser.add_mutually_exclusive_group()
    how.add_argument("--check", action="store_true", help="compare with the file, write nothing")
    how.add_argument("--add", action="store_true", help="add this machine's, keep the others'")
    args = parser.parse_args()
    new = made()
    every = recorded_all() if DIGESTS.exists() else {}
    if args.check:
        old = every.get(numerics(), {})
        lines = differences(old, new)
        for line in lines:
            print(line, file=sys.stderr)
        print(f"{len(new)} cases made, {len(lines)} differences from {DIGESTS.name}")
        return 1 if lines else 0
    every = {**every, numerics(): new} if args.add else {numerics(): new}
    DIGESTS.write_text(json.dumps(every, indent=1, sort_keys=True) + "\n")
    print(f"wrote {DIGESTS.relative_to(DIGESTS.parents[2])}: {len(new)} cases for {numerics()}")
    return 0


if __name__ == "__main__":  # the encoder's process pool imports this module again
    sys.exit(main())
