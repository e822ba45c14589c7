"""The IncrementalGMM core: the maths by hand, the fast path against a slow literal reference,
order-independent batches, and learning simulated scenes with known truth."""
import json
import math

import numpy as np
import pytest

from igmm_layers import IncrementalGMM
from igmm_layers.errors import InvalidInputError, NotFittedError
from igmm_layers.sim.metrics import match_scores, ospa
from igmm_layers.sim.reference import ReferenceIGMM
from robot_sim.detections import random_scene, simulate_detections


def test_published_covariance_update_goes_negative_where_the_exact_one_does_not():
    # 1-D, sigma_ini = 1: a second point 2.5 sigma away is not novel (6.25 < -2 ln 0.01 = 9.21);
    # posterior 1, sp = 2, omega = 1/2, new mean 1.25.
    # published: 0.5 * 1 + 0.5 * 1.25^2 - 1.25^2 = -0.28125; exact: 0.5 * (1 + 0.5 * 2.5^2) = 2.0625
    X = np.array([[0.0], [2.5]])
    published = ReferenceIGMM(sigma_ini=1.0, covariance_update="published").partial_fit(X)
    exact = ReferenceIGMM(sigma_ini=1.0).partial_fit(X)
    fast = IncrementalGMM(sigma_ini=1.0).partial_fit(X)
    assert published.covs[0][0, 0] == pytest.approx(-0.28125)
    assert exact.covs[0][0, 0] == pytest.approx(2.0625)
    assert fast.n_components_ == 1
    assert fast.means_[0, 0] == pytest.approx(1.25)
    assert fast.covariances_[0, 0, 0] == pytest.approx(2.0625)
    assert fast.precisions_[0, 0, 0] == pytest.approx(1 / 2.0625)
    assert fast.log_dets_[0] == pytest.approx(math.log(2.0625))


def test_exact_update_stays_positive_definite_where_the_published_one_breaks():
    # At every place: a first detection, then one 2.1-3.0 sigma away (inside the novelty gate),
    # then more detections around; the published update is indefinite after any such pair.
    rng = np.random.default_rng(5)
    sigma = 0.3
    X = []
    for k in range(20):
        centre = np.array([10.0 * k, 0.0])
        angle, distance = rng.uniform(0, 2 * np.pi), rng.uniform(2.1, 3.0) * sigma
        X += [centre, centre + distance * np.array([np.cos(angle), np.sin(angle)])]
        X += list(centre + rng.normal(0, sigma, (10, 2)))
    published = ReferenceIGMM(sigma_ini=sigma, v_min=10**6, covariance_update="published")
    fast = IncrementalGMM(sigma_ini=sigma, v_min=10**6)
    min_published = np.inf
    for x in X:
        published.learn_one(np.asarray(x))
        fast.partial_fit(np.asarray(x)[None])
        min_published = min(min_published, min(np.linalg.eigvalsh(c).min() for c in published.covs))
        assert np.linalg.eigvalsh(fast.covariances_).min() > 0
    assert min_published < 0


def test_novelty_threshold_is_the_squared_mahalanobis_distance_minus_two_ln_tau():
    edge = math.sqrt(2 * math.log(100))  # tau = 0.01, sigma_ini = 1
    inside = IncrementalGMM(sigma_ini=1.0, novelty_constant=0.01).partial_fit([[0.0], [edge - 1e-6]])
    outside = IncrementalGMM(sigma_ini=1.0, novelty_constant=0.01).partial_fit([[0.0], [edge + 1e-6]])
    assert (inside.n_components_, outside.n_components_) == (1, 2)
    np.testing.assert_array_equal(outside.is_novel([[edge + 1e-6], [20.0]]), [False, True])
    np.testing.assert_allclose(outside.covariances_[1], [[1.0]])  # sigma_ini^2 I
    assert list(outside.support_) == [1.0, 1.0] and list(outside.ages_) == [1, 1]


def test_sigma_ini_is_covariance_scale_times_data_range():
    model = IncrementalGMM(covariance_scale=0.02, data_range=[10.0, 5.0]).partial_fit([[1.0, 2.0]])
    np.testing.assert_allclose(model.covariances_[0], np.diag([0.2 ** 2, 0.1 ** 2]))


def test_confidence_weights_the_update():
    # sp = 1 + 0.5, omega = 0.5 / 1.5 = 1/3: mean 1/3, variance (2/3)(1 + (1/3) * 1) = 8/9
    model = IncrementalGMM(sigma_ini=1.0).partial_fit([[0.0], [1.0]], sample_weight=[1.0, 0.5])
    assert model.support_[0] == pytest.approx(1.5)
    assert model.means_[0, 0] == pytest.approx(1 / 3)
    assert model.covariances_[0, 0, 0] == pytest.approx(8 / 9)


def test_measurement_covariance_widens_new_and_updated_clusters():
    R = np.diag([0.3, 0.1])
    model = IncrementalGMM(sigma_ini=0.5).partial_fit([[0.0, 0.0], [0.2, 0.0]], measurement_cov=[R, R])
    # new: 0.25 I + R; then omega = 1/2: 0.5 (C + 0.5 e e^T) + 0.5 R
    np.testing.assert_allclose(model.covariances_[0], np.diag([0.5 * (0.55 + 0.5 * 0.04) + 0.15,
                                                              0.5 * 0.35 + 0.05]))
    np.testing.assert_allclose(model.precisions_[0], np.linalg.inv(model.covariances_[0]))
    assert model.log_dets_[0] == pytest.approx(np.linalg.slogdet(model.covariances_[0])[1])
    # the same as (n, D) variances
    diag = IncrementalGMM(sigma_ini=0.5).partial_fit([[0.0, 0.0], [0.2, 0.0]],
                                                     measurement_cov=[[0.3, 0.1], [0.3, 0.1]])
    np.testing.assert_allclose(diag.covariances_, model.covariances_)


def test_a_cluster_is_pruned_when_its_age_passes_v_min_with_too_little_support():
    model = IncrementalGMM(sigma_ini=0.1, v_min=10, sp_min=3.0).partial_fit(np.zeros((20, 2)))
    model.partial_fit([[5.0, 5.0]])
    assert model.n_components_ == 2
    model.partial_fit(np.zeros((9, 2)))
    assert model.n_components_ == 2 and model.ages_[1] == 10
    model.partial_fit(np.zeros((1, 2)))
    assert model.n_components_ == 1
    np.testing.assert_allclose(model.means_, [[0.0, 0.0]])


@pytest.mark.parametrize("dim,weights,with_cov", [(2, False, False), (5, True, True), (3, True, False)])
def test_fast_path_matches_the_literal_reference(dim, weights, with_cov):
    rng = np.random.default_rng(dim)
    centres = rng.uniform(0, 6, size=(4, dim))
    X = np.concatenate([rng.normal(c, 0.3, size=(70, dim)) for c in centres]
                       + [rng.uniform(0, 6, size=(15, dim))])
    rng.shuffle(X)
    w = rng.uniform(0.3, 1.0, len(X)) if weights else None
    cov = None
    if with_cov:
        A = rng.normal(scale=0.15, size=(len(X), dim, dim))
        cov = A @ np.swapaxes(A, 1, 2)
    fast = IncrementalGMM(sigma_ini=0.5, v_min=40, sp_min=4.0, refresh_interval=10**9)
    fast.partial_fit(X, w, measurement_cov=cov)
    slow = ReferenceIGMM(sigma_ini=0.5, v_min=40, sp_min=4.0).partial_fit(X, w, cov)
    assert fast.n_components_ == len(slow.means) >= 4
    np.testing.assert_allclose(fast.means_, np.array(slow.means), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(fast.covariances_, np.array(slow.covs), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(fast.support_, slow.support, rtol=1e-7)
    np.testing.assert_array_equal(fast.ages_, slow.ages)
    # precisions and log-determinants kept by rank-one updates = recomputed from scratch
    np.testing.assert_allclose(fast.precisions_, np.linalg.inv(np.array(slow.covs)), rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(fast.log_dets_, np.linalg.slogdet(np.array(slow.covs))[1], atol=1e-8)


def test_rank_one_updates_do_not_drift_over_many_updates():
    rng = np.random.default_rng(3)
    centres = rng.uniform(0, 10, (6, 4))
    X = centres[rng.integers(0, 6, 20000)] + rng.normal(0, 0.3, (20000, 4))
    model = IncrementalGMM(sigma_ini=0.5, refresh_interval=10**9).partial_fit(X)
    exact = np.linalg.inv(model.covariances_)
    scale = np.abs(exact).max(axis=(1, 2))[:, None, None]
    assert np.max(np.abs(model.precisions_ - exact) / scale) < 1e-9
    np.testing.assert_allclose(model.log_dets_, np.linalg.slogdet(model.covariances_)[1], atol=1e-9)


def _scene(seed, clutter=0.1):
    scene = random_scene(10, bounds=[(0, 20), (0, 20)], min_separation=1.5, random_state=seed)
    dets = simulate_detections(scene, mean_detections=20, noise_std=0.1, clutter_fraction=clutter,
                               random_state=seed + 100)
    return np.array([obj.position for obj in scene]), dets


def test_batch_mode_gives_bit_identical_models_for_any_order():
    truth, dets = _scene(7)
    rng = np.random.default_rng(0)
    models = []
    for _ in range(20):
        order = rng.permutation(len(dets))
        models.append(IncrementalGMM(covariance_scale=0.01, data_range=20, v_min=50, batch=True)
                      .fit(dets.positions[order], dets.confidences[order]))
    for model in models[1:]:
        np.testing.assert_array_equal(model.means_, models[0].means_)
        np.testing.assert_array_equal(model.covariances_, models[0].covariances_)
        np.testing.assert_array_equal(model.support_, models[0].support_)
    # sequential learning of the same orders does depend on the order
    sequential = [IncrementalGMM(covariance_scale=0.01, data_range=20, v_min=50)
                  .fit(dets.positions[order]) for order in (rng.permutation(len(dets)) for _ in range(2))]
    assert not np.array_equal(sequential[0].means_, sequential[1].means_)
    assert match_scores(models[0].means_[models[0].confirmed_], truth)["recall"] == 1.0


def _chunkings(n, count, rng):
    """`count` random orders of n rows, each split into 1-8 chunks at random places."""
    for _ in range(count):
        order = rng.permutation(n)
        cuts = np.sort(rng.choice(np.arange(1, n), int(rng.integers(0, 8)), replace=False))
        yield np.split(order, cuts)


def _fit_in_chunks(chunks, X, weights, batch):
    model = IncrementalGMM(covariance_scale=0.01, data_range=20, batch=batch)
    for part in chunks:
        model.partial_fit(X[part], weights[part])
    return model


def test_batch_mode_is_the_same_for_the_same_data_in_any_chunks_and_orders():
    # dense scene: 25 objects 1 m apart, 10 detections each, 0.15 m noise, 10% clutter
    scene = random_scene(25, bounds=[(0, 20), (0, 20)], min_separation=1.0, random_state=3)
    dets = simulate_detections(scene, mean_detections=10, noise_std=0.15, clutter_fraction=0.1,
                               random_state=4)
    X, weights = dets.positions, dets.confidences
    rng = np.random.default_rng(1)
    chunkings = list(_chunkings(len(X), 8, rng))
    assert len({len(chunks) for chunks in chunkings}) > 2  # different numbers of calls
    one_call = IncrementalGMM(covariance_scale=0.01, data_range=20, batch=True).fit(X, weights)
    for chunks in chunkings:
        model = _fit_in_chunks(chunks, X, weights, batch=True)
        assert model.n_batch_rows_ == len(X) and model.n_samples_seen_ == len(X)
        assert model.confirmed_.sum() == one_call.confirmed_.sum()
        np.testing.assert_array_equal(model.means_, one_call.means_)
        np.testing.assert_array_equal(model.covariances_, one_call.covariances_)
        np.testing.assert_array_equal(model.support_, one_call.support_)
    # the same chunkings learnt sequentially give different cluster counts: the check can fail
    counts = {int(_fit_in_chunks(chunks, X, weights, batch=False).confirmed_.sum()) for chunks in chunkings}
    assert len(counts) > 1
    truth = np.array([obj.position for obj in scene])
    assert match_scores(one_call.means_[one_call.confirmed_], truth)["recall"] >= 0.9


def test_batch_mode_keeps_its_rows_through_bad_input_and_consolidate_starts_afresh():
    truth, dets = _scene(2)
    X = dets.positions
    model = IncrementalGMM(covariance_scale=0.01, data_range=20, batch=True).partial_fit(X[:100])
    before = model.to_dict()
    with pytest.raises(InvalidInputError, match="NaN"):
        model.partial_fit(np.array([[1.0, float("nan")]]))
    assert model.n_batch_rows_ == 100 and model.to_dict() == before
    model.partial_fit(X[100:])
    whole = IncrementalGMM(covariance_scale=0.01, data_range=20, batch=True).fit(X[::-1])
    np.testing.assert_array_equal(model.means_, whole.means_)
    # consolidate: the current model becomes the starting point; later chunks relearn from it
    model.consolidate()
    assert model.n_batch_rows_ == 0
    extra = X[:50] + 0.01
    a = IncrementalGMM.from_dict(model.to_dict()).set_params(batch=True)
    for part in (extra[:10], extra[10:]):
        model.partial_fit(part)
    a.partial_fit(extra[::-1])
    assert model.n_batch_rows_ == 50
    np.testing.assert_allclose(model.means_, a.means_, rtol=0, atol=1e-9)
    assert model.n_components_ == a.n_components_
    # switching batch mode off consolidates too
    model.set_params(batch=False)
    assert model.n_batch_rows_ == 0


@pytest.mark.parametrize("batch", [False, True])
def test_learns_simulated_scenes_with_clutter(batch):
    for seed in range(4):
        truth, dets = _scene(seed)
        assert 0.08 < dets.clutter_fraction < 0.12
        model = IncrementalGMM(covariance_scale=0.01, data_range=20, v_min=50, batch=batch)
        model.fit(dets.positions, dets.confidences)
        found = model.means_[model.confirmed_]
        scores = match_scores(found, truth, radius=0.5)
        assert scores["precision"] >= 0.9 and scores["recall"] >= 0.9, (seed, scores)
        assert ospa(found, truth, cutoff=1.0) <= 0.25


def test_state_round_trips_through_json_and_learning_continues_the_same():
    truth, dets = _scene(3)
    half = len(dets) // 2
    model = IncrementalGMM(covariance_scale=0.01, data_range=20, v_min=50)
    model.partial_fit(dets.positions[:half], times=dets.stamps[:half])
    copy = IncrementalGMM.from_dict(json.loads(json.dumps(model.to_dict())))
    probe = truth + 0.05
    np.testing.assert_allclose(copy.predict_proba(probe), model.predict_proba(probe), atol=1e-12)
    np.testing.assert_array_equal(copy.ages_, model.ages_)
    assert copy.observation_times_ == model.observation_times_
    for m in (model, copy):
        m.partial_fit(dets.positions[half:], times=dets.stamps[half:])
    np.testing.assert_allclose(copy.means_, model.means_, atol=1e-9)
    np.testing.assert_allclose(copy.support_, model.support_, atol=1e-9)


def test_sklearn_style_interface():
    model = IncrementalGMM(sigma_ini=0.2)
    with pytest.raises(NotFittedError, match="no components"):
        model.predict([[0.0, 0.0]])
    a = np.random.default_rng(0).normal([0, 0], 0.1, (50, 2))
    b = np.random.default_rng(1).normal([5, 5], 0.1, (50, 2))
    assert model.fit(np.concatenate([a, b])) is model and model.confirmed_.sum() == 2
    assert model.partial_fit(a[:3]) is model
    np.testing.assert_array_equal(model.predict([[0.1, 0.0], [5.0, 4.9]]),
                                  [np.argmin(np.linalg.norm(model.means_ - [0, 0], axis=1)),
                                   np.argmin(np.linalg.norm(model.means_ - [5, 5], axis=1))])
    np.testing.assert_allclose(model.predict_proba(a).sum(axis=1), 1.0)
    assert model.score(a) > model.score(a + 1.0)
    assert model.weights_.sum() == pytest.approx(1.0)
    model.fit(b)  # fit forgets what came before
    assert model.confirmed_.sum() == 1 and np.allclose(model.means_[model.confirmed_], [[5, 5]], atol=0.1)
    params = model.get_params()
    assert IncrementalGMM(**params).get_params() == params
    with pytest.raises(InvalidInputError, match="unknown parameter"):
        model.set_params(colour="red")


@pytest.mark.parametrize("kwargs,match", [
    ({"X": [[0.0, float("nan")]]}, "NaN"),
    ({"X": [[0.0, 1.0, 2.0]]}, "3 features, the model has 2"),
    ({"X": [0.0, 1.0]}, "2-D"),
    ({"X": [[0.0, 1.0]], "sample_weight": [-1.0]}, "positive"),
    ({"X": [[0.0, 1.0]], "measurement_cov": [[[1.0, 2.0], [0.0, 1.0]]]}, "symmetric"),
    ({"X": [[0.0, 1.0]], "times": [1.0, 2.0]}, "times"),
])
def test_bad_input_is_refused_and_the_model_is_unchanged(kwargs, match):
    model = IncrementalGMM(sigma_ini=0.2).partial_fit([[0.0, 0.0], [0.05, 0.0]])
    before = model.to_dict()
    with pytest.raises(InvalidInputError, match=match):
        model.partial_fit(**kwargs)
    assert model.to_dict() == before
    with pytest.raises(InvalidInputError, match="novelty_constant"):
        IncrementalGMM(novelty_constant=1.5).partial_fit([[0.0]])


def test_clusters_remember_when_they_were_seen():
    model = IncrementalGMM(sigma_ini=0.2, max_times=3)
    model.partial_fit([[0.0, 0.0], [0.01, 0.0], [5.0, 5.0], [0.0, 0.01], [0.02, 0.0]],
                      times=[10.0, 30.0, 12.0, 20.0, 40.0])
    near_origin = int(np.argmin(np.linalg.norm(model.means_, axis=1)))
    assert model.first_seen_[near_origin] == 10.0 and model.last_seen_[near_origin] == 40.0
    assert model.observation_times_[near_origin] == [20.0, 30.0, 40.0]  # sorted, oldest dropped
    assert model.observation_times_[1 - near_origin] == [12.0]
