"""Screenshots of an .rrd recording in a headless Rerun viewer (the pictures in docs/viewer.md).

Usage:
    python scripts/viewer_screenshots.py FILE.rrd --steps 14,21 --out docs/img/viewer

Writes OUT/<file stem>_step<N>.png (1920 x 1080) with the time cursor paused at each step. Needs
the viewer extra and a graphics adapter: a GPU, or Mesa's software one on a machine without
(``apt-get install mesa-vulkan-drivers``; no display is needed). Uses rerun's experimental
``ViewerClient`` (rerun-sdk 0.41).
"""

from __future__ import annotations

import argparse
import socket
import time
from pathlib import Path

from rerun.experimental import ViewerClient

#: Seconds to let the viewer draw after the time cursor moved (a software rasteriser is slow).
SETTLE_S = 1.5


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def screenshots(rrd: Path, steps: list[int], out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    viewer = ViewerClient.spawn(headless=True, port=_free_port(), hide_welcome_screen=True)
    written = []
    try:
        viewer.open(str(rrd.resolve()))
        for step in steps:
            viewer.set_time("step", sequence=step, play_state="paused")
            time.sleep(SETTLE_S)
            path = out / f"{rrd.stem}_step{step}.png"
            viewer.save_screenshot(str(path.resolve()))
            written.append(path)
    finally:
        viewer.quit()
    return written


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rrd", type=Path, help="a recording written by packlab viz rerun")
    parser.add_argument("--steps", required=True, help="comma-separated steps, e.g. 14,21")
    parser.add_argument("--out", type=Path, default=Path("docs/img/viewer"), help="directory")
    args = parser.parse_args()
    steps = [int(s) for s in args.steps.split(",")]
    for path in screenshots(args.rrd, steps, args.out):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
