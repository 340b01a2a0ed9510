"""Kinds as classes (issue 46): a controller and a friction law defined in this file alone run
through the simulation (every integrator, batches), the bound, identification and a sweep,
with no edit elsewhere; the registry refuses unknown and duplicate kinds in one line."""

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import armimp_jax as aj
from armimp_jax import paper, study
from armimp_jax._model.controllers import controller_kind
from armimp_jax._model.controllers.base import CONTROLLER_KINDS
from armimp_jax._model.friction import friction_kind


class Damper(aj.AbstractController):
    """A pure damper on the handle: ``F_u = F_Delta - d xd`` (the arm's stiffness holds it)."""

    kind: ClassVar[str] = "toy_damper"
    UNITS: ClassVar[dict] = dict(d="N s/m")
    DESIGN_GAINS: ClassVar[None] = None

    d: np.ndarray = eqx.field(converter=np.asarray, default=((20.0, 0.0), (0.0, 20.0)))

    def init(self, x0):
        return ()

    def step(self, memory, x, xd, fh, f_delta, x0, period):
        return f_delta - jnp.stack(
            [self.d[0, 0] * xd[0] + self.d[0, 1] * xd[1], self.d[1, 0] * xd[0] + self.d[1, 1] * xd[1]]
        ), memory


class SmoothCoulomb(aj.AbstractFriction):
    """``tau_c v / sqrt(v^2 + eps^2)`` per joint: a Coulomb torque smoothed over ``eps`` [rad/s]."""

    kind: ClassVar[str] = "toy_smooth_coulomb"
    UNITS: ClassVar[dict] = dict(tau_c="N m", eps="rad/s")
    STIFF_STATIC: ClassVar[bool] = True
    IDENTIFIABLE: ClassVar[tuple] = ("tau_c",)

    tau_c: np.ndarray = eqx.field(converter=lambda v: np.broadcast_to(np.asarray(v, float), (2,)).copy())
    eps: np.ndarray = eqx.field(converter=lambda v: np.broadcast_to(np.asarray(v, float), (2,)).copy(), default=0.005)

    def viscous_coefficient(self):
        return 0.0

    def static_torque(self, v):
        return self.tau_c * v / jnp.sqrt(v * v + self.eps * self.eps)

    def static_slope(self, v):
        r = v * v + self.eps * self.eps
        return self.tau_c * self.eps * self.eps / (r * jnp.sqrt(r))

    def without_coulomb(self):
        return eqx.tree_at(lambda law: law.tau_c, self, jnp.zeros_like(self.tau_c))

    def has_coulomb(self):
        return bool(np.any(np.asarray(self.tau_c) > 0))


NOISE = dict(sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18), voluntary=aj.VoluntaryForce(0.3, 2.0))
F = aj.perturbation(jax.random.key(5), 2000, 10.0)


def _trial(friction=None, **kw):
    return aj.make_trial(
        Damper(), arm=paper.arm(2), friction=SmoothCoulomb(0.1) if friction is None else friction, **kw
    )


def test_the_toy_kinds_simulate_under_every_integrator_and_batch():
    trial = _trial()
    ref = jax.jit(aj.simulate, static_argnames="numerics")(
        trial, F, numerics=aj.Numerics(solver=aj.solvers.RK4(), substeps=200)
    )
    assert not bool(ref.diverged) and np.std(np.asarray(ref.x)) > 1e-4
    rms = np.sqrt(np.mean(np.asarray(ref.fh) ** 2))
    for numerics in (
        aj.Numerics(),
        aj.Numerics(solver=aj.solvers.ARK3(), substeps=20),
    ):  # the stiff torque taken implicitly
        sim = jax.jit(aj.simulate, static_argnames="numerics")(trial, F, numerics=numerics)
        assert np.max(np.abs(np.asarray(sim.fh) - np.asarray(ref.fh))) < 2e-3 * rms
    batch = aj.simulate_batch(aj.batch.stack_trials([trial, _trial(SmoothCoulomb(0.0))]), np.stack([F, F]))
    np.testing.assert_allclose(batch.fh[0], jax.jit(aj.simulate)(trial, F).fh, rtol=0, atol=1e-12)


@pytest.mark.slow  # about 60 s cold: crlb and identify compiled for the toy kinds
def test_the_toy_kinds_have_a_bound_and_identify_through_the_loop():
    truth = _trial(**NOISE)
    bound = aj.crlb(truth, F)
    assert bound.near_linear and "without its Coulomb friction" in bound.reference
    assert all(np.all(np.isfinite(s)) and np.all(s > 0) for s in bound.se.values())
    # identify's default integrator runs the law implicitly above; RK4 at 2 substeps is stable for
    # this law's slope (20 N m s/rad at rest) and compiles in a fraction of the time
    num = aj.Numerics(solver=aj.solvers.RK4(), substeps=2)
    sim = aj.simulate(_trial(), F, numerics=num)
    arm = paper.arm(2)
    start = aj.make_trial(
        Damper(),
        arm=aj.Arm(arm.mass, arm.damping, 1.1 * arm.stiffness, arm.endpoint),
        friction=SmoothCoulomb(0.06),
    )
    res = aj.identify(start, F, sim.x, sim.fh, free=("arm.stiffness", "friction.tau_c"), numerics=num)
    assert res.converged, res.message
    np.testing.assert_allclose(res.values["arm.stiffness"], arm.stiffness, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(res.values["friction.tau_c"], [0.1, 0.1], rtol=1e-5)


def test_intervals_of_a_pair_no_monte_carlo_measured_come_with_a_warning():
    """identify's warning (``measured.unmeasured``): a kind of a lab's own, or a package pair
    whose coverage cell has not passed at 50 recordings; none for the measured pairs."""
    from armimp_jax._identification.measured import unmeasured

    arm = paper.arm(2)
    # a noisy model of these kinds: the intervals come with the warning that no coverage cell measured them
    (warning,) = unmeasured(aj.make_trial(Damper(), arm=arm, friction=SmoothCoulomb(0.06), **NOISE))
    assert "a controller of kind 'toy_damper'" in warning and "friction law of kind 'toy_smooth_coulomb'" in warning
    assert unmeasured(aj.make_trial(aj.Admittance(), arm=arm, friction=aj.CoulombViscous(0.05), **NOISE)) == []
    assert unmeasured(aj.make_trial(aj.IMBIC(), arm=arm, friction=aj.NO_FRICTION, **NOISE)) == []
    # a package pair whose coverage cell has not yet passed at 50 recordings: provisional, said so
    (pending,) = unmeasured(aj.make_trial(aj.PD(), arm=arm, friction=aj.CoulombViscous(0.05), **NOISE))
    assert "under pd through coulomb_viscous friction has not yet been measured" in pending


def test_the_toy_kinds_sweep_from_a_config(tmp_path):
    config = tmp_path / "toy.toml"
    config.write_text(
        '[controller]\ntype = "toy_damper"\nd = [15.0, 30.0]\n[friction]\ntype = "toy_smooth_coulomb"\ntau_c = 0.05\n'
        "[record]\nseconds = 2.0\n[welch]\nnperseg = 512\n"
    )
    grid, points, _ = study.read_toml(config)
    pts = study.expand(grid, points)
    assert [p["d"] for p in pts] == [15.0, 30.0] and all(p["eps"] == 0.005 for p in pts)
    settings = study.SweepSettings(pts, seeds=1, method="ark3", substeps=5)
    result = study.run_sweep(settings, tmp_path / "out", warn=lambda _: None)
    rows = result["conditions"]
    assert len(rows) == 2 and all(r["n"] == 1 and np.isfinite(r["stats"]["phi_T"]["mean"]) for r in rows)
    trial = study.Point.parse(pts[1]).trial
    np.testing.assert_array_equal(trial.controller.d, 30.0 * np.eye(2))


def test_a_kind_defined_without_a_file_is_refused_as_a_duplicate_in_words():
    """A class made by ``exec`` (a notebook, a docs example) has no source file: run again in the
    same module it is redefined; one of the same kind from another module is refused in one line,
    as any duplicate is, not by ``inspect``'s error."""
    source = (
        "class Twice(aj.AbstractController):\n"
        "    kind: ClassVar[str] = 'toy_twice'\n"
        "    UNITS: ClassVar[dict] = {}\n"
        "    def init(self, x0):\n        return ()\n"
        "    def step(self, memory, x, xd, fh, f_delta, x0, period):\n        return f_delta, memory\n"
    )
    try:
        exec(source, dict(aj=aj, ClassVar=ClassVar, __name__="notebook"))
        first = controller_kind("toy_twice")
        exec(source, dict(aj=aj, ClassVar=ClassVar, __name__="notebook"))  # the cell run again: redefined
        assert controller_kind("toy_twice") is not first and controller_kind("toy_twice").__name__ == "Twice"
        with pytest.raises(TypeError, match="the controller kind 'toy_twice' is Twice's already"):
            exec(source, dict(aj=aj, ClassVar=ClassVar, __name__="another_notebook"))
    finally:  # the registry is the process's: leave it as the other tests know it
        CONTROLLER_KINDS._kinds.pop("toy_twice", None)


def test_kinds_are_found_by_name_and_unknown_or_duplicate_ones_refused():
    assert controller_kind("toy_damper") is Damper and friction_kind("toy_smooth_coulomb") is SmoothCoulomb
    with pytest.raises(ValueError, match="unknown controller type 'mpc'; known: admittance, imbic, pd, toy_damper"):
        controller_kind("mpc")
    with pytest.raises(ValueError, match="unknown friction type 'dahl'; known: coulomb_viscous, lugre"):
        study.normalize_point(dict(friction="dahl"))
    with pytest.raises(TypeError, match="the controller kind 'pd' is PD's already"):

        class Other(aj.AbstractController):  # noqa: F841
            kind: ClassVar[str] = "pd"
            UNITS: ClassVar[dict] = {}

            def init(self, x0):
                return ()

            def step(self, memory, x, xd, fh, f_delta, x0, period):
                return f_delta, memory
