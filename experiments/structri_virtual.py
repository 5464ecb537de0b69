"""Structural Triangulation on virtual camera rings with real CMU poses (paper Sect. 4.1, Fig. 4/6).

Run: ``.venv/bin/python -m experiments.structri_virtual --out runs/structri_virtual [--quick]``
(--quick: 2 patterns x C in {2, 3, 4} x sigma in {2, 10}, 120 poses, under 2 minutes on 2 CPU cores).
Writes DIR/config.json, DIR/log.jsonl, DIR/results.json, DIR/results.md, DIR/mpjpe_vs_*.png.
Logic: :mod:`experiments.structri_study`.
"""

import argparse
import dataclasses
import os

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_experimental_ynn_fusion_type=")

from experiments.structri_study import VirtualConfig, run_virtual  # noqa: E402

QUICK = dict(views=(2, 3, 4), sigmas=(2.0, 10.0), frames=120, reference_frames=3)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True, help="output folder (created)")
    parser.add_argument("--quick", action="store_true", help=f"small grid: {QUICK}")
    parser.add_argument("--data-root", default=None,
                        help="unused: the poses come from the clips shipped in mocap/assets (kept for a uniform CLI)")
    for f in dataclasses.fields(VirtualConfig):
        kind = type(f.default)
        if kind is tuple:
            parser.add_argument(f"--{f.name.replace('_', '-')}", nargs="*", default=None,
                                help=f"{f.name} (default {f.default})")
        elif kind is bool:
            parser.add_argument(f"--{f.name.replace('_', '-')}", type=lambda s: s.lower() in ("1", "true", "yes"),
                                default=None, help=f"{f.name} true/false (default {f.default})")
        else:
            parser.add_argument(f"--{f.name.replace('_', '-')}", type=kind, default=None, help=f"{f.name} (default {f.default})")
    args = vars(parser.parse_args(argv))
    out, quick = args.pop("out"), args.pop("quick")
    args.pop("data_root")
    cfg = dataclasses.replace(VirtualConfig(), **(QUICK if quick else {}))
    casts = {"views": int, "sigmas": float, "patterns": str, "clips": str}
    overrides = {k: (tuple(map(casts[k], v)) if k in casts else v) for k, v in args.items() if v is not None}
    run_virtual(dataclasses.replace(cfg, **overrides), out)


if __name__ == "__main__":
    main()
