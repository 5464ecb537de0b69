"""Structural Triangulation on virtual camera rings with real CMU poses (paper Sect. 4.1, Fig. 4/6).

The poses come from the clips shipped in mocap/assets (no data folder). ``--quick``: 2 patterns x C in
{2, 3, 4} x sigma in {2, 10}, 120 poses, under 2 minutes on 2 CPU cores; options given beside it override
those values. ``--steps 1 2 ... 12`` adds the N-step study of both readings of Algorithm 1 (the official code's
and the printed one, ``structri.structural_triangulation(multiplier_system=...)``). Writes OUT/config.json,
log.jsonl, results.json, results.md, mpjpe_vs_*.png and run.json, replacing OUT's previous outputs as a whole,
and prints results.md. Logic: :mod:`experiments.structri_study`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import tyro

from experiments import _cli
from experiments.structri_study import VirtualConfig, run_virtual

QUICK = dict(views=(2, 3, 4), sigmas=(2.0, 10.0), frames=120, reference_frames=3)
"""What --quick changes (each where the option is not given another value)."""


@dataclasses.dataclass(frozen=True)
class Config:
    out: Path
    """Output folder."""
    quick: bool = False
    """A small grid: 3 camera counts, 2 noise levels, 120 poses, 3 reference frames."""
    virtual: Annotated[VirtualConfig, tyro.conf.OmitArgPrefixes] = VirtualConfig()
    """The experiment."""

    def experiment(self) -> VirtualConfig:
        """``virtual`` with --quick's values where an option left the default."""
        if not self.quick:
            return self.virtual
        default = VirtualConfig()
        return dataclasses.replace(self.virtual, **{name: value for name, value in QUICK.items()
                                                    if getattr(self.virtual, name) == getattr(default, name)})


def main(config: Config) -> None:
    with _cli.run_folder(config.out) as out:
        run_virtual(config.experiment(), out)
    print((config.out / "results.md").read_text())


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__, float64=True)
