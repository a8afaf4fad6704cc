"""Screenshots of the web player in headless Debian chromium: docs/player.png and docs/views/.

Usage: .venv/bin/python scripts/player_screenshot.py [--out docs/player.png] [--t 2.2]
       .venv/bin/python scripts/player_screenshot.py --input CAPTURE.splatv --t 0.5 \\
           --out docs/views/NAME.png [--bare]
Without --input, generates the demo's kind of scene (seeded) with its rig cameras; with it,
segments that input as `tsog segment` does. Serves it on 127.0.0.1 with our server, opens
/play/{scene} at t, paused, in its opening view, and saves a 960x540 screenshot (--bare: the
overlay and controls hidden).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from browser import COVERED, HIDE_UI, chromium
from helpers import ThreadedServer
from tsog_stream.cli.main import main as tsog
from tsog_stream.segment import SegmentOptions, segment_scene
from tsog_stream.server import make_app
from tsog_stream.synthetic import SceneSpec, generate_scene, rig_cameras


def main() -> int:
    """Make or segment the scene, serve it, take the screenshot."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/player.png"))
    parser.add_argument("--t", type=float, default=2.2, help="time shown, seconds")
    parser.add_argument("--input", type=Path, help="a capture to segment (default: generated)")
    parser.add_argument("--bare", action="store_true", help="hide the overlay and controls")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        if args.input is None:
            spec = SceneSpec(background=6000, objects=8, per_object=600, seed=1)
            scene = generate_scene(spec)
            options = SegmentOptions(window_s=1.0)
            segment_scene(scene, root / "demo.tsogs", options, cameras=rig_cameras())
        elif tsog(["segment", str(args.input), "-o", str(root / "demo.tsogs"), "-q"]) != 0:
            return 1
        server = ThreadedServer(make_app(root))
        try:
            with chromium() as browser:
                page = browser.new_page(viewport={"width": 960, "height": 540})
                page.goto(f"http://127.0.0.1:{server.port}/play/demo?t={args.t}&paused")
                page.wait_for_function(COVERED, timeout=60_000)
                if args.bare:
                    page.add_style_tag(content=HIDE_UI)
                time.sleep(2)  # the overlay refreshes five times a second; the sort settles
                args.out.parent.mkdir(parents=True, exist_ok=True)
                page.screenshot(path=str(args.out))
        finally:
            server.stop()
    print(f"{args.out}: written")
    return 0


if __name__ == "__main__":
    sys.exit(main())
