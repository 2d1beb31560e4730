"""Camera snapshot of a scenario, without ROS: the world as the overhead camera sees it.

    python -m tsrrt_sim.snapshot --scenario clean --out out/snapshot

Loads the scenario (the arm starts in OBSERVE_POSTURE, out of the camera's view), lets the
objects settle and writes DIR/camera.png (RGB), DIR/depth.png (16-bit, millimetres) and
DIR/objects.json (true poses).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from tsrrt_common.errors import TsrrtError
from tsrrt_common.scenario import load_scenario
from tsrrt_sim.world import SimWorld

SETTLE_S = 1.0


def take_snapshot(scenario_name: str, out_dir: Path, seed: int | None = None) -> dict:
    """Write the snapshot files; returns the objects.json content."""
    scenario = load_scenario(scenario_name, seed)
    world = SimWorld(scenario)
    try:
        world.settle(SETTLE_S)
        frame = world.render()
        poses = world.object_poses(include_obstacles=True)
    finally:
        world.close()
    specs = {spec.id: spec for spec in (*scenario.objects, *scenario.obstacles)}
    content = {
        "scenario": scenario.name,
        "seed": scenario.seed,
        "sim_time": frame.sim_time,
        "frame_id": "world",
        "objects": [{"id": object_id, "class": specs[object_id].object_class,
                     "static": specs[object_id].static, "x": pose.x, "y": pose.y,
                     "theta": pose.theta} for object_id, pose in poses.items()],
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out_dir / "camera.png"), frame.rgb[:, :, ::-1]):
        raise TsrrtError(f"could not write {out_dir / 'camera.png'}")
    depth_mm = np.clip(np.round(frame.depth * 1000.0), 0, 65535).astype(np.uint16)
    cv2.imwrite(str(out_dir / "depth.png"), depth_mm)
    (out_dir / "objects.json").write_text(json.dumps(content, indent=2) + "\n")
    return content


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="clean", help="shipped scenario name or YAML path")
    parser.add_argument("--seed", type=int, default=None, help="override the placement seed")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    args = parser.parse_args(argv)
    try:
        content = take_snapshot(args.scenario, args.out, args.seed)
    except TsrrtError as error:
        print(f"snapshot: {error}", file=sys.stderr)
        return 2
    print(f"wrote {args.out / 'camera.png'}, {args.out / 'depth.png'} and "
          f"{args.out / 'objects.json'} ({len(content['objects'])} objects, scenario "
          f"{content['scenario']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
