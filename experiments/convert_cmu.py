"""Convert the CMU clips of :data:`mocap.CLIP_SOURCES` into the compact shipped ``.npz`` files.

    python -m experiments.convert_cmu --data-root /work/shared/data --out mocap/assets [--clips NAME ...]

Deterministic: the same input files give byte-identical output. Each file is written whole (a partial file
replaced at the end).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mocap
import training
from experiments import _cli


@dataclasses.dataclass(frozen=True)
class Config:
    out: Path
    """Output folder (e.g. mocap/assets)."""
    data_root: Path | None = None
    """Folder holding cmu_mocap/ (default: $MVMOCAP_DATA_ROOT)."""
    clips: tuple[str, ...] = tuple(sorted(mocap.CLIP_SOURCES))
    """Clip names (keys of mocap.CLIP_SOURCES)."""
    fps: float = 30.0
    """Frame rate the clips are resampled to."""

    def __post_init__(self) -> None:
        unknown = sorted(set(self.clips) - set(mocap.CLIP_SOURCES))
        if unknown:
            raise ValueError(f"unknown clips {unknown}; known: {sorted(mocap.CLIP_SOURCES)}")
        if self.fps <= 0:
            raise ValueError(f"--fps must be > 0, got {self.fps}")
        if mocap.find_data_root(self.data_root, "cmu_mocap") is None:
            raise ValueError("no data folder: pass --data-root or set $MVMOCAP_DATA_ROOT (a folder with cmu_mocap/)")


def main(config: Config) -> None:
    data_root = mocap.find_data_root(config.data_root, "cmu_mocap")
    config.out.mkdir(parents=True, exist_ok=True)
    for name in config.clips:
        description, people = mocap.CLIP_SOURCES[name]
        motions = mocap.read_clip_sources(data_root, name)
        clip = mocap.clip_from_motions(name, motions, config.fps, description,
                                       tuple("+".join(files) for files in people))
        path = config.out / f"{name}.npz"
        training.write_atomically(path, lambda file: mocap.save_clip(clip, file))
        print(f"{name}: {clip.num_people} person(s), {clip.num_frames} frames at {clip.fps:g} Hz, "
              f"{path.stat().st_size} bytes")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__)
