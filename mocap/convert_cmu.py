"""Convert the CMU clips of :data:`mocap.CLIP_SOURCES` into the compact shipped ``.npz`` files.

    python -m mocap.convert_cmu --data-root /work/shared/data --out mocap/assets [--clips NAME ...]

Deterministic: the same input files give byte-identical output.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import geometry

from ._clips import CLIP_SOURCES, clip_from_motions, read_clip_sources, save_clip


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-root", required=True, help="folder holding cmu_mocap/")
    parser.add_argument("--out", required=True, help="output folder (e.g. mocap/assets)")
    parser.add_argument("--clips", nargs="*", default=sorted(CLIP_SOURCES), help="clip names")
    parser.add_argument("--fps", type=float, default=30.0)
    args = parser.parse_args(argv)
    geometry.disable_faulty_cpu_fusion()  # the configuration the shipped clips were made with
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in args.clips:
        description, people = CLIP_SOURCES[name]
        motions = read_clip_sources(args.data_root, name)
        clip = clip_from_motions(name, motions, args.fps, description,
                                 tuple("+".join(files) for files in people))
        save_clip(clip, out / f"{name}.npz")
        size = (out / f"{name}.npz").stat().st_size
        print(f"{name}: {clip.num_people} person(s), {clip.num_frames} frames at {clip.fps:g} Hz, {size} bytes")


if __name__ == "__main__":
    main()
