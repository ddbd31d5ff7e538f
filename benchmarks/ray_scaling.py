"""Ray scale-out, measured: the same render shards on a local Ray cluster of one worker node, then of two.

Each node offers one CPU (`ray start --num-cpus 1`) and each task renders with one Cycles thread (the Ray
default of `--threads`), so on a machine with two free cores the ideal throughput ratio is 2. The cluster is
started the documented way (`ray start --head`, a second `ray start --address`), the render is the user's
command with `--executor ray --ray-address`, and the two runs' files are compared byte for byte.
Prints figures, asserts nothing: `.venv/bin/python benchmarks/ray_scaling.py [--robots A+B,...] [--frames N]`.
"""

import argparse
import filecmp
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from kernel.bop import DATASET_INFO

PORT = 6391
RAY = str(Path(sys.executable).with_name("ray"))
ENV = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "token"}  # as docs/syneepose.md says


def ray_cmd(*args: str) -> None:
    subprocess.run([RAY, *args], env=ENV, check=True, capture_output=True)


def wait_for_cpus(address: str, cpus: int, timeout: float = 60.0) -> None:
    os.environ.update(ENV)  # read when ray is imported
    import ray

    ray.init(address=address, log_to_driver=False)
    try:
        deadline = time.time() + timeout
        while ray.cluster_resources().get("CPU", 0) < cpus:
            if time.time() > deadline:
                raise RuntimeError(f"the Ray cluster at {address} did not reach {cpus} CPUs")
            time.sleep(0.5)
    finally:
        ray.shutdown()


def render(address: str, out: Path, robots: str, frames: int) -> float:
    cmd = [sys.executable, "-m", "syneepose", "render", "--preset", "mini", "--robots", robots, "--frames",
           str(frames), "--out", str(out), "--executor", "ray", "--ray-address", address]
    start = time.perf_counter()
    subprocess.run(cmd, env=ENV, check=True, capture_output=True)
    return time.perf_counter() - start


def same_files(a: Path, b: Path) -> tuple[int, list[str]]:
    names = sorted(str(p.relative_to(a)) for p in a.rglob("*") if p.is_file() and p.name != DATASET_INFO)
    return len(names), [n for n in names if not filecmp.cmp(a / n, b / n, shallow=False)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", default="ur5e+robotiq_2f85,panda+panda_hand,ur10e+robotiq_2f140,panda+kinova_3f")
    parser.add_argument("--frames", type=int, default=8)
    args = parser.parse_args()
    address = f"127.0.0.1:{PORT}"
    frames = len(args.robots.split(",")) * args.frames
    with tempfile.TemporaryDirectory() as tmp:
        try:
            ray_cmd("start", "--head", "--num-cpus", "1", "--port", str(PORT), "--include-dashboard", "false")
            wait_for_cpus(address, 1)
            one = render(address, Path(tmp) / "one", args.robots, args.frames)
            ray_cmd("start", "--address", address, "--num-cpus", "1")
            wait_for_cpus(address, 2)
            two = render(address, Path(tmp) / "two", args.robots, args.frames)
        finally:
            ray_cmd("stop", "--force")
        count, differ = same_files(Path(tmp) / "one", Path(tmp) / "two")
    print(f"mini, {len(args.robots.split(','))} segments x {args.frames} frames ({frames} frames), one Cycles thread "
          f"per task: 1 node {one:.1f} s ({one / frames:.2f} s/frame), 2 nodes {two:.1f} s ({two / frames:.2f} "
          f"s/frame); throughput x{one / two:.2f}; {count} files, {len(differ)} differ"
          + (f" ({', '.join(differ[:5])})" if differ else ""))


if __name__ == "__main__":
    main()
