"""One optimisation loop (``_design/descent.py``): its steps, stop and hooks, and the
``optimizer=`` that design and the tuner take (an optax transformation, checked in one line)."""

import numpy as np
import optax
import pytest

from armimp_jax._design.descent import descend, optimizer_or_default


def test_descend_steps_from_first_stops_and_reports():
    seen = []
    out = descend(0, lambda s, i: s + i, 5, after=lambda s, i: seen.append((i, s)), first=1)
    assert out == 10 and seen == [(1, 1), (2, 3), (3, 6), (4, 10)]
    assert descend(0, lambda s, i: s + 1, 10, stop=lambda s: s >= 3) == 3


def test_the_default_is_adam_and_anything_else_is_refused_in_one_line():
    grads = {"a": np.array([1.0, -2.0])}
    ours = optimizer_or_default(None, 0.1, where="design")
    adam = optax.adam(0.1)
    a, _ = ours.update(grads, ours.init(grads))
    b, _ = adam.update(grads, adam.init(grads))
    np.testing.assert_array_equal(a["a"], b["a"])
    with pytest.raises(ValueError, match="^tune: optimizer must be an optax GradientTransformation"):
        optimizer_or_default("adam", 0.1, where="tune")


def test_a_tuning_state_records_a_custom_optimizer():
    from armimp_jax._design.tuner import TuneConfig, config_settings

    config = TuneConfig()
    assert config_settings(config)["optimiser"] == "adam"
    assert config_settings(config, optax.sgd(0.1))["optimiser"] == "custom"
