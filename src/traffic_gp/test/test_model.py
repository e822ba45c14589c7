"""TrafficGP (TensorFlow, kept tiny): recovers a known pattern better than the mean baseline,
handles exposure, warm-starts, saves and loads without training, refuses bad input. The shared
`small_world` and `fitted` fixtures are in conftest.py."""
import json

import numpy as np
import pytest

from robot_common.errors import ConfigError
from traffic_gp.baselines import BinnedMean
from traffic_gp.errors import ModelFormatError, NotFittedError
from traffic_gp.model import TrafficGP
from traffic_gp.observations import Observations
from traffic_gp.persistence import PARAM_PREFIX, read_header
from traffic_gp.posterior import PosteriorSnapshot
from traffic_gp.sim.evaluation import day_times, model_counts, rmse


def test_recovers_the_true_pattern_better_than_the_mean_per_cell_and_bin(small_world, fitted):
    sim, obs = small_world
    times = day_times(10.0)
    truth = sim.expected_count(times)
    baseline = BinnedMean(sim.cells, bin_minutes=30).fit(obs)
    gp_error = rmse(model_counts(fitted, sim, times), truth)
    base_error = rmse(model_counts(baseline, sim, times), truth)
    assert gp_error < 0.8 * base_error, (gp_error, base_error)
    main = np.nonzero(sim.layout.main)[0]
    busy, quiet = fitted.predict(sim.cells.x[main], sim.cells.y[main], 48 + 14.0), \
        fitted.predict(sim.cells.x[main], sim.cells.y[main], 48 + 2.0)
    assert busy.mean() > 5 * quiet.mean()


def test_exposure_means_a_half_seen_cell_counts_half(small_world):
    """Counts from half-seen cells watched 10 s: the density must come out as the truth."""
    rng = np.random.default_rng(3)
    n = 6000
    x, y, t = rng.uniform(0, 4, n), rng.uniform(0, 4, n), rng.uniform(0, 24, n)
    expo = 0.5 * 0.25 * (1 + 10.0 / 20.0) * np.ones(n)
    obs = Observations(x, y, t, expo, rng.poisson(0.8 * expo))
    model = TrafficGP(n_inducing=10, hourly=False, n_steps=150, batch_size=256,
                      likelihood="poisson", profile="none", validation_fraction=0).fit(obs)
    assert model.predict(2.0, 2.0, 12.0)[0] == pytest.approx(0.8, rel=0.15)


def test_save_and_load_predict_identically_without_training(small_world, fitted, tmp_path):
    sim, _ = small_world
    path = fitted.save(tmp_path / "crowd.npz", meta={"map": "generated:4"})
    loaded = TrafficGP.load(path)
    x, y, t = sim.cells.x, sim.cells.y, np.full(sim.cells.n_cells, 58.9)
    np.testing.assert_array_equal(loaded.predict_latent(x, y, t)[0], fitted.predict_latent(x, y, t)[0])
    np.testing.assert_array_equal(loaded.predict_latent(x, y, t)[1], fitted.predict_latent(x, y, t)[1])
    assert loaded.n_steps_ == fitted.n_steps_ and loaded._trainer is None
    assert loaded.get_params() == fitted.get_params() and loaded.meta_ == {"map": "generated:4"}
    assert len(loaded.data_) == len(fitted.data_)


def test_partial_fit_after_loading_warm_starts_and_adds_rows(small_world, fitted, tmp_path):
    sim, obs = small_world
    model = TrafficGP.load(fitted.save(tmp_path / "copy.npz"))
    x, y = sim.cells.x[:20], sim.cells.y[:20]
    before = model.predict(x, y, 50.0)
    rows = len(model.data_)
    model.partial_fit(obs.subset(np.arange(500)), n_steps=0)      # new rows, no step: unchanged
    np.testing.assert_array_equal(model.predict(x, y, 50.0), before)
    assert len(model.data_) == rows + 500
    model.partial_fit(obs.subset(np.arange(500, 1000)), n_steps=10)
    assert model.n_steps_ == fitted.n_steps_ + 10 and len(model.data_) == rows + 1000
    assert not np.array_equal(model.predict(x, y, 50.0), before)
    assert np.allclose(model.predict(x, y, 50.0), before, rtol=0.5), "continued, not restarted"


def test_model_files_of_another_version_or_garbage_are_refused(fitted, tmp_path):
    path = fitted.save(tmp_path / "m.npz", include_data=False)
    assert read_header(path)["format_version"] == 1
    with np.load(path) as archive:
        arrays = {key: archive[key] for key in archive.files}
    header = json.loads(str(arrays["header"]))
    header["format_version"] = 99
    arrays["header"] = np.array(json.dumps(header))
    np.savez(tmp_path / "future.npz", **arrays)
    with pytest.raises(ModelFormatError, match="version 99"):
        TrafficGP.load(tmp_path / "future.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a model")
    with pytest.raises(ModelFormatError, match="cannot read"):
        TrafficGP.load(tmp_path / "junk.npz")
    with pytest.raises(ModelFormatError, match="cannot read"):
        TrafficGP.load(tmp_path / "missing.npz")


def test_bad_use_gives_clear_errors(small_world, tmp_path):
    sim, obs = small_world
    with pytest.raises(NotFittedError, match="not fitted"):
        TrafficGP().predict(1.0, 1.0, 1.0)
    with pytest.raises(NotFittedError, match="not fitted"):
        TrafficGP().save(tmp_path / "never.npz")
    with pytest.raises(NotFittedError, match="zero observations"):
        TrafficGP().fit(Observations.empty())
    with pytest.raises(ConfigError, match="n_inducing=0"):
        TrafficGP(n_inducing=0).fit(obs)
    with pytest.raises(ConfigError, match="inducing points need"):
        TrafficGP(n_inducing=50, n_steps=0).fit(obs.subset(np.arange(10)))


def test_the_weekly_model_tells_days_apart_and_the_daily_one_repeats(small_world, fitted):
    sim, obs = small_world
    x, y = sim.cells.x[:10], sim.cells.y[:10]
    np.testing.assert_array_equal(fitted.predict(x, y, 10.5), fitted.predict(x, y, 10.5 + 24.0))
    weekly = TrafficGP(n_inducing=20, weekly=True, n_steps=0, likelihood="poisson",
                       profile="none", fallback=False, calibrate=False).fit(obs)
    assert weekly.period == 168.0
    here = np.array([[5.0, 6.5, 58.5]])
    prior = weekly.model_.kernel(here, here).numpy()[0, 0]
    a_week_later = weekly.model_.kernel(here, here + [0, 0, 168.0]).numpy()[0, 0]
    a_day_later = weekly.model_.kernel(here, here + [0, 0, 24.0]).numpy()[0, 0]
    assert a_week_later == pytest.approx(prior) and a_day_later < 0.95 * prior


@pytest.mark.parametrize("layout", ["space x day + space x hour x day", "space x day",
                                    "with the weekly terms"])
def test_numpy_posterior_of_a_saved_model_predicts_what_gpflow_predicts(small_world, fitted, layout,
                                                                        tmp_path):
    """The snapshot re-implements the SVGP's predictions in NumPy; GPflow is the reference. A
    few training steps (eager, about 0.25 CPU-s each for the weekly kernel) move q(u) and the
    hyperparameters off their initial values: what is compared needs no converged model."""
    sim, obs = small_world
    model = {"space x day + space x hour x day": fitted,
             "space x day": TrafficGP(n_inducing=30, hourly=False, n_steps=10, batch_size=512,
                                      likelihood="negbin", profile="none", fallback=False,
                                      calibrate=False, refit_steps=0),
             "with the weekly terms": TrafficGP(n_inducing=30, weekly=True, n_steps=8,
                                                batch_size=512, likelihood="poisson",
                                                profile="none", fallback=False,
                                                calibrate=False, refit_steps=0)}[layout]
    if not hasattr(model, "model_"):
        model.fit(obs)
    snapshot = PosteriorSnapshot.load(model.save(tmp_path / "crowd.npz"))
    rng = np.random.default_rng(1)
    x, y, t = sim.cells.x, sim.cells.y, rng.uniform(0, 168, sim.cells.n_cells)
    reference, ours = model.predict_latent(x, y, t), snapshot.predict_latent(x, y, t)
    np.testing.assert_allclose(ours[0], reference[0], rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(ours[1], reference[1], rtol=1e-5, atol=1e-8)
    some = slice(0, 40)
    np.testing.assert_allclose(snapshot.sample_totals(x[some], y[some], t[some], 0.25, 200),
                               model.sample_totals(x[some], y[some], t[some], 0.25, 200), rtol=1e-4)
    assert snapshot.n_steps_ == model.n_steps_ and snapshot.period == model.period


def test_a_saved_model_loads_and_predicts_without_tensorflow(fitted, tmp_path):
    import subprocess
    import sys

    path = fitted.save(tmp_path / "crowd.npz")
    expected = fitted.predict(1.5, 1.5, 14.0)[0]
    code = ("import sys, time; start = time.perf_counter()\n"
            "from traffic_gp.posterior import PosteriorSnapshot\n"
            f"value = PosteriorSnapshot.load({str(path)!r}).predict(1.5, 1.5, 14.0)[0]\n"
            "print(value, 'tensorflow' in sys.modules, time.perf_counter() - start)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    value, tensorflow_imported, _seconds = out.stdout.split()
    assert tensorflow_imported == "False"
    assert float(value) == pytest.approx(expected, rel=1e-6)


def test_a_damaged_parameter_set_is_a_clear_error(fitted, tmp_path):
    path = fitted.save(tmp_path / "crowd.npz")
    with np.load(path) as archive:
        arrays = {k: archive[k] for k in archive.files if k != PARAM_PREFIX + ".q_sqrt"}
    np.savez(tmp_path / "damaged.npz", **arrays)
    with pytest.raises(ModelFormatError, match="unexpected saved parameters"):
        PosteriorSnapshot.load(tmp_path / "damaged.npz")
