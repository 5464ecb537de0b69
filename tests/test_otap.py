"""OTAP (jcsat/_otap.py): the Sinkhorn plan against ott-jax, marginals, masking, gradients, invariances."""

from fractions import Fraction
from functools import partial

import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx
from hypothesis import given, settings
from jax.test_util import check_grads
from numpy.testing import assert_allclose, assert_array_equal
from ott.geometry import geometry
from ott.problems.linear import linear_problem
from ott.solvers.linear import sinkhorn

from jcsat import OTAP, otap, sinkhorn_plan
from jcsat._otap import position_filter_matrix

# Eager calls retrace and recompile the Sinkhorn scan every time; most tests call the jitted functions.
jit_plan = jax.jit(sinkhorn_plan, static_argnames=("epsilon", "iterations", "tolerance"))
jit_otap = jax.jit(otap, static_argnames=("epsilon", "iterations", "tolerance", "position_filter", "sigma"))


def make_problem(seed: int, n: int, p: int, d: int, num_valid: int, dtype=jnp.float64):
    """Tokens ~ N(0, 1), reference ~ U(-1/sqrt(p), 1/sqrt(p)) (the OTK init), the first ``num_valid`` tokens valid."""
    rng = np.random.default_rng(seed)
    tokens = jnp.asarray(rng.normal(size=(n, d)), dtype)
    reference = jnp.asarray(rng.uniform(-1, 1, size=(p, d)) / np.sqrt(p), dtype)
    return tokens, jnp.arange(n) < num_valid, reference


def ott_plan(similarity, mask, iterations: int, epsilon: float = 0.1, transposed: bool = False) -> np.ndarray:
    """``p * P_ott`` from ott-jax's log-domain Sinkhorn, with a fixed, unrolled iteration count.

    ``transposed=False`` is the spec's configuration (tokens as rows, a uniform over the valid ones,
    b = 1/p). ott updates the column potential first, OTK the row one, so the two agree only once
    converged. ``transposed=True`` poses the transposed problem (references as rows), which makes
    ott's update order ours: the iterates then agree at every iteration count.
    """
    n, p = similarity.shape
    a = jnp.where(mask, 1.0 / jnp.sum(mask), 0.0)
    b = jnp.full(p, 1.0 / p)
    solver = sinkhorn.Sinkhorn(
        min_iterations=iterations, max_iterations=iterations, inner_iterations=1, implicit_diff=None, threshold=0.0
    )
    cost, rows, columns = (-similarity.T, b, a) if transposed else (-similarity, a, b)
    with jax.numpy_rank_promotion("allow"):
        plan = solver(linear_problem.LinearProblem(geometry.Geometry(cost_matrix=cost, epsilon=epsilon), rows, columns)).matrix
    return p * np.asarray(plan.T if transposed else plan)


@pytest.mark.parametrize("iterations, num_valid", [(1, 9), (3, 12), (100, 9)])
def test_plan_equals_ott_iterates(iterations, num_valid):
    tokens, mask, reference = make_problem(0, n=12, p=4, d=8, num_valid=num_valid)
    similarity = tokens @ reference.T
    ours = jit_plan(similarity, mask, iterations=iterations)
    assert_allclose(ours, ott_plan(similarity, mask, iterations, transposed=True), atol=1e-12)


@pytest.mark.parametrize("seed, n, p, num_valid", [(1, 12, 4, 12), (3, 40, 10, 31)])
def test_plan_matches_ott_spec_configuration(seed, n, p, num_valid):
    tokens, mask, reference = make_problem(seed, n, p, d=16, num_valid=num_valid)
    similarity = tokens @ reference.T
    assert_allclose(jit_plan(similarity, mask), ott_plan(similarity, mask, 100), atol=1e-5)


def test_marginals():
    tokens, mask, reference = make_problem(5, n=40, p=10, d=16, num_valid=27)
    plan = jit_plan(tokens @ reference.T, mask, iterations=300)
    assert_allclose(plan.sum(axis=0), 1.0, atol=1e-12)  # the last update is on the columns
    assert_allclose(plan[:27].sum(axis=1), 10 / 27, atol=1e-8)
    assert_array_equal(plan[27:], 0.0)
    assert bool(jnp.all(plan >= 0))


def test_tolerance_freezes_once_converged():
    tokens, mask, reference = make_problem(6, n=40, p=10, d=16, num_valid=30)
    similarity = tokens @ reference.T
    loose = jit_plan(similarity, mask, iterations=200, tolerance=1e-3)
    full = jit_plan(similarity, mask, iterations=200)
    row_error = float(jnp.abs(loose[:30].sum(axis=1) - 10 / 30).sum())
    assert 1e-6 < row_error <= 1e-3  # stopped early, and within the tolerance
    assert_allclose(loose.sum(axis=0), 1.0, atol=1e-12)
    # Once frozen, extra iterations change nothing; gradients still flow through the frozen scan.
    assert_array_equal(jit_plan(similarity, mask, iterations=400, tolerance=1e-3), loose)
    grad = jax.jit(jax.grad(lambda s: jnp.sum(sinkhorn_plan(s, mask, iterations=200, tolerance=1e-3) * full)))(similarity)
    assert bool(jnp.all(jnp.isfinite(grad)))


def test_fully_masked_gives_zeros_and_finite_gradients():
    tokens, _, reference = make_problem(7, n=10, p=3, d=4, num_valid=0)
    mask = jnp.zeros(10, bool)
    tokens = tokens.at[0].set(jnp.nan)  # padding values never matter
    assert_array_equal(jit_plan(tokens @ reference.T, mask), 0.0)
    assert_array_equal(jit_otap(tokens, mask, reference), 0.0)
    grads = jax.jit(jax.grad(lambda t, r: jnp.sum(otap(t, mask, r) ** 2), argnums=(0, 1)))(tokens, reference)
    for grad in grads:
        assert_array_equal(grad, 0.0)


def test_gradients_numerically():
    tokens, mask, reference = make_problem(8, n=7, p=3, d=4, num_valid=5)
    # check_grads feeds NumPy arrays to its finite differences: jnp.asarray keeps the annotations honest.
    plan = jax.jit(lambda s: sinkhorn_plan(jnp.asarray(s), mask, iterations=5))
    check_grads(plan, (tokens @ reference.T,), order=1, modes=("fwd", "rev"))
    pooled = jax.jit(lambda t, r: otap(jnp.asarray(t), mask, jnp.asarray(r), iterations=5))
    check_grads(pooled, (tokens, reference), order=1, modes=("rev",))


def test_jit_equals_eager_and_compiles_once():
    tokens, mask, reference = make_problem(9, n=40, p=10, d=16, num_valid=33)
    jitted = jax.jit(lambda t, m, r: otap(t, m, r))  # own cache: jax.jit(otap) would share jit_otap's
    assert_allclose(jitted(tokens, mask, reference), otap(tokens, mask, reference), rtol=1e-10, atol=1e-12)
    jitted(tokens + 1.0, jnp.arange(40) < 20, reference)
    assert jitted._cache_size() == 1


def test_module_batches_and_ignores_padding_values():
    model = OTAP(16, 10, rngs=nnx.Rngs(0))
    pool = nnx.jit(lambda m, t, v: m(t, v))
    reference = model.reference[...]
    assert reference.shape == (10, 16) and reference.dtype == jnp.float32
    assert float(jnp.abs(reference).max()) <= 1 / np.sqrt(10)
    rng = np.random.default_rng(10)
    tokens = jnp.asarray(rng.normal(size=(2, 3, 40, 16)))
    mask = jnp.asarray(rng.random((2, 3, 40)) < 0.7).at[1, 2].set(False)  # one fully masked sequence
    out = pool(model, tokens, mask)
    assert out.shape == (2, 3, 10, 16)
    assert_allclose(out[0, 1], jit_otap(tokens[0, 1], mask[0, 1], reference), rtol=1e-12)
    assert_allclose(model(tokens[0, 1], mask[0, 1]), out[0, 1], rtol=1e-12)  # no batch axes, eager
    assert_array_equal(out[1, 2], 0.0)
    scrambled = jnp.where(mask[..., None], tokens, jnp.asarray(rng.normal(size=tokens.shape)) * 1e6)
    assert_array_equal(pool(model, scrambled.at[0, 0, jnp.argmin(mask[0, 0])].set(jnp.inf), mask), out)


def test_outputs_are_convex_combinations():
    tokens, mask, reference = make_problem(11, n=40, p=10, d=16, num_valid=25)
    out = jit_otap(tokens, mask, reference)
    low, high = tokens[:25].min(axis=0), tokens[:25].max(axis=0)
    assert bool(jnp.all(out >= low[None, :] - 1e-12)) and bool(jnp.all(out <= high[None, :] + 1e-12))


def test_float32_model():
    model = OTAP(128, 25, rngs=nnx.Rngs(1))
    tokens, mask, _ = make_problem(12, n=100, p=25, d=128, num_valid=70, dtype=jnp.float32)
    out = nnx.jit(lambda m, t, v: m(t, v))(model, tokens[None], mask[None])[0]
    assert out.dtype == jnp.float32
    exact = jit_otap(tokens.astype(jnp.float64), mask, model.reference[...].astype(jnp.float64))
    assert_allclose(out, exact, atol=1e-4)
    plan = jit_plan(tokens @ model.reference[...].T, mask)
    assert plan.dtype == jnp.float32
    assert_allclose(plan.sum(axis=0), 1.0, atol=1e-5)
    grad = nnx.jit(nnx.grad(lambda m: jnp.sum(m(tokens, mask) ** 2)))(model)
    assert bool(jnp.all(jnp.isfinite(grad.reference[...])))


def test_position_filters():
    n, p, sigma = 100, 25, 0.1
    hard = position_filter_matrix(n, p, "hard", sigma)
    exact = np.array([[abs(Fraction(i, n) - Fraction(j, p)) < Fraction(1, 10) for j in range(p)] for i in range(n)])
    assert_array_equal(hard, exact)
    i, j = np.arange(n)[:, None], np.arange(p)[None, :]
    assert_allclose(position_filter_matrix(n, p, "gaussian", sigma), np.exp(-(((i / n - j / p) / sigma) ** 2)))
    tokens, mask, reference = make_problem(13, n, p, d=8, num_valid=80)
    for kind in ("hard", "gaussian"):
        weights = jnp.asarray(position_filter_matrix(n, p, kind, sigma))
        plan = weights * jit_plan(weights * (tokens @ reference.T), mask)
        assert_allclose(jit_otap(tokens, mask, reference, position_filter=kind), plan.T @ tokens, rtol=1e-12)
        assert bool(jnp.all(plan.sum(axis=0) <= 1 + 1e-12))


@pytest.mark.parametrize(
    "call",
    [
        lambda s, m: sinkhorn_plan(s, m, epsilon=0.0),
        lambda s, m: sinkhorn_plan(s, m, iterations=0),
        lambda s, m: sinkhorn_plan(s, m, tolerance=-1.0),
        lambda s, m: otap(s, m, s, position_filter="box"),
        lambda s, m: otap(s, m, s, position_filter="hard", sigma=0.0),
        lambda s, m: OTAP(4, 4, epsilon=-0.1, rngs=nnx.Rngs(0)),
    ],
)
def test_rejects_bad_static_arguments(call):
    with pytest.raises(ValueError):
        call(jnp.ones((4, 4)), jnp.ones(4, bool))


@settings(max_examples=40, deadline=None)
@given(
    data=st.data(), n=st.sampled_from([1, 9]), p=st.sampled_from([1, 4]), seed=st.integers(0, 2**16),
    scale=st.floats(0.1, 10.0),
)
def test_invariant_to_token_permutation(data, n, p, seed, scale):
    """Shapes come from a short list (each new shape compiles); the mask, order and values vary freely."""
    num_valid = data.draw(st.integers(0, n))
    order = np.array(data.draw(st.permutations(range(n))))
    tokens, mask, reference = make_problem(seed, n, p, d=3, num_valid=num_valid)
    pool = partial(jit_otap, reference=scale * reference, iterations=30)
    assert_allclose(pool(tokens[order], mask[order]), pool(tokens, mask), rtol=1e-9, atol=1e-12)
