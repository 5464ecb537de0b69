"""Structural Triangulation: against the plain NumPy port, the certified optimistix reference, the
paper's qualitative claims (anchor table, spec section 7), and the robustness contract."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from geometry import STRUCTRI17, Skeleton, bone_lengths, structri_virtual_rig
from experiments.structri_study import VirtualConfig, run_virtual
from structri import (Status, constrained_reference, estimate_bone_lengths, lagrangian_triangulation,
                      lem_triangulation, ls_triangulation, reduced_objective, reduced_problem,
                      structural_triangulation)
from structri._solver import StructriResult, _padded_frames, _solve, _solve_flat, _solve_symmetric
from structri.numpy_reference import numpy_lem_triangulation, numpy_structural_triangulation_frames

# H36M-like constant lengths in metres: thigh/shin 0.45, upper arm 0.28, forearm 0.25.
_LENGTH = {"r_hip": 0.13, "l_hip": 0.13, "r_knee": 0.45, "l_knee": 0.45, "r_ankle": 0.45, "l_ankle": 0.45,
           "spine": 0.23, "thorax": 0.25, "neck_nose": 0.10, "head": 0.12, "r_shoulder": 0.15, "l_shoulder": 0.15,
           "r_elbow": 0.28, "l_elbow": 0.28, "r_wrist": 0.25, "l_wrist": 0.25}
_DIRECTION = {"r_hip": (-1, 0, 0), "l_hip": (1, 0, 0), "r_knee": (0, -1, 0), "l_knee": (0, -1, 0),
              "r_ankle": (0, -1, 0), "l_ankle": (0, -1, 0), "spine": (0, 1, 0), "thorax": (0, 1, 0),
              "neck_nose": (0, 1, 0), "head": (0, 1, 0), "r_shoulder": (-1, 0, 0), "l_shoulder": (1, 0, 0),
              "r_elbow": (-1, -0.3, 0), "l_elbow": (1, -0.3, 0), "r_wrist": (-1, -0.3, 0.2), "l_wrist": (1, -0.3, 0.2)}
LENGTHS = np.array([_LENGTH[STRUCTRI17.joints[c]] for _, c in STRUCTRI17.bones])


def synthetic_poses(frames, rng, root_spread=0.05):
    """y-up poses around a T-pose with exact constant bone lengths, pelvis near the origin (metres)."""
    poses = np.zeros((frames, STRUCTRI17.num_joints, 3))
    poses[:, 0] = rng.normal(scale=root_spread, size=(frames, 3))
    for j in STRUCTRI17.topological_order[1:]:
        d = np.array(_DIRECTION[STRUCTRI17.joints[j]], float) + 0.4 * rng.normal(size=(frames, 3))
        unit = d / np.linalg.norm(d, axis=1, keepdims=True)
        poses[:, j] = poses[:, STRUCTRI17.parents[j]] + _LENGTH[STRUCTRI17.joints[j]] * unit
    return poses


def virtual_rig(views, pattern, unit=1.0):
    """Spec section 5 (y-up data): R_y(theta_i), t = [0, 0, 2 m], f = 900 px, skew 0.5."""
    return structri_virtual_rig(views, pattern, up_axis="y", distance=2.0 * unit)


def observe(rig, poses, sigma, rng):
    P = np.einsum("vab,vbc->vac", np.asarray(rig.K), np.concatenate([np.asarray(rig.R), np.asarray(rig.t)[..., None]], -1))
    h = np.einsum("vab,fjb->fvja", P[:, :, :3], poses) + P[None, :, None, :, 3]
    return h[..., :2] / h[..., 2:] + sigma * rng.normal(size=h.shape[:-1] + (2,)), P


def mpjpe(a, b):
    return float(np.mean(np.linalg.norm(np.asarray(a) - b, axis=-1)))


# Every solver call below on ``scene`` takes all FRAMES frames (slicing the result where fewer are checked), and the
# other synthetic scenes have FRAMES frames too: equal shapes and options share one compilation within this module.
FRAMES = 24


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(0)
    poses = synthetic_poses(FRAMES, rng)
    rig = virtual_rig(4, "round")
    points, P = observe(rig, poses, 6.0, rng)
    return poses, rig, points, P


def test_matches_numpy_reference(scene):
    poses, rig, points, P = scene
    for steps in (1, 3, 5):  # 5 > _UNROLLED_MAX_STEPS: the looped eliminations
        ours = structural_triangulation(points, rig, LENGTHS, n_steps=steps)
        ref = numpy_structural_triangulation_frames(points, P, LENGTHS, n_steps=steps)
        np.testing.assert_allclose(ours.pose, ref, rtol=0, atol=1e-6 * np.max(np.abs(ref)))
        assert np.all(np.asarray(ours.status) == Status.OK)
    squared = structural_triangulation(points, rig, LENGTHS, n_steps=3, schedule="squared")
    ref = numpy_structural_triangulation_frames(points, P, LENGTHS, n_steps=3, schedule="squared")
    np.testing.assert_allclose(squared.pose, ref, rtol=0, atol=1e-6 * np.max(np.abs(ref)))
    ls = ls_triangulation(points, P)
    ref = numpy_structural_triangulation_frames(points, P, LENGTHS, method="LS")
    np.testing.assert_allclose(ls.pose, ref, rtol=0, atol=1e-6 * np.max(np.abs(ref)))
    # LEM runs the official DLT in millimetres (it is not unit-invariant): metres in, metres out.
    P_mm = P.copy()
    P_mm[:, :, 3] *= 1000.0
    lem = np.asarray(lem_triangulation(points[:4], P).pose)
    np.testing.assert_allclose(lem, np.stack([numpy_lem_triangulation(p, P_mm) / 1000.0 for p in points[:4]]),
                               rtol=0, atol=1e-6 * np.max(np.abs(lem)))
    in_metres = np.asarray(lem_triangulation(points[:4], P, millimetres_per_unit=1.0).pose)
    np.testing.assert_allclose(in_metres[0], numpy_lem_triangulation(points[0], P), rtol=0, atol=1e-8)
    assert np.max(np.abs(in_metres - lem)) > 1e-3  # the unit matters


@pytest.mark.parametrize("schedule", ["length", "squared"])
def test_printed_algorithm_variant_matches_numpy_reference(scene, schedule):
    """``multiplier_system="initial"`` (T^(0) in Algorithm 1's line 6) against the dense NumPy port of the same
    variant; it is a different method from the code's T^(i-1) from the second step on."""
    _, _, points, P = scene
    ours = structural_triangulation(points, P, LENGTHS, n_steps=3, schedule=schedule, multiplier_system="initial",
                                    max_length_error=float("inf"))
    ref = numpy_structural_triangulation_frames(points, P, LENGTHS, n_steps=3, schedule=schedule,
                                                multiplier_system="initial")
    np.testing.assert_allclose(ours.pose, ref, rtol=0, atol=1e-9 * np.max(np.abs(ref)))
    code = numpy_structural_triangulation_frames(points, P, LENGTHS, n_steps=3, schedule=schedule)
    assert np.max(np.abs(ref - code)) > 1e-6
    one_step = [structural_triangulation(points, P, LENGTHS, n_steps=1, multiplier_system=system).pose
                for system in ("current", "initial")]
    np.testing.assert_array_equal(*one_step)


def test_reduced_problem_matches_sparse_inverse(scene):
    """A from the official (GQ)^T D (GQ) route and b0 = A^-1 beta equal the per-joint LS bones."""
    _, _, points, P = scene
    A, beta = reduced_problem(points[0], P)
    b0 = np.linalg.solve(np.asarray(A), np.asarray(beta)).reshape(-1, 3)
    np.testing.assert_allclose(b0, ls_triangulation(points[0], P).bones, rtol=1e-9, atol=1e-12)


def test_traced_inside_a_callers_jit_equals_a_direct_call(scene):
    """A caller's jit traces the solver with abstract points (no value-dependent Python branches may run); the
    direct call is checked against the NumPy port above. (Running it op by op under ``jax.disable_jit`` took 29 s
    of the suite and checked the same.)"""
    _, rig, points, _ = scene
    jitted = jax.jit(lambda p: structural_triangulation(p, rig, LENGTHS, n_steps=2).pose)(points[:2])
    direct = structural_triangulation(points[:2], rig, LENGTHS, n_steps=2).pose
    np.testing.assert_allclose(jitted, direct, rtol=1e-10, atol=1e-12)


def test_chunks_solved_side_by_side_equal_one_chunk(scene):
    """Chunks of 5 frames, two side by side, the last step padded (the layout a 10k-frame batch takes, at a size the
    suite can afford) give per frame what one chunk of all frames gives."""
    _, _, points, P = scene
    def solve(layout):
        return _solve(points, P, LENGTHS, STRUCTRI17, None, "st", 3, degenerate_rcond=1e-3, layout=layout)
    whole, side_by_side = solve((FRAMES, 1)), solve((5, 2))
    for name in StructriResult._fields:
        np.testing.assert_allclose(getattr(side_by_side, name), getattr(whole, name), rtol=1e-12, atol=1e-14,
                                   err_msg=name)


def test_inputs_of_nearby_lengths_share_one_compilation(scene):
    """Frames are padded to a power of two below one round of chunks, else to whole rounds: 5 and 7 frames run
    one compiled program, and each frame's result is the one it gets in a longer input."""
    _, _, points, P = scene
    assert [_padded_frames(f, (160, 2)) for f in (1, 5, 8, 9, 256, 257, 320, 321, 900)] == [
        1, 8, 8, 16, 256, 320, 320, 640, 960]
    def solve(frames):
        return _solve(points[:frames], P, LENGTHS, STRUCTRI17, None, "st", 2, degenerate_rcond=1e-3)
    longest = solve(FRAMES)
    compiled = _solve_flat._cache_size()
    five, seven = solve(5), solve(7)
    assert _solve_flat._cache_size() == compiled + 1
    for part in (five, seven):
        for name in StructriResult._fields:
            np.testing.assert_allclose(getattr(part, name), getattr(longest, name)[:len(part.pose)], rtol=1e-9,
                                       atol=1e-12, err_msg=name)


@pytest.mark.parametrize("pattern,views", [("round", 3), ("half", 2)])
def test_anchor_ordering_in_millimetres(pattern, views):
    """Spec section 7 (official code works in mm): ST < LS < LEM in MPJPE, ST <= LEM in most frames,
    and the bone lengths of ST within a fraction of a millimetre."""
    rng = np.random.default_rng(1)
    poses = 1000.0 * synthetic_poses(FRAMES, rng)
    points, P = observe(virtual_rig(views, pattern, unit=1000.0), poses, 6.0, rng)
    st = structural_triangulation(points, P, 1000.0 * LENGTHS)
    ls, lem = ls_triangulation(points, P), lem_triangulation(points, P, millimetres_per_unit=1.0)
    assert mpjpe(st.pose, poses) < mpjpe(ls.pose, poses) < mpjpe(lem.pose, poses)
    per_frame = lambda r: np.mean(np.linalg.norm(np.asarray(r.pose) - poses, axis=-1), axis=-1)  # noqa: E731
    assert np.mean(per_frame(st) <= per_frame(lem)) >= 0.8
    assert np.mean(np.abs(np.linalg.norm(np.asarray(st.bones), axis=-1) - 1000.0 * LENGTHS)) < 0.5
    lagrangian = lagrangian_triangulation(points, P, 1000.0 * LENGTHS, millimetres_per_unit=1.0)
    assert abs(mpjpe(lagrangian.pose, poses) - mpjpe(ls.pose, poses)) < 1.0


def test_bone_length_error_at_two_pixels():
    rng = np.random.default_rng(2)
    poses = synthetic_poses(FRAMES, rng)
    points, P = observe(virtual_rig(4, "round"), poses, 2.0, rng)
    st = structural_triangulation(points, P, LENGTHS)
    assert np.max(np.abs(np.linalg.norm(np.asarray(st.bones), axis=-1) - LENGTHS)) < 0.5e-3
    np.testing.assert_allclose(bone_lengths(st.pose, STRUCTRI17), np.linalg.norm(np.asarray(st.bones), axis=-1),
                               atol=1e-12)


def test_against_certified_reference(scene):
    poses, _, points, P = scene
    st = jax.tree.map(lambda x: x[:4], structural_triangulation(points, P, LENGTHS))  # the first 4 frames
    exact = structural_triangulation(points[:4], P, LENGTHS, update="exact")
    ls = ls_triangulation(points, P)
    gaps, pose_gaps = [], []
    for f in range(4):
        ref = constrained_reference(points[f], P, LENGTHS)
        assert bool(ref.certified), (float(ref.kkt_residual), float(ref.reduced_hessian_min_eigenvalue))
        A, beta = reduced_problem(points[f], P)
        objective = lambda b: float(reduced_objective(A, beta, b))  # noqa: E731
        gaps.append(abs(objective(st.bones[f]) - objective(ref.bones)) / (objective(ref.bones) - objective(ls.bones[f])))
        pose_gaps.append(np.max(np.abs(np.asarray(st.pose[f] - ref.pose))))
        np.testing.assert_allclose(np.linalg.norm(np.asarray(ref.bones), axis=-1), LENGTHS, rtol=1e-9)
    assert np.median(gaps) < 0.01
    assert np.max(pose_gaps) < 5e-3  # metres
    violation = lambda r: np.abs(np.linalg.norm(np.asarray(r.bones), axis=-1) - LENGTHS)  # noqa: E731
    assert np.max(violation(exact)) <= np.max(violation(st))
    assert np.max(violation(st)) < 2e-3


def test_reference_runs_in_float64_in_a_float32_session(scene):
    """The oracle enables 64-bit types for its own call only: a float32 session gets the certified float64
    optimum (the same one as in float64 sessions) and keeps its float32 setting."""
    _, _, points, P = scene
    in_float64 = constrained_reference(points[0], P, LENGTHS)
    with jax.enable_x64(False):
        ref = constrained_reference(points[0], P, LENGTHS)
        assert not jax.config.jax_enable_x64
    assert ref.pose.dtype == ref.bones.dtype == jnp.float64
    assert bool(ref.certified)
    np.testing.assert_allclose(ref.pose, in_float64.pose, rtol=0, atol=1e-12)


def test_schedules_and_single_step_agree_at_one_step(scene):
    _, _, points, P = scene
    a = structural_triangulation(points, P, LENGTHS, n_steps=1)
    b = structural_triangulation(points, P, LENGTHS, n_steps=1, schedule="squared")
    np.testing.assert_allclose(a.pose, b.pose, rtol=1e-12, atol=1e-12)
    c = structural_triangulation(points, P, LENGTHS, n_steps=3, schedule="squared")
    assert np.max(np.abs(np.linalg.norm(np.asarray(c.bones), axis=-1) - LENGTHS)) < 2e-3


def test_estimated_lengths_symmetric(scene):
    _, _, points, P = scene
    est = np.asarray(estimate_bone_lengths(points, P, STRUCTRI17, frames=np.arange(12)))
    for k, (_, child) in enumerate(STRUCTRI17.bones):
        mirror = [i for i, (_, c) in enumerate(STRUCTRI17.bones) if c == STRUCTRI17.mirror[child]][0]
        assert est[k] == pytest.approx(est[mirror], rel=1e-12)
    np.testing.assert_allclose(est, LENGTHS, rtol=0.15)


def test_degenerate_two_opposite_cameras():
    rng = np.random.default_rng(3)
    poses = synthetic_poses(FRAMES, rng, root_spread=0.0)  # pelvis on the camera axis: parallel rays
    points, P = observe(virtual_rig(2, "round"), poses, 6.0, rng)
    for solver in (lambda: structural_triangulation(points, P, LENGTHS),
                   lambda: lem_triangulation(points, P), lambda: ls_triangulation(points, P)):
        result = solver()
        assert np.all(np.isfinite(np.asarray(result.pose)))
    official = dict(max_length_error=float("inf"))  # the official code checks no lengths
    st = structural_triangulation(points, P, LENGTHS, **official)
    assert np.all(np.asarray(st.status) == Status.SINGLE_STEP)
    single = structural_triangulation(points, P, LENGTHS, n_steps=1, **official)
    np.testing.assert_allclose(st.pose, single.pose, rtol=0, atol=1e-12)
    assert mpjpe(st.pose, poses) < mpjpe(ls_triangulation(points, P).pose, poses)
    # Along parallel rays the single step leaves bones many times their length: by default that is LS.
    assert np.all(np.asarray(structural_triangulation(points, P, LENGTHS).status) == Status.FALLBACK_LS)


def test_missing_and_far_lengths_are_finite(scene):
    _, _, points, P = scene
    conf = np.full(points.shape[:-1], 0.25)
    conf[:, 1:, 9] = 0.0  # head seen by one view only: A is singular
    conf[:, 0, 10] = 0.0  # right wrist loses one view: still well posed
    conf[0, :, 5] = 0.0  # left ankle unseen in frame 0
    st = structural_triangulation(points, P, LENGTHS, confidences=conf)
    assert np.all(np.isfinite(np.asarray(st.pose)))
    assert np.all(np.asarray(st.status) == Status.UNDERDETERMINED)
    conf[:, :, 9] = 0.25
    conf[0, :, 5] = 0.25
    st = structural_triangulation(points, P, LENGTHS, confidences=conf)
    assert np.all(np.asarray(st.status) == Status.OK)
    far = structural_triangulation(points, P, 3.0 * LENGTHS)
    assert np.all(np.isfinite(np.asarray(far.pose)))
    assert set(np.unique(np.asarray(far.status))) <= {Status.OK, Status.FALLBACK_LS}


def test_gross_outliers_fall_back_to_ls_instead_of_metre_long_bones(scene):
    """The first-order update is a linearisation: a head 800 px off in two of four views sends it to bones tens
    of times their target length while every multiplier stays finite. Those frames must report FALLBACK_LS
    and return LS; the clean frames keep ST's solution."""
    _, _, points, P = scene
    points = points.copy()
    points[::2, :2, STRUCTRI17.index("head")] += np.array([800.0, -800.0])[:, None]  # every other frame
    unchecked = structural_triangulation(points, P, LENGTHS, max_length_error=float("inf"))
    assert np.all(np.asarray(unchecked.status) == Status.OK)
    assert np.max(np.linalg.norm(np.asarray(unchecked.bones)[::2], axis=-1) / LENGTHS) > 10.0
    st = structural_triangulation(points, P, LENGTHS)
    ls = ls_triangulation(points, P)
    fallback = np.asarray(st.status) == Status.FALLBACK_LS
    assert fallback[::2].all() and not fallback[1::2].any()
    np.testing.assert_array_equal(np.asarray(st.pose)[fallback], np.asarray(ls.pose)[fallback])
    kept = np.abs(np.linalg.norm(np.asarray(st.bones)[~fallback], axis=-1) - LENGTHS) / LENGTHS
    assert np.all(kept <= 0.5)


def test_clear_errors(scene):
    _, rig, points, P = scene
    with pytest.raises(ValueError, match="bone_lengths"):
        structural_triangulation(points, P, LENGTHS[:-1])
    with pytest.raises(ValueError, match="points_2d"):
        structural_triangulation(points[..., :16, :], P, LENGTHS)
    with pytest.raises((ValueError, TypeError), match="projections|views"):
        structural_triangulation(points, P[:3], LENGTHS)
    with pytest.raises((ValueError, TypeError), match="confidences|joints"):
        structural_triangulation(points, P, LENGTHS, confidences=np.ones(points.shape[:-2] + (3,)))
    with pytest.raises(ValueError, match="at least 2 views"):
        structural_triangulation(points[:, :1], P[:1], LENGTHS)
    with pytest.raises(ValueError, match="tree"):
        Skeleton("loop", ("a", "b", "c"), (-1, 2, 1))
    with pytest.raises(TypeError, match="Skeleton"):
        structural_triangulation(points, P, LENGTHS, skeleton=(-1, 0, 0))
    with pytest.raises(ValueError, match="distortion"):
        structural_triangulation(points, rig._replace(dist=rig.dist.at[:, 0].set(0.1)), LENGTHS)
    with pytest.raises(ValueError, match="max_length_error"):
        structural_triangulation(points, P, LENGTHS, max_length_error=0.0)


@pytest.mark.timeout(240, method="thread")  # a deadlock blocks in C, where the signal method cannot interrupt
def test_virtual_experiment_smoke(tmp_path):
    """The virtual-camera experiment on a tiny grid without the certified reference: files written, ST beats LEM,
    targets evaluated."""
    import json

    cfg = VirtualConfig(patterns=("half",), views=(3,), sigmas=(4.0,), frames=24, reference_frames=0,
                        lagrangian_iterations=20, estimate_frames=3, clips=("02_01_walk",), steps=(1, 3))
    # In a float32 session the experiment computes in float64 for itself and leaves the session's setting alone.
    jax.config.update("jax_enable_x64", False)
    try:
        results = run_virtual(cfg, tmp_path, progress=False)
        assert not jax.config.jax_enable_x64
    finally:
        jax.config.update("jax_enable_x64", True)  # the test session's setting (conftest.py)
    for name in ("config.json", "log.jsonl", "results.json", "results.md", "mpjpe_vs_sigma.png", "mpjpe_vs_views.png",
                 "mpjpe_vs_steps.png"):
        assert (tmp_path / name).is_file(), name
    (cell,) = results["cells"]
    assert cell["mpjpe_mm"]["ST"] < cell["mpjpe_mm"]["LEM"]
    # Measured on 2026-11-25 (float64, seeded noise: run to run exact, across installs far inside 0.1 %).
    assert [cell["mpjpe_mm"][m] for m in ("LEM", "LS", "ST")] == pytest.approx([11.5668, 10.7204, 8.6802], rel=1e-3)
    assert cell["mpble_mm"]["ST"] < 0.5
    # The N-step study: the code's variant at the experiment's N is the ST column; the variants agree at N = 1.
    study = cell["step_study"]
    assert study["code"]["3"]["mpjpe_mm"] == cell["mpjpe_mm"]["ST"]
    assert study["code"]["1"]["mpjpe_mm"] == pytest.approx(study["printed"]["1"]["mpjpe_mm"], rel=1e-9)
    assert study["code"]["3"]["mpjpe_mm"] != study["printed"]["3"]["mpjpe_mm"]
    report = (tmp_path / "results.md").read_text()
    assert "N-step study, printed variant" in report
    # Without reference frames (the quick headline run has them) the report says so instead of a table of Nones.
    assert "no certified reference" in report and "## Reference" not in report
    assert json.loads((tmp_path / "config.json").read_text())["frames"] == 24


@pytest.mark.parametrize(("option", "value", "message"), [
    ("patterns", ("round", "ring"), "patterns must be some of"),
    ("patterns", (), "patterns must be some of"),
    ("views", (3, 1), "views must be distinct camera counts >= 2"),
    ("views", (3, 3), "views must be distinct camera counts >= 2"),
    ("sigmas", (2.0, -1.0), "sigmas must be pixel noise levels >= 0"),
    ("frames", 0, "frames must be >= 1"),
    ("frame_stride", 0, "frame_stride must be >= 1"),
    ("estimate_frames", 0, "estimate_frames must be >= 1"),
    ("n_steps", -1, "n_steps must be >= 0"),
    ("reference_frames", -1, "reference_frames must be >= 0"),
    ("up_axis", "x", "up_axis must be 'y' or 'z'"),
    ("steps", (3, 0), "steps must be distinct SCA step counts >= 1"),
    ("steps", (2, 2), "steps must be distinct SCA step counts >= 1"),
])
def test_a_bad_virtual_option_is_refused_by_name(option, value, message):
    with pytest.raises(ValueError, match=message):
        VirtualConfig(**{option: value})


def test_no_lapack_in_batched_solvers(scene):
    """The batched solvers must not call LAPACK: jaxlib 0.10's batched LAPACK kernels (e.g. the LU of
    a vmapped ``jnp.linalg.solve``) split their batch over XLA's intra-op thread pool and block a pool
    thread while they wait, so two of them side by side in one program deadlock a small pool (the
    virtual experiment hung in ``update="exact"`` on 2 cores). Lowering only: nothing is compiled."""
    _, _, points, P = scene
    conf = np.full(points.shape[:-1], 0.25)
    solvers = {
        "st": lambda p: structural_triangulation(p, P, LENGTHS, confidences=conf),
        "st_exact": lambda p: structural_triangulation(p, P, LENGTHS, confidences=conf, update="exact"),
        "ls": lambda p: ls_triangulation(p, P),
        "lem": lambda p: lem_triangulation(p, P),
        "lagrangian": lambda p: lagrangian_triangulation(p, P, LENGTHS, n_iterations=3),
        "estimate": lambda p: estimate_bone_lengths(p, P),
    }
    canary = jax.jit(jax.vmap(jnp.linalg.solve)).lower(np.eye(3)[None].repeat(2, 0), np.ones((2, 3))).as_text()
    assert "lapack" in canary.lower()  # the check below can fail
    for name, solver in solvers.items():
        assert "lapack" not in jax.jit(solver).lower(points).as_text().lower(), name


@pytest.mark.parametrize(("size", "unrolled"), [(16, True), (16, False), (30, True)])
def test_frames_last_elimination_matches_numpy(size, unrolled):
    """Both elimination paths (unrolled up to ``_UNROLLED_MAX_SIZE`` unknowns unless ``unrolled=False``, looped
    above) solve SPD systems with several right-hand sides, frames on the last axis."""
    rng = np.random.default_rng(size)
    frames = 5
    factor = rng.normal(size=(frames, size, size))
    system = factor @ np.swapaxes(factor, 1, 2) + size * np.eye(size)
    rhs = rng.normal(size=(frames, size, 2))
    # Compiled, as the solvers run it (eager, the unrolled path dispatches thousands of tiny ops one by one).
    ours = jax.jit(_solve_symmetric, static_argnums=2)(
        jnp.moveaxis(jnp.asarray(system), 0, -1), jnp.moveaxis(jnp.asarray(rhs), 0, -1), unrolled)
    np.testing.assert_allclose(np.moveaxis(np.asarray(ours), -1, 0), np.linalg.solve(system, rhs), rtol=1e-10)


def test_benchmark_smoke():
    from experiments import bench_structri
    out = bench_structri.run(bench_structri.Config(frames=FRAMES, numpy_frames=4, reference_frames=1, repeats=1,
                                                   layouts=("5x2",)))
    assert out["st_max_rel_diff"] < 1e-6 and out["lem_max_rel_diff"] < 1e-6
    assert out["st_speedup_vs_numpy"] > 0 and out["reference_s_per_frame"] > 0
    assert set(out["st_layout_us_per_frame"]) == {"default", "5x2"}
    with pytest.raises(ValueError, match="CHUNKxSTREAMS"):
        bench_structri.Config(layouts=("160",))


def test_per_frame_projection_matrices(scene):
    """Moving cameras: one (views, 3, 4) stack per frame gives each frame's own solve."""
    poses, rig, points, P = scene
    per_frame = np.broadcast_to(P, (4, *P.shape)).copy()
    per_frame[1:, :, :, 3] *= 1.0 + 0.01 * np.arange(1, 4)[:, None, None]  # other translations per frame
    ours = np.asarray(structural_triangulation(points[:4], per_frame, LENGTHS).pose)
    for f in range(4):
        np.testing.assert_allclose(ours[f], np.asarray(structural_triangulation(points[f], per_frame[f], LENGTHS).pose),
                                   rtol=0, atol=1e-9)


# ----------------------------------------------------------------------------------------------
# Bad input ("Trustworthy runs"): refused with a one-line error, or an answer its status describes.


def test_frame_no_view_sees_is_at_the_origin_as_its_status_says(scene):
    _, _, points, P = scene
    conf = np.full(points.shape[:-1], 0.25)
    conf[3] = 0.0  # frame 3: every confidence zero
    for solve in (lambda c: structural_triangulation(points, P, LENGTHS, confidences=c),
                  lambda c: ls_triangulation(points, P, confidences=c),
                  lambda c: lem_triangulation(points, P, confidences=c)):
        result, seen = solve(conf), solve(np.full(points.shape[:-1], 0.25))
        assert int(result.status[3]) == Status.UNDERDETERMINED  # "the origin itself when no view sees it"
        np.testing.assert_array_equal(np.asarray(result.pose[3]), 0.0)
        np.testing.assert_array_equal(np.asarray(result.bones[3]), 0.0)
        others = np.arange(FRAMES) != 3  # frames are independent: the others are untouched
        np.testing.assert_array_equal(np.asarray(result.pose)[others], np.asarray(seen.pose)[others])


@pytest.mark.parametrize("lengths, match", [
    (np.where(np.arange(16) == 4, 0.0, LENGTHS), r"bone_lengths must be finite and > 0: got 0.0 at index \(4,\)"),
    (-LENGTHS, r"bone_lengths must be finite and > 0: got -0\.45 at index \(0,\)"),
    (np.where(np.arange(16) == 2, np.nan, LENGTHS), r"bone_lengths .* got nan at index \(2,\)"),
])
def test_bad_bone_lengths_are_refused(scene, lengths, match):
    _, _, points, P = scene
    with pytest.raises(ValueError, match=match):
        structural_triangulation(points, P, lengths)
    with pytest.raises(ValueError, match=match):
        lagrangian_triangulation(points, P, lengths)


def test_negative_confidences_are_refused(scene):
    _, _, points, P = scene
    conf = np.full(points.shape[:-1], 0.25)
    conf[2, 1, 7] = -0.5
    for solve in (structural_triangulation, lambda *a, confidences: ls_triangulation(a[0], a[1], confidences=confidences),
                  lambda *a, confidences: lem_triangulation(a[0], a[1], confidences=confidences)):
        with pytest.raises(ValueError, match=r"confidences must be finite and >= 0 .*got -0.5 at index \(2, 1, 7\)"):
            solve(points, P, LENGTHS, confidences=conf)


def test_nan_points_are_refused_unless_their_confidence_is_zero(scene):
    _, _, points, P = scene
    points = np.array(points)
    conf = np.full(points.shape[:-1], 0.25)
    points[1, 2, 5] = np.nan
    with pytest.raises(ValueError, match=r"points_2d must be finite where the confidence is positive .* got nan "
                                         r"at index \(1, 2, 5, 0\)"):
        structural_triangulation(points, P, LENGTHS, confidences=conf)
    with pytest.raises(ValueError, match="points_2d must be finite"):
        structural_triangulation(points, P, LENGTHS)  # default confidences: every view counts
    conf[1, 2, 5] = 0.0  # a missed detection: NaN is allowed and dropped like any view of weight 0
    finite = np.where(np.isnan(points), 123.0, points)
    for solve in (lambda x: structural_triangulation(x, P, LENGTHS, confidences=conf),
                  lambda x: ls_triangulation(x, P, confidences=conf), lambda x: lem_triangulation(x, P, confidences=conf)):
        np.testing.assert_array_equal(np.asarray(solve(points).pose), np.asarray(solve(finite).pose))
        assert np.isfinite(np.asarray(solve(points).pose)).all()

