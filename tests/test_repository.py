"""The repository as a whole: its tracked files stay small enough to travel to the GPU machine, which takes a
working tree of at most 64 MiB (the shipped models are most of it)."""

import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TRAVEL_LIMIT = 64 * 2**20
HEADROOM = 2 * 2**20
"""Left for what a GPU session carries beside the tree (its run folders, a checkpoint to resume)."""


def test_the_tracked_tree_leaves_room_under_the_gpu_machines_limit():
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True)
    if listed.returncode != 0:
        pytest.skip("not a git checkout: the tracked files cannot be listed")
    files = [REPO / name for name in listed.stdout.decode().split("\0") if name and (REPO / name).is_file()]
    sizes = sorted(((path.stat().st_size, path.relative_to(REPO)) for path in files), reverse=True)
    total = sum(size for size, _ in sizes)
    largest = ", ".join(f"{path} {size / 2**20:.1f} MiB" for size, path in sizes[:3])
    assert total <= TRAVEL_LIMIT - HEADROOM, (
        f"the tracked files take {total / 2**20:.1f} MiB, over {(TRAVEL_LIMIT - HEADROOM) / 2**20:.0f} MiB "
        f"(largest: {largest})")
