"""OTAP, JCSAT's optimal-transport aggregation pooling (paper Sec. 3.3, Eq. 10): the OTK layer of Mialon et al.

A sequence of ``n`` tokens (some of them padding) is pooled into ``p`` output tokens. The similarity
``K = tokens @ reference.T`` against a learnable reference (``p x d``) defines the entropic transport
problem with cost ``-K``; its plan ``P`` (``n x p``) weighs the tokens: ``out_j = sum_i P[i, j] tokens_i``.

Conventions (the official code's; ``docs/jcsat.md``, "Where the paper is silent"):

- **Marginals.** Token ``i`` sends ``p / n_valid`` (0 if padded), reference ``j`` receives 1, so the plan
  returned here is ``P_OTK = p * P_std``, ``P_std`` being the plan with the usual marginals
  ``(1/n_valid, 1/p)``. The iteration ends on the column update: every column of ``P_OTK`` sums to
  exactly 1, and each output is a **weighted average** of the valid tokens (the OTK code's scale).
  Paper Eq. 10 writes ``sqrt(p) * sum_i P_std[i, j] tokens_i``, which is this value divided by
  ``sqrt(p)`` (3.16 for p = 10, 5 for p = 25, identical for p = 1); the project keeps the weighted
  average and lets the next linear/normalisation layer absorb the constant.
- **Fixed iteration count**, log domain, unrolled in a ``lax.scan`` so that reverse-mode
  differentiation backpropagates through every step (as in OTK and JCSAT: eps = 0.1, 100 iterations).
- **Fully masked sequences** (no valid token: ``a = p / 0``) give an all-zero plan and output, with
  finite gradients (project rule; OTK returns finite garbage there).
- Padded tokens carry no mass, and their values, even inf or NaN, never reach the result.
"""

from __future__ import annotations

import math
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Bool, Float

__all__ = ["OTAP", "otap", "sinkhorn_plan"]


def _check_options(epsilon: float, iterations: int, tolerance: float | None) -> None:
    if not epsilon > 0:
        raise ValueError(f"epsilon must be positive (the entropic regularisation), got {epsilon}")
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    if tolerance is not None and not tolerance >= 0:
        raise ValueError(f"tolerance must be None or >= 0, got {tolerance}")


def _check_filter(position_filter: str | None, sigma: float) -> None:
    if position_filter not in (None, "hard", "gaussian"):
        raise ValueError(f"position_filter must be None, 'hard' or 'gaussian', got {position_filter!r}")
    if position_filter is not None and not sigma > 0:
        raise ValueError(f"sigma must be positive, got {sigma}")


def _logsumexp(x: Float[Array, "n p"], axis: int) -> Float[Array, " _"]:
    """``log sum exp`` along ``axis`` for finite maxima: about 30% faster Sinkhorn on CPU than
    ``jax.nn.logsumexp``, whose extra inf/sign/``where`` handling this problem never needs. The shift
    by the maximum cancels exactly, so no gradient is taken through it."""
    shift = jax.lax.stop_gradient(jnp.max(x, axis=axis, keepdims=True))
    return jnp.squeeze(shift, axis) + jnp.log(jnp.sum(jnp.exp(x - shift), axis=axis))


def sinkhorn_plan(
    similarity: Float[Array, "n p"],
    mask: Bool[Array, " n"],
    *,
    epsilon: float = 0.1,
    iterations: int = 100,
    tolerance: float | None = None,
) -> Float[Array, "n p"]:
    """The OTK transport plan ``P_OTK = p * P_std`` for the cost ``-similarity``, by log-domain Sinkhorn.

    Args:
        similarity: ``K``, unnormalised token-reference similarities (cost is ``-K``). Rows of padded
            tokens are ignored, whatever their values.
        mask: True for valid tokens.
        epsilon: entropic regularisation, in the units of ``K``.
        iterations: number of (row, column) update pairs; the last update is on the columns.
        tolerance: optional early stop. Once the row marginals of the current plan are within
            ``tolerance`` (L1 error ``sum_i |sum_j P_OTK[i, j] - p / n_valid|``, the units of the
            returned plan, i.e. ``p`` times ott-jax's ``threshold``), the potentials stop changing.

    Returns:
        ``(n, p)`` plan: columns sum to 1, valid rows to about ``p / n_valid``, padded rows are 0;
        all zeros when no token is valid.

    The potentials are kept in units of ``epsilon`` (``f = u / eps``, ``g = v / eps``), so one
    iteration is ``f = log a - LSE_j(K/eps + g)`` over all references, then
    ``g = -LSE_i(K/eps + f)`` over valid tokens, from ``f = g = 0``. Padded rows are left out of the
    column sum exactly (``-inf`` added inside the log-sum-exp, whose maximum always comes from a
    valid row) rather than by OTK's ``u = -1e8``, whose float32 cancellation is what turns a fully
    masked sequence into garbage there.

    The early stop is a *freeze inside the fixed-length scan*, not a ``while_loop``: the result is
    the same as stopping, but reverse-mode differentiation (which ``while_loop`` does not support)
    keeps working, and under ``vmap`` a ``while_loop`` would run every sequence until the slowest
    one converges anyway. The price is that all ``iterations`` steps are always computed.
    """
    _check_options(epsilon, iterations, tolerance)
    n, p = similarity.shape
    dtype = similarity.dtype
    any_valid = jnp.any(mask)
    # A fully masked sequence has no mass to send. It is solved as a stand-in problem with every row
    # valid and a zero similarity, then the plan is zeroed below: the values and the gradients stay
    # finite, and the zeroing `where` passes no gradient to the stand-in.
    rows = mask | ~any_valid
    scaled = jnp.where(mask[:, None], similarity / epsilon, 0.0)
    log_a = (math.log(p) - jnp.log(jnp.sum(rows))).astype(dtype)
    padding = jnp.where(rows, 0.0, -jnp.inf).astype(dtype)

    def row_update(g: Float[Array, " p"]) -> Float[Array, " n"]:
        return log_a - _logsumexp(scaled + g[None, :], axis=1)

    def column_update(f: Float[Array, " n"]) -> Float[Array, " p"]:
        return -_logsumexp(scaled + (f + padding)[:, None], axis=0)

    def step(carry, index):
        f, g, frozen = carry
        f_next = row_update(g)
        g_next = column_update(f_next)
        if tolerance is not None:
            # Row sums of the plan (f, g) are a * exp(f - f_next): the convergence test costs nothing
            # extra. (f, g) is a finished iterate (ending on a column update) only after step 0.
            row_error = jnp.sum(jnp.where(rows, jnp.abs(jnp.expm1(f - f_next)), 0.0)) * jnp.exp(log_a)
            frozen = frozen | ((index > 0) & (row_error <= tolerance))
            f_next, g_next = jnp.where(frozen, f, f_next), jnp.where(frozen, g, g_next)
        return (f_next, g_next, frozen), None

    start = (jnp.zeros(n, dtype), jnp.zeros(p, dtype), jnp.array(False))
    (f, g, _), _ = jax.lax.scan(step, start, jnp.arange(iterations))
    plan = jnp.exp(scaled + f[:, None] + g[None, :])
    return jnp.where(mask[:, None], plan, 0.0)


def position_filter_matrix(n: int, p: int, kind: str, sigma: float) -> np.ndarray:
    """OTK's position filter ``F`` (``n x p``, float64 NumPy constant) tying token ``i`` to output ``j``.

    ``'gaussian'``: ``exp(-((i/n - j/p) / sigma)^2)``. ``'hard'``: ``1[|i/n - j/p| < sigma]``, decided
    in integers as ``|i p - j n| * den < num * n * p`` with ``sigma = num/den`` (its nearest simple
    fraction, 1/10 for 0.1), so windows do not depend on float rounding at their edges.
    """
    i = np.arange(n)[:, None]
    j = np.arange(p)[None, :]
    if kind == "gaussian":
        return np.exp(-(((i / n - j / p) / sigma) ** 2))
    fraction = Fraction(sigma).limit_denominator(10**6)
    return (np.abs(i * p - j * n) * fraction.denominator < fraction.numerator * n * p).astype(np.float64)


def otap(
    tokens: Float[Array, "n d"],
    mask: Bool[Array, " n"],
    reference: Float[Array, "p d"],
    *,
    epsilon: float = 0.1,
    iterations: int = 100,
    tolerance: float | None = None,
    position_filter: str | None = None,
    sigma: float = 0.1,
) -> Float[Array, "p d"]:
    """Pool ``n`` tokens (some padded) into ``p``: ``out_j = sum_i P_OTK[i, j] tokens_i``.

    Each output is a weighted average (convex combination) of the valid tokens, i.e. ``sqrt(p)`` times
    the paper's Eq. 10 (see the module docstring); zeros when no token is valid.

    ``position_filter`` (off by default, spec section 5 item 6; an ablation option) multiplies the
    similarity before Sinkhorn and the plan after it by :func:`position_filter_matrix`, with the
    token's position in the padded sequence. In the log domain only the second product removes
    mass, so filtered outputs are no longer averages (their weights sum to at most 1).
    Other keywords: see :func:`sinkhorn_plan`.
    """
    _check_filter(position_filter, sigma)
    # Padding is zeroed first so that its values (inf/NaN included) cannot leak through 0 * x.
    tokens = jnp.where(mask[:, None], tokens, 0.0)
    similarity = tokens @ reference.T
    if position_filter is not None:
        weights = jnp.asarray(position_filter_matrix(*similarity.shape, position_filter, sigma), similarity.dtype)
        similarity = weights * similarity
    plan = sinkhorn_plan(similarity, mask, epsilon=epsilon, iterations=iterations, tolerance=tolerance)
    if position_filter is not None:
        plan = weights * plan
    return plan.T @ tokens


class OTAP(nnx.Module):
    """One-head OTAP layer: :func:`otap` with a learnable reference of shape ``(num_outputs, features)``.

    The reference is initialised from ``U(-1/sqrt(p), 1/sqrt(p))`` (OTK), ``p = num_outputs``.
    """

    def __init__(
        self,
        features: int,
        num_outputs: int,
        *,
        epsilon: float = 0.1,
        iterations: int = 100,
        tolerance: float | None = None,
        position_filter: str | None = None,
        sigma: float = 0.1,
        param_dtype: jnp.dtype = jnp.float32,
        rngs: nnx.Rngs,
    ) -> None:
        if features < 1 or num_outputs < 1:
            raise ValueError(f"features and num_outputs must be >= 1, got {features} and {num_outputs}")
        _check_options(epsilon, iterations, tolerance)
        _check_filter(position_filter, sigma)
        bound = 1.0 / math.sqrt(num_outputs)
        self.reference = nnx.Param(
            jax.random.uniform(rngs.params(), (num_outputs, features), param_dtype, -bound, bound)
        )
        self.epsilon = epsilon
        self.iterations = iterations
        self.tolerance = tolerance
        self.position_filter = position_filter
        self.sigma = sigma

    def __call__(self, tokens: Float[Array, "*batch n d"], mask: Bool[Array, "*batch n"]) -> Float[Array, "*batch p d"]:
        """Pool every sequence of the leading batch axes (vmapped :func:`otap`)."""
        reference = self.reference[...]

        def pool(sequence: Float[Array, "n d"], valid: Bool[Array, " n"]) -> Float[Array, "p d"]:
            return otap(
                sequence, valid, reference, epsilon=self.epsilon, iterations=self.iterations,
                tolerance=self.tolerance, position_filter=self.position_filter, sigma=self.sigma,
            )

        batch = tokens.shape[:-2]
        pooled = jax.vmap(pool)(tokens.reshape(-1, *tokens.shape[-2:]), mask.reshape(-1, mask.shape[-1]))
        return pooled.reshape(*batch, *pooled.shape[1:])
