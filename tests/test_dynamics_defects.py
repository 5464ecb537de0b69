"""Issue 26's training defects of the dynamics models, on tiny models and without training: PHD+T's f_JE must
get a gradient from the AR objective (dynamics/_train.py), and every ablation of :func:`dynamics.train_all` must
start where the model it is compared with starts and train as long (dynamics/_train_jat.py)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

import dynamics._train_jat as train_jat
from dynamics import (JAT, PHDT, JATConfig, PHDTConfig, PosePrior, ResNetBackbone, TrainConfig,
                      TransformerTrainConfig, train_all)
from dynamics._train import BackboneConfig, _ar_objective
from test_dynamics import BODY, true_frames

OBSERVED, HORIZON = 5, 3


def test_the_ar_objective_trains_phdt_joint_encoder():
    """The old objective stopped the gradient on the whole observation, Gamma^ = f_JE(J^) included, and PHD+T's
    rollout never re-encodes joints: f_JE's gradient was exactly zero, its shipped weights their initialisation."""
    model_config = PHDTConfig(feature_dim=16, joint_dim=16, channels_per_group=16, hmr_hidden=16, tcn_blocks=1,
                              delta_offsets=(-1,))
    config = TrainConfig(backbone=BackboneConfig(feature_dim=16), model=model_config, observed=OBSERVED,
                         horizon=HORIZON)
    model = PHDT(model_config, rngs=nnx.Rngs(0))
    rng = np.random.default_rng(0)
    rows = jax.tree.map(lambda column: jnp.asarray(column)[None], true_frames(rng, OBSERVED + HORIZON))
    features = jnp.asarray(rng.normal(size=(1, OBSERVED + HORIZON, model_config.feature_dim)), jnp.float32)
    prior = PosePrior(model_config.num_shapes, rngs=nnx.Rngs(1))
    graphdef, encoder, rest = nnx.split(model, nnx.All(nnx.Param, nnx.PathContains("joint_encoder")), ...)

    def loss(encoder):
        return _ar_objective(config, BODY, nnx.merge(graphdef, encoder, rest), (features, rows), None, prior)[0]

    gradients = jax.tree.leaves(jax.grad(loss)(encoder))
    assert gradients and all(np.all(np.isfinite(g)) for g in gradients)
    assert max(float(jnp.max(jnp.abs(g))) for g in gradients) > 0.0


SMALL = JATConfig(feature_dim=16, temporal_dim=16, joint_dim=8, hmr_hidden=16, bias_hidden=8, receptive_field=10)
CONDITIONING = ("movie_encoder", "movie", "hmr")
"""JAT's ``movie/`` stage's parts, frozen in its ``ar/`` stage."""


def _values(model: nnx.Module) -> dict[tuple, np.ndarray]:
    """A copy of the parameters by path (the model's variables change in place)."""
    return {path: np.array(variable[...]) for path, variable in nnx.to_flat_state(nnx.state(model, nnx.Param))}


@pytest.fixture(scope="module")
def plan(tmp_path_factory) -> dict[str, tuple[TransformerTrainConfig, dict, dict]]:
    """Each transformer's run config, parameters when its training starts and when it ends, from
    :func:`train_all` with a stand-in ``train_transformer`` that builds the model as the real one does and
    "trains" it by adding 1 to every parameter: whatever a run inherits from a trained model is changed."""
    runs = {}

    def train_transformer(config, workdir, body, backbone, init=None, *, resume, log, progress, data_workers):
        model = JAT(config.model, rngs=nnx.Rngs(config.seed))
        if init is not None:
            nnx.update(model, nnx.state(init, nnx.Param))
        start = _values(model)
        nnx.update(model, jax.tree.map(lambda x: x + 1.0, nnx.state(model, nnx.Param)))
        runs[workdir.name] = (config, start, _values(model))
        return model

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(train_jat, "train_transformer", train_transformer)
        train_all(TransformerTrainConfig(model=SMALL), tmp_path_factory.mktemp("plan"), BODY,
                  ResNetBackbone((4,), 1, SMALL.feature_dim, rngs=nnx.Rngs(0)), resume=False, progress=False)
    return runs


def _assert_same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for path in a:
        np.testing.assert_array_equal(a[path], b[path], err_msg=".".join(map(str, path)))


def test_jat_without_bias_starts_where_jat_ar_stage_starts(plan):
    """The old plan started "JAT w/o bias" from the trained JAT, f_AR included, and trained it 300 more steps:
    twice JAT's f_AR training. It must start from JAT's trained conditioning networks and JAT's initial f_AR,
    f_JE and f_transl (less the bias) and train only its own ``ar/`` stage, as long as JAT's."""
    jat_config, jat_start, jat_trained = plan["jat"]
    config, start, _ = plan["jat_without_bias"]
    assert config.model == dataclasses.replace(jat_config.model, joint_aware_bias=False)
    assert config.movie is None  # JAT's conditioning stage is not repeated: its result is inherited
    assert (config.ar, config.seed, config.losses, config.horizon) == (
        jat_config.ar, jat_config.seed, jat_config.losses, jat_config.horizon)
    expected = {path: (jat_trained if path[0] in CONDITIONING else jat_start)[path] for path in jat_start
                if path[0] != "bias_self"}
    _assert_same(start, expected)


def test_mpjat_without_p_starts_where_mpjat_starts(plan):
    """MPJAT w/o P differs from MPJAT in the interpenetration weight only: the same start, the same stages."""
    mpjat_config, mpjat_start, _ = plan["mpjat"]
    config, start, _ = plan["mpjat_without_p"]
    assert config.losses.interpenetration == 0.0 < mpjat_config.losses.interpenetration
    assert config == dataclasses.replace(mpjat_config, losses=config.losses)
    _assert_same(start, mpjat_start)
