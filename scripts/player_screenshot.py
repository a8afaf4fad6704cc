"""Write docs/player.png: the web player on a generated scene, in headless Debian chromium.

Usage: .venv/bin/python scripts/player_screenshot.py [--out docs/player.png] [--t 2.2]
Generates the demo's kind of scene (seeded), segments it, serves it on 127.0.0.1 with our
server, opens /play/{scene} at t with the controls showing and saves a 960x540 screenshot.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from browser import COVERED, chromium
from helpers import ThreadedServer
from tsog_stream.segment.segmenter import SegmentOptions, segment_scene
from tsog_stream.server import make_app
from tsog_stream.synthetic import SceneSpec, generate_scene


def main() -> int:
    """Make the scene, serve it, take the screenshot."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/player.png"))
    parser.add_argument("--t", type=float, default=2.2, help="time shown, seconds")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        spec = SceneSpec(background=6000, objects=8, per_object=600, seed=1)
        segment_scene(generate_scene(spec), root / "demo.tsogs", SegmentOptions(window_s=1.0))
        server = ThreadedServer(make_app(root))
        try:
            with chromium() as browser:
                page = browser.new_page(viewport={"width": 960, "height": 540})
                url = f"http://127.0.0.1:{server.port}/play/demo?t={args.t}&paused&yaw=25&pitch=-18&distance=11"
                page.goto(url)
                page.wait_for_function(COVERED, timeout=30_000)
                time.sleep(2)  # the overlay refreshes five times a second; the sort settles
                page.screenshot(path=str(args.out))
        finally:
            server.stop()
    print(f"{args.out}: written")
    return 0


if __name__ == "__main__":
    sys.exit(main())
