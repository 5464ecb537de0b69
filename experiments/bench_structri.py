"""Speed of the batched, jitted Structural Triangulation against the per-frame NumPy port.

About 20 s on 2 CPU cores. Prints one JSON object: frames/s of ST+SCA and of LEM (jax batched vs
NumPy per frame, float64, STRUCTRI17, virtual round ring), the speed-up, the max relative difference, the
compile times, and the optimistix reference's time per frame.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import time

import jax
import numpy as np

from experiments import _cli
from experiments.bench_geometry import interleaved_times
from geometry import STRUCTRI17
from structri import _solver, constrained_reference, lem_triangulation, structural_triangulation
from structri.numpy_reference import numpy_lem_triangulation, numpy_structural_triangulation


@dataclasses.dataclass(frozen=True)
class Config:
    frames: int = 10_000
    """Frames for the batched jax solvers."""
    numpy_frames: int = 200
    """Frames timed for the per-frame NumPy port (normalised to frames/s)."""
    reference_frames: int = 5
    """Frames solved by the optimistix reference (after one compiling frame)."""
    views: int = 4
    """Cameras on the round ring."""
    n_steps: int = 3
    """SCA steps of Structural Triangulation."""
    sigma: float = 6.0
    """Pixel noise standard deviation."""
    seed: int = 0
    """Seed of the poses and the noise."""
    repeats: int = 7
    """Timed rounds, each calling every contender once in turn; each one's best is kept (7: a busy spell of the
    shared 2-core VM can slow three rounds in a row)."""
    layouts: tuple[str, ...] = ()
    """Also time ST + SCA with other chunk layouts of the batched solver, each CHUNKxSTREAMS (frames per chunk x
    chunks solved side by side, e.g. 128x1 160x2), interleaved with the default layout; prints microseconds per
    frame of each (the figures behind ``structri._solver._CHUNK_FRAMES`` and ``_STREAMS``)."""
    json: bool = False
    """Print one JSON object (otherwise key: value lines)."""

    def __post_init__(self) -> None:
        for name in ("frames", "numpy_frames", "reference_frames", "views", "repeats"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        if not self.sigma >= 0:
            raise ValueError(f"--sigma must be >= 0 pixels, got {self.sigma}")
        if self.numpy_frames > self.frames or self.reference_frames >= self.frames:
            raise ValueError("--numpy-frames and --reference-frames must be fewer than --frames")
        for layout in self.layouts:
            parse_layout(layout)


def parse_layout(text: str) -> tuple[int, int]:
    """``"160x2"`` -> ``(160, 2)``: frames per chunk, chunks side by side."""
    parts = text.split("x")
    if len(parts) != 2 or not all(p.isdigit() and int(p) >= 1 for p in parts):
        raise ValueError(f"--layouts takes CHUNKxSTREAMS with positive integers (e.g. 160x2), got {text!r}")
    return int(parts[0]), int(parts[1])


def make_problem(cfg: Config):
    """Random near-T-poses (metres, y-up), the spec's round ring, noisy 2D points."""
    rng = np.random.default_rng(cfg.seed)
    by_child = {"r_hip": 0.13, "l_hip": 0.13, "r_knee": 0.45, "l_knee": 0.45, "r_ankle": 0.45, "l_ankle": 0.45,
                "spine": 0.23, "thorax": 0.25, "neck_nose": 0.10, "head": 0.12, "r_shoulder": 0.15, "l_shoulder": 0.15,
                "r_elbow": 0.28, "l_elbow": 0.28, "r_wrist": 0.25, "l_wrist": 0.25}
    lengths = np.array([by_child[STRUCTRI17.joints[c]] for _, c in STRUCTRI17.bones])
    bone_of = {c: k for k, (_, c) in enumerate(STRUCTRI17.bones)}
    poses = np.zeros((cfg.frames, 17, 3))
    poses[:, 0] = rng.normal(scale=0.05, size=(cfg.frames, 3))
    for j in STRUCTRI17.topological_order[1:]:
        d = rng.normal(size=(cfg.frames, 3))
        poses[:, j] = poses[:, STRUCTRI17.parents[j]] + lengths[bone_of[j]] * d / np.linalg.norm(d, axis=1, keepdims=True)
    theta = 2 * np.pi * np.arange(cfg.views) / cfg.views
    K = np.array([[900.0, 0.5, 500.0], [0.0, 900.0, 500.0], [0.0, 0.0, 1.0]])
    P = np.stack([K @ np.array([[np.cos(t), 0, np.sin(t), 0], [0, 1, 0, 0], [-np.sin(t), 0, np.cos(t), 2.0]])
                  for t in theta])
    h = np.einsum("vab,fjb->fvja", P[:, :, :3], poses) + P[None, :, None, :, 3]
    points = h[..., :2] / h[..., 2:] + cfg.sigma * rng.normal(size=h.shape[:-1] + (2,))
    return points, P, lengths


def _compare(name, jax_fn, numpy_fn, points, cfg):
    few = points[:cfg.numpy_frames]
    calls = {"jax": lambda: jax_fn(points), "numpy": lambda: np.stack([numpy_fn(p) for p in few])}
    seconds, first = interleaved_times(calls, cfg.repeats)
    ours, ref = np.asarray(calls["jax"]())[:cfg.numpy_frames], calls["numpy"]()
    jax_fps, numpy_fps = cfg.frames / seconds["jax"], cfg.numpy_frames / seconds["numpy"]
    return {f"{name}_jax_frames_per_s": jax_fps, f"{name}_compile_s": first["jax"] - seconds["jax"],
            f"{name}_numpy_frames_per_s": numpy_fps, f"{name}_speedup_vs_numpy": jax_fps / numpy_fps,
            f"{name}_max_rel_diff": float(np.max(np.abs(ours - ref)) / np.max(np.abs(ref)))}


def _layout_times(points, P, lengths, cfg: Config) -> dict[str, float]:
    """Microseconds per frame of ST + SCA with the default chunk layout and each of ``cfg.layouts``."""
    layouts = {"default": (_solver._CHUNK_FRAMES, _solver._STREAMS)} | {text: parse_layout(text) for text in cfg.layouts}

    def solver(layout):
        return jax.jit(lambda p: _solver._solve(p, P, lengths, STRUCTRI17, None, "st", cfg.n_steps,
                                                degenerate_rcond=1e-3, layout=layout).pose)

    calls = {name: functools.partial(solver(layout), points) for name, layout in layouts.items()}
    seconds, _ = interleaved_times(calls, cfg.repeats)
    return {name: 1e6 * s / cfg.frames for name, s in seconds.items()}


def run(cfg: Config) -> dict:
    points, P, lengths = make_problem(cfg)
    out = {"config": {k: v for k, v in dataclasses.asdict(cfg).items() if k != "json"}, "backend": jax.default_backend(), "dtype": "float64"}
    # The NumPy port is the official code, which checks no lengths.
    st = jax.jit(lambda p: structural_triangulation(p, P, lengths, n_steps=cfg.n_steps,
                                                    max_length_error=float("inf")).pose)
    out |= _compare("st", st, lambda p: numpy_structural_triangulation(p, P, lengths, n_steps=cfg.n_steps),
                    points, cfg)
    lem = jax.jit(lambda p: lem_triangulation(p, P).pose)  # metres in and out, the DLT in millimetres
    P_mm = P.copy()
    P_mm[:, :, 3] *= 1000.0
    out |= _compare("lem", lem, lambda p: numpy_lem_triangulation(p, P_mm) / 1000.0, points, cfg)
    if cfg.layouts:
        out["st_layout_us_per_frame"] = _layout_times(points, P, lengths, cfg)
    jax.block_until_ready(constrained_reference(points[0], P, lengths).pose)  # compile
    t = time.perf_counter()
    for f in range(1, cfg.reference_frames + 1):
        jax.block_until_ready(constrained_reference(points[f], P, lengths).pose)
    out["reference_s_per_frame"] = (time.perf_counter() - t) / cfg.reference_frames
    return out


def main(config: Config) -> None:
    result = run(config)
    print(json.dumps(result) if config.json else "\n".join(f"{k}: {v}" for k, v in result.items()))


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__, float64=True)
