"""The negative-binomial count likelihood and early stopping (TensorFlow, kept small).

Data come from a known overdispersed process (Poisson counts whose rate has a Gamma(r, r) factor
per row, r = 2): the expected values below (the 0.9 level, r) are those of the generating
process, not of the code under test."""
import numpy as np
import pytest
from scipy import stats

from traffic_gp import predictive
from traffic_gp.model import TrafficGP
from traffic_gp.observations import Observations
from traffic_gp.posterior import PosteriorSnapshot

TRUE_R = 2.0


def true_rate(t):
    return 4.0 * np.exp(np.sin(2 * np.pi * np.asarray(t) / 24.0))


def overdispersed(n, seed):
    rng = np.random.default_rng(seed)
    x, y, t = rng.uniform(0, 4, n), rng.uniform(0, 4, n), rng.uniform(0, 5 * 24, n)   # 5 days
    rate = true_rate(t) * rng.gamma(TRUE_R, 1.0 / TRUE_R, n)
    return Observations(x, y, t, np.ones(n), rng.poisson(rate))


def test_the_numpy_negative_binomial_mixture_matches_sampling():
    rng = np.random.default_rng(0)
    mean, var, r = 1.2, 0.3, 3.0
    mu = np.exp(rng.normal(mean, np.sqrt(var), 400000))
    samples = rng.poisson(mu * rng.gamma(r, 1.0 / r, mu.size))
    for k in (0, 2, 5, 12):
        assert predictive.cdf(k, mean, var, 1.0, r) == pytest.approx(np.mean(samples <= k),
                                                                     abs=3e-3)
    low, high = predictive.interval(0.9, mean, var, 1.0, r)
    assert (low, high) == (np.quantile(samples, 0.05, method="inverted_cdf"),
                           np.quantile(samples, 0.95, method="inverted_cdf"))
    counts = np.array([0, 3, 40])
    np.testing.assert_allclose(predictive.log_density(counts, np.log(7.0), 0.0, 1.0, r),
                               stats.nbinom.logpmf(counts, r, r / (r + 7.0)), rtol=1e-9)


def test_large_counts_get_quantiles_quickly_and_exactly():
    rate = np.array([2000.0, 350.0, 0.0])
    for q in (0.05, 0.95):
        np.testing.assert_array_equal(predictive.quantile(q, np.log(np.maximum(rate, 1e-9)), 0.0,
                                                          1.0), stats.poisson.ppf(q, rate))


@pytest.fixture(scope="module")
def fitted_pair():
    train = overdispersed(6000, seed=1)
    settings = dict(n_inducing=15, hourly=False, n_steps=600, batch_size=512, random_state=0,
                    profile="none", fallback=False, calibrate=False)   # the trained likelihoods
    return (TrafficGP(likelihood="negbin", **settings).fit(train),
            TrafficGP(likelihood="poisson", **settings).fit(train))


def test_negative_binomial_intervals_are_calibrated_where_poisson_ones_are_not(fitted_pair):
    negbin, poisson = fitted_pair
    test = overdispersed(4000, seed=2)
    rng = np.random.default_rng(3)
    covers = {}
    for name, model in (("negbin", negbin), ("poisson", poisson)):
        mean, var = model.predict_latent(test.x, test.y, test.t)
        covers[name] = predictive.coverage(test.count, mean, var, 1.0, 0.9, rng,
                                           model.dispersion_)["pit"]
    # 4000 rows: the binomial standard error of a 0.9 share is 0.005
    assert 0.87 <= covers["negbin"] <= 0.93, covers
    assert covers["poisson"] < 0.8, covers
    assert negbin.dispersion_ == pytest.approx(TRUE_R, rel=0.3)
    assert poisson.dispersion_ is None
    assert negbin.score(test) > poisson.score(test)
    expected = negbin.predict(2.0, 2.0, np.array([6.0, 18.0]))
    np.testing.assert_allclose(expected, true_rate([6.0, 18.0]), rtol=0.2)


def test_the_numpy_posterior_carries_the_dispersion(fitted_pair, tmp_path):
    negbin, _ = fitted_pair
    snapshot = PosteriorSnapshot.load(negbin.save(tmp_path / "nb.npz"))
    assert snapshot.dispersion_ == pytest.approx(negbin.dispersion_, rel=1e-9)
    t = np.linspace(0, 24, 30)
    for ours, reference in zip(snapshot.predict_interval(1.0, 1.0, t),
                               negbin.predict_interval(1.0, 1.0, t)):
        np.testing.assert_array_equal(ours, reference)
    loaded = TrafficGP.load(tmp_path / "nb.npz")
    assert loaded.likelihood == "negbin" and loaded.dispersion_ == negbin.dispersion_


# at most 500 steps: the plateau comes after the 100 warm-up steps, long before the anneal's
# schedule (the last 40 %, from step 300), so the early anneal and stop are still what is tested
EARLY = dict(n_inducing=10, hourly=False, n_steps=500, batch_size=256, eval_every=10, patience=3,
             likelihood="negbin", profile="none", fallback=False, calibrate=False, refit_steps=0,
             random_state=0)


def test_training_stops_on_the_held_out_days_and_keeps_the_best_state():
    train = overdispersed(3000, seed=4)
    model = TrafficGP(**EARLY).fit(train)
    assert model.stopped_early_ and model.n_steps_ < 500
    # the plateau started the anneal (scheduled at step 300) early, and fit ran it to its end
    assert model.anneal_start_ is not None and model.anneal_start_ < 300
    assert model.n_steps_ >= model.anneal_start_ + 0.4 * 500
    assert len(model.validation_loss_) == len(model.eval_steps_) == len(model.elbo_)
    losses, lowest = np.array(model.validation_loss_), min(model.validation_loss_)
    ties = np.nonzero(losses <= lowest + 1e-3 * abs(lowest))[0]    # the documented tie rule
    assert model.best_step_ == model.eval_steps_[ties[-1]]
    assert model.n_steps_ - model.eval_steps_[int(np.argmin(losses))] >= 3 * 10
    held_out = train.subset(np.nonzero(train.t >= 4 * 24.0)[0])      # the last of the 5 days
    assert model.split_["cut_hours"] == 4 * 24.0
    assert -model.score(held_out) == pytest.approx(losses[ties[-1]], rel=1e-3)
    again = TrafficGP(**EARLY).fit(train)
    assert again.n_steps_ == model.n_steps_ and again.validation_loss_ == model.validation_loss_


def test_without_a_hold_out_the_step_count_is_run_in_full():
    train = overdispersed(2000, seed=5)
    model = TrafficGP(n_inducing=10, hourly=False, n_steps=120, batch_size=256,
                      validation_fraction=0.0).fit(train)
    assert model.n_steps_ == 120 and not model.stopped_early_ and model.best_step_ is None
    assert model.eval_steps_[-1] == 120 and np.all(np.isfinite(model.elbo_))
