"""Write the perception figure of one hard bench state per noise preset (docs/img/perception/).

Usage: python scripts/perception_figures.py [--out docs/img/perception] [--case 0]

The state: a packlab-bench-v1 hard case packed by its perfect plan up to half its objects, the
next ``buffer_size`` objects shown; perception with depth segmentation (the classical one).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from packlab.bench.suites import load_suite
from packlab.sim.heightmap import rasterise_poses
from packlab.sim.sensing import perceive_state
from packlab.sim.sensing.scene import planned_scene
from packlab.viz.perception import perception_figure
from packlab.viz.plots import save_figure


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/img/perception")
    parser.add_argument("--case", type=int, default=0)
    args = parser.parse_args()
    case = [c for c in load_suite("packlab-bench-v1") if c.difficulty == "hard"][args.case]
    sizes, positions, quats = planned_scene(case)
    order = [[b.internal_id for b in case.objects].index(s.internal_id) for s in case.gt_plan]
    later = order[len(order) // 2 :]
    positions[later] = np.nan  # half packed
    shown = sizes[later[: case.buffer_size]].astype(int)
    placed = np.all(np.isfinite(positions), axis=1)
    exact = rasterise_poses(
        case.container.cells,
        case.container.cell_xy_mm,
        sizes[placed],
        positions[placed],
        quats[placed],
    )
    out = Path(args.out)
    for name in ("none", "structured-light", "stereo"):
        state = perceive_state(
            case.container, sizes, positions, quats, shown, name, np.random.default_rng(0), "depth"
        )
        fig = perception_figure(state, exact, f"{case.episode_id}, {name}:")
        print(save_figure(fig, out / f"perception-{name}.png"))


if __name__ == "__main__":
    main()
