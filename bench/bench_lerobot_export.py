"""LeRobot v3.0 export and import: seconds and bytes per episode, against the MCAP demo files they come from.

Records scripted demos of a task (not timed), then times ``c2farm export lerobot``'s work (read the
MCAP files, PNG-encode the images, write parquet and statistics) and ``c2farm import lerobot``'s
(decode, rebuild the points, write MCAP) for each camera set:

    .venv/bin/python bench/bench_lerobot_export.py --episodes 5
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from actors.demos.generate import generate_demos
from deploy.lerobot_dataset import export_dataset, import_dataset


def folder_bytes(root: Path) -> int:
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--task", default="reach_target")
    ap.add_argument("--episodes", type=int, default=5, help="demos per camera set")
    ap.add_argument("--image-size", type=int, default=128)
    ap.add_argument("--camera-sets", default="front;front,left_shoulder,right_shoulder,wrist",
                    help="camera sets separated by ';' (default: cpu-small's one camera, the paper's four)")
    args = ap.parse_args()
    print(f"{args.task}, {args.episodes} demos per camera set, {args.image_size} px")
    print("| cameras | frames/episode | export s/episode | import s/episode | MB/episode (LeRobot) "
          "| MB/episode (MCAP) |")
    print("|---|---|---|---|---|---|")
    for cams in args.camera_sets.split(";"):
        cameras = tuple(cams.split(","))
        with tempfile.TemporaryDirectory() as tmp:
            root = Path(tmp)
            summary = generate_demos(args.task, args.episodes, 1, root / "demos", cameras=cameras,
                                     image_size=args.image_size, progress=False)
            files = [Path(p) for p in summary.written]
            t0 = time.perf_counter()
            episodes, frames = export_dataset(files, root / "ds", "bench")
            export_s = (time.perf_counter() - t0) / episodes
            t0 = time.perf_counter()
            import_dataset(root / "ds", root / "back")
            import_s = (time.perf_counter() - t0) / episodes
            lerobot_mb = folder_bytes(root / "ds") / episodes / 1e6
            mcap_mb = sum(p.stat().st_size for p in files) / episodes / 1e6
        print(f"| {len(cameras)} ({cams}) | {frames / episodes:.0f} | {export_s:.2f} | {import_s:.2f} "
              f"| {lerobot_mb:.2f} | {mcap_mb:.2f} |")


if __name__ == "__main__":
    main()
