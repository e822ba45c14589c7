"""Density grids over the model's cells at several times (the node's `~predict_density`)."""
import numpy as np
import pytest

from robot_common.cells import CellGrid
from robot_common.maps import FREE, OCCUPIED, UNKNOWN, GridMap
from traffic_gp.errors import TrafficError
from traffic_gp.observations import Observations
from traffic_gp.posterior import LatentPredictions, PosteriorSnapshot
from traffic_gp.queries import MAX_DENSITY_TIMES, CrowdQueries
from traffic_gp.quick import BaselineForecast


def small_floor() -> CellGrid:
    """A 3 m x 2 m floor of 0.1 m map cells in 0.5 m model cells (4 x 6), origin (1, 2): a wall
    along the bottom, an unknown map cell in the model cell at row 2, col 4."""
    cells = np.full((20, 30), FREE, np.int8)
    cells[:3, :] = OCCUPIED          # model row 0 (map rows 0..4) holds wall cells
    cells[12, 22] = UNKNOWN          # model cell (2, 4): map rows 10..14, cols 20..24
    return CellGrid(GridMap(cells, 0.1, (1.0, 2.0, 0.0)), 5)


class Plane(LatentPredictions):
    """A crowd model whose log density is Gaussian with mean log(x + 10 y + t) and variance
    `var`, so its expected density and spread are known by hand."""

    def __init__(self, var: float):
        self.var = var

    def _latent_at(self, x, y, t, full_cov: bool = False):
        mean = np.log(np.asarray(x) + 10.0 * np.asarray(y) + np.asarray(t))
        return mean, np.full(mean.shape, self.var)


def test_grids_are_laid_out_by_time_row_and_column_from_the_origin():
    cells = small_floor()
    density, stddev = CrowdQueries(Plane(0.0), cells).density_grids([0.0, 5.0])
    assert density.shape == stddev.shape == (2, 4, 6)
    # model cell (row 1, col 2) has its centre at (1 + 2.5 x 0.5, 2 + 1.5 x 0.5) = (2.25, 2.75):
    # density 2.25 + 27.5 + t, no spread (a point forecast: NaN)
    assert density[0, 1, 2] == pytest.approx(29.75)
    assert density[1, 1, 2] == pytest.approx(34.75)
    assert density[1, 3, 5] == pytest.approx(1 + 2.75 + 10 * (2 + 1.75) + 5.0)
    assert np.isnan(stddev[:, 1:, :]).all()
    # the bottom row holds walls and the unknown cell is outside the model: 0, NaN
    assert np.all(density[:, 0, :] == 0) and np.all(density[:, 2, 4] == 0)
    assert np.isnan(stddev[:, 0, :]).all()
    assert np.count_nonzero(density[0]) == cells.n_cells == 4 * 6 - 6 - 1


def test_spread_is_that_of_the_lognormal_density():
    # f ~ N(log 29.75, 0.5) at cell (1, 2) at t = 0: E exp(f) = 29.75 e^0.25, and
    # sd exp(f) = 29.75 e^0.25 sqrt(e^0.5 - 1)
    density, stddev = CrowdQueries(Plane(0.5), small_floor()).density_grids([0.0])
    assert density[0, 1, 2] == pytest.approx(29.75 * np.exp(0.25))
    assert stddev[0, 1, 2] == pytest.approx(29.75 * np.exp(0.25) * np.sqrt(np.expm1(0.5)))
    assert np.isnan(stddev[0, 0, 0])


def test_a_baseline_fitted_on_constant_counts_serves_their_density_everywhere():
    # every free cell watched each hour of one day with exposure 0.25 m^2, one person each time:
    # 4 people per m^2 in every cell at every hour; too few rows for a hold-out, so the binned
    # mean is served without a calibrated width: no standard deviation
    cells = small_floor()
    hours = np.arange(24) + 0.5
    n = cells.n_cells
    obs = Observations(np.tile(cells.x, 24), np.tile(cells.y, 24), np.repeat(hours, n),
                       np.full(24 * n, 0.25), np.ones(24 * n))
    model = BaselineForecast(validation_fraction=0.0).fit(obs, cells)
    density, stddev = CrowdQueries(model, cells).density_grids([3.2, 17.9, 23.99])
    np.testing.assert_allclose(density[:, cells.rows, cells.cols], 4.0, rtol=1e-9)
    assert np.all(density[:, 0, :] == 0) and np.isnan(stddev).all()


def test_too_many_or_no_or_non_finite_times_are_refused():
    queries = CrowdQueries(Plane(0.1), small_floor())
    with pytest.raises(TrafficError, match=f"{MAX_DENSITY_TIMES + 1} times asked: give 1 to 48"):
        queries.density_grids(np.zeros(MAX_DENSITY_TIMES + 1))
    with pytest.raises(TrafficError, match="0 times asked"):
        queries.density_grids([])
    with pytest.raises(TrafficError, match="finite"):
        queries.density_grids([1.0, np.nan])
    assert queries.density_grids(np.zeros(MAX_DENSITY_TIMES))[0].shape == (48, 4, 6)


def random_posterior(n_inducing: int = 30, seed: int = 0) -> PosteriorSnapshot:
    """A posterior of the saved layout (no TensorFlow): a sum of two products, SE(space) x
    Periodic(24 h) and SE(space) x Periodic(1 h) x Periodic(24 h), random parameters."""
    rng = np.random.default_rng(seed)
    values = {".mean_function.c": np.array([-2.0]),
              ".inducing_variable.Z": np.column_stack([rng.uniform(0, 15, (n_inducing, 2)),
                                                       rng.uniform(0, 24, n_inducing)]),
              ".q_mu": rng.normal(size=(n_inducing, 1)),
              ".q_sqrt": 0.3 * rng.normal(size=(1, n_inducing * (n_inducing + 1) // 2))}
    for term, periods in enumerate([(24.0,), (1.0, 24.0)]):
        prefix = f".kernel.kernels[{term}].kernels"
        values[f"{prefix}[0].variance"] = np.array(0.5)
        values[f"{prefix}[0].lengthscales"] = np.array(3.0)
        for k, period in enumerate(periods, start=1):
            values[f"{prefix}[{k}].base_kernel.variance"] = np.array(1.0)
            values[f"{prefix}[{k}].base_kernel.lengthscales"] = np.array(0.7)
            values[f"{prefix}[{k}].period"] = np.array(period)   # softplus(period): any > 0
    return PosteriorSnapshot({"params": {}}, values)


def test_a_saved_posterior_predicts_grids_as_it_predicts_each_place_and_time():
    # the fast path (space factors once per place) against the row-by-row prediction
    snapshot = random_posterior()
    x, y = np.array([1.5, 8.5, 12.5, 3.5]), np.array([2.5, 6.5, 1.5, 9.5])
    times = np.array([8.0, 12.4, 30.9])
    mean, var = snapshot.predict_latent_grid(x, y, times)
    slow_mean, slow_var = snapshot.predict_latent(np.tile(x, 3), np.tile(y, 3), np.repeat(times, 4))
    np.testing.assert_allclose(mean.ravel(), slow_mean, rtol=1e-10)
    np.testing.assert_allclose(var.ravel(), slow_var, rtol=1e-10)
    assert mean.shape == (3, 4) and np.ptp(mean[:, 1]) > 0.01 and np.ptp(mean[0]) > 0.01
    # more places than one block of the fast path
    many = np.linspace(0.0, 15.0, 6000)      # blocks of 2501 places for 2 terms
    mean, var = snapshot.predict_latent_grid(many, many[::-1], times[:2])
    slow_mean, slow_var = snapshot.predict_latent(np.tile(many, 2), np.tile(many[::-1], 2),
                                                  np.repeat(times[:2], 6000))
    np.testing.assert_allclose(mean.ravel(), slow_mean, rtol=1e-10)
    np.testing.assert_allclose(var.ravel(), slow_var, rtol=1e-10)
