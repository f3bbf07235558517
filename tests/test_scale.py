"""The default path at the size of real logs (issue 31): no crash on a demonstration of a few
samples, and work that grows linearly in N — checked by counting calls and rows, not by the clock."""

import sys
from collections import Counter

import numpy as np
import pytest

from ccl_cli import diagnostics
from ccl_cli import simulate as sim
from ccl_cli.dataset import Demonstrations
from ccl_cli.learn import model_selection as ms
from ccl_cli.learn.constraint import AutoConstraint, PerSegment, geometry, segments
from ccl_cli.learn.constraint import evidence as ev
from ccl_cli.learn.constraint.manifold import ManifoldConstraint
from ccl_cli.learn.constraint.timeblocks import nearest_window, window_index
from ccl_cli.learn.constraint.windows import PerWindow


def with_a_scrap(n_demos: int = 12, seed: int = 0) -> Demonstrations:
    """Varying-constraint toy demonstrations and, last, a demonstration of 2 samples."""
    d = sim.toy2d(task=True, vary_constraint=True, n_demos=n_demos, n_steps=100, seed=seed)
    return Demonstrations.concatenate([d, d.subset(np.arange(2))])


def test_a_demonstration_of_two_samples_has_no_training_rows_in_a_fold_and_still_gets_held_out_rows():
    """The 10⁶ crash ("demonstration 3760 was not seen when fitting this per-window model", a
    demonstration of 2 samples): inside-window folds hold out both samples (or drop them by the
    guard gap), so the fold's model has never seen that demonstration. Its held-out rows come
    from the same kind of model fitted on the fold's training part as one stretch."""
    d = with_a_scrap()
    scrap = d.demo == d.demo.max()
    assert scrap.sum() == 2
    seg, _ = window_index(d.demo, d.t, None, len(d.U))
    folds = ms.inner_folds(seg, 5, 2, "demonstration")
    unseen = [j for j, (train, test) in enumerate(folds.pairs)
              if np.isin(np.flatnonzero(scrap), test).any() and not scrap[train].any()]
    assert unseen  # the cause: a fold that holds the scrap out and never trains on it
    data = ev.Sample.of(d.X, d.U, d.demo, d.t, None)
    cand = ev.Candidate("per_demo", "", lambda k: PerWindow(window=None, n_constraints=k, heldout=False),
                        1, seg)
    rows = ev.held_out_rows(cand, folds, 1, data)
    norms = np.linalg.norm(rows[scrap, 0], axis=1)
    np.testing.assert_allclose(norms, 1.0)


def test_auto_fits_and_applies_with_a_demonstration_of_two_samples():
    d = with_a_scrap()
    model = AutoConstraint(candidates=["nhat", "per_demo", "per_window", "per_segment"]).fit(
        d.X, d.U, groups=d.demo, t=d.t)
    table = {r["class"]: r for r in model.selection_["candidates"]}
    tried = [table[c] for c in ("per_demo", "per_window", "per_segment")
             if not table[c]["reason"].startswith("not")]
    assert tried and all(r["k"] is not None and "failed" not in r["reason"] for r in tried)
    assert model.n_constraints_ == 1
    # held-out data holding an unseen scrap: the model applies by its stated rule, no error
    test = with_a_scrap(n_demos=4, seed=1)
    applied = model.applies_to(test.X, test.U, groups=test.demo + 1000, t=test.t, new_recording=True)
    P = applied.model.projection(test.X, groups=test.demo + 1000, t=test.t)
    assert P.shape == (len(test.U), 2, 2) and np.isfinite(P).all()


# -- linear work: calls and rows counted ---------------------------------------------------------
def python_calls(fn, *args, **kw) -> int:
    """The number of Python and C function calls ``fn(*args, **kw)`` makes."""
    count = Counter()

    def hook(frame, event, arg):
        if event in ("call", "c_call"):
            count[event] += 1

    sys.setprofile(hook)
    try:
        fn(*args, **kw)
    finally:
        sys.setprofile(None)
    return sum(count.values())


def many_demonstrations(n_demos: int, length: int = 50, seed: int = 0) -> Demonstrations:
    """``n_demos`` random walks of ``length`` samples in 3-D, 50 Hz, some stamps jittered."""
    rng = np.random.default_rng(seed)
    X = np.cumsum(rng.standard_normal((n_demos * length, 3)) * 0.01, axis=0)
    t = np.tile(np.arange(length) / 50.0, n_demos) + rng.uniform(0, 1e-3, n_demos * length)
    return Demonstrations(X, np.gradient(X, axis=0) * 50, np.repeat(np.arange(n_demos), length), t)


def test_the_data_checks_make_as_many_calls_for_ten_times_the_demonstrations():
    """stamps (a median per demonstration), the demonstration counts and low_rank_actions: no
    Python loop over the samples of each demonstration (was a mask per demonstration: N × D)."""
    small, large = many_demonstrations(200), many_demonstrations(2000)
    for check in (diagnostics.stamps, diagnostics.demonstrations):
        assert python_calls(check, large) <= python_calls(check, small) + 20
    a, b = (python_calls(diagnostics.low_rank_actions, d, d.U, 1, np.full(3, 1e-6)) for d in (small, large))
    assert b <= 10 * a + 100  # one small eigvalsh per demonstration, nothing per sample


def test_window_lookup_makes_as_many_calls_for_ten_times_the_demonstrations():
    small, large = many_demonstrations(200), many_demonstrations(2000)

    def lookup(d):
        seg, table = window_index(d.demo, d.t, 0.5, len(d.U))
        return nearest_window(table, 0.5, len(d.U), d.demo, d.t)

    assert python_calls(lookup, large) <= python_calls(lookup, small) + 20
    seg, table = window_index(large.demo, large.t, 0.5, len(large.U))
    np.testing.assert_array_equal(nearest_window(table, 0.5, len(large.U), large.demo, large.t), seg)


def test_per_segment_cuts_every_demonstration_in_one_programme(monkeypatch):
    """One batched eigvalsh per block position (the longest demonstration's blocks), whatever
    the number of demonstrations; the matrices it sees grow linearly with them."""
    seen = []
    real = segments.quietest_motion

    def counted(C):
        seen.append(C.shape[:-2])
        return real(C)

    monkeypatch.setattr(segments, "quietest_motion", counted)
    counts = {}
    for n_demos in (20, 200):
        seen.clear()
        d = many_demonstrations(n_demos, length=100)
        PerSegment(n_constraints=1, heldout=False).fit(d.X, d.U, groups=d.demo, t=d.t)
        counts[n_demos] = (len(seen), sum(int(np.prod(s)) for s in seen))
    assert counts[200][0] == counts[20][0]  # calls: blocks of the longest demonstration, + the price
    assert counts[200][1] <= 10 * counts[20][1]  # matrices: linear in the demonstrations


def lengths(monkeypatch, owner, name: str, method: bool = False) -> list[int]:
    """The length of the first array of every call of ``owner.name`` from now on (after ``self``
    for a ``method``): a list that grows as they run."""
    seen: list[int] = []
    real = getattr(owner, name)

    def counted(*args, **kw):
        seen.append(len(args[1] if method else args[0]))
        return real(*args, **kw)

    monkeypatch.setattr(owner, name, counted)
    return seen


def test_the_states_geometry_reads_a_bounded_sample(monkeypatch):
    """decide fits its manifolds on at most ~EVIDENCE_ROWS rows however many there are: the rows
    the fits see are the same at 2·10⁵ and 2·10⁶ samples of the same structure."""
    rows = lengths(monkeypatch, ManifoldConstraint, "fit", method=True)
    seen = {}
    for n_demos in (2_000, 20_000):
        rng = np.random.default_rng(0)
        walk = np.cumsum(rng.standard_normal((n_demos * 100, 2)) * 0.01, axis=0)
        X = np.c_[walk, 0.3 * walk[:, 0] + 1e-4 * rng.standard_normal(len(walk))]  # on a plane
        groups = np.repeat(np.arange(n_demos), 100)
        rows.clear()
        found = geometry.decide(X, groups)
        seen[n_demos] = (found.k, len(rows), sum(rows))
    assert seen[2_000][0] == seen[20_000][0] == 1
    for n in (2_000, 20_000):  # fits and the rows they see: bounded, not growing with N
        assert seen[n][1] <= 1_500 and seen[n][2] <= 80 * geometry.EVIDENCE_ROWS
    assert abs(seen[20_000][2] - seen[2_000][2]) <= 0.05 * seen[2_000][2]


def test_how_sure_reads_the_same_bounded_sample_at_ten_times_the_samples(monkeypatch):
    """auto's cone (the states' manifold fitted again without each fold, its rows against the
    final ones) is read on the bounded sample of whole demonstrations above CHOICE_ROWS: the
    rows it compares do not grow with N, and the final model is still fitted on all of them."""
    from ccl_cli.learn.constraint import auto as auto_module
    from ccl_cli.learn.constraint import sure

    compared = lengths(monkeypatch, sure, "angles")
    seen = {}
    for n_demos in (30, 300):
        rng = np.random.default_rng(1)
        steps = rng.standard_normal((n_demos * 500, 2)) * 0.01
        walk = np.cumsum(steps, axis=0)
        X = np.c_[walk, 0.5 * walk[:, 1]]  # on the plane z = y / 2
        groups = np.repeat(np.arange(n_demos), 500)
        t = np.tile(np.arange(500) / 50.0, n_demos)
        U = np.gradient(X, axis=0) * 50
        compared.clear()
        model = AutoConstraint().fit(X, U, groups=groups, t=t, derivative={"window": 5, "order": 2})
        cone = model.selection_["sure"]["cone"]
        seen[n_demos] = (model.n_constraints_, compared[:], cone["samples"])
        normal = np.array([0.0, 0.5, -1.0]) / np.sqrt(1.25)
        row = model.constraint(X[:1], groups=groups[:1], t=t[:1])[0, 0]
        assert abs(abs(float(row @ normal)) - 1) < 1e-6
    assert seen[30][0] == seen[300][0] == 1
    assert seen[30][1] == [15_000] and seen[30][2] == 15_000  # up to CHOICE_ROWS: every sample
    assert seen[300][1] == [seen[300][2]] and seen[300][2] <= auto_module.CHOICE_ROWS  # 150,000: a sample


def test_ncl_makes_a_bounded_number_of_passes_over_all_the_rows():
    """Above the subsample, ncl's passes over all N rows are at most FULL_PASSES +
    ORIGINAL_FULL_PASSES whatever N; the stages before run on SUBSAMPLE_ROWS rows."""
    from ccl_cli.learn import nullspace as ns

    seen = {}
    for n_demos in (150, 600):  # about 1.4·10⁴ and 5.5·10⁴ samples
        d = sim.toy2d(task=True, n_demos=n_demos, n_steps=1000, seed=0)
        model = ns.NullSpaceComponent(tune=False).fit(d.X, d.U, groups=d.demo)
        on_all = [s for s in model.stages_ if s["rows"] == len(d.U)]
        seen[n_demos] = (sum(s["full_passes"] + s["cost_passes"] for s in on_all),
                         {s["rows"] for s in model.stages_ if s["rows"] != len(d.U)})
    for n_demos, (passes, others) in seen.items():
        assert 1 <= passes <= ns.FULL_PASSES + ns.ORIGINAL_FULL_PASSES, (n_demos, passes)
        assert others == {ns.SUBSAMPLE_ROWS}


def test_the_truth_comparison_reads_its_angles_at_a_bounded_sample(monkeypatch):
    """Against the ground truth, the angles are read at TRUTH_ROWS samples evenly spaced when
    there are more: the same median and k agreement as over every sample, at a bounded cost."""
    from ccl_cli.app import truth
    from ccl_cli.learn.constraint import StateIndependentConstraint

    d = sim.toy2d(task=True, vary_constraint=True, n_demos=3000, n_steps=100, seed=4)
    assert d.n_samples > 5 * truth.TRUTH_ROWS
    model = StateIndependentConstraint(n_constraints=1).fit(d.X, d.U)
    real = truth.per_sample
    read = lengths(monkeypatch, truth, "per_sample")
    found = truth.compare(model, d, d.U, "train")
    assert read == [truth.TRUTH_ROWS] and found["read_at"] == truth.TRUTH_ROWS
    assert found["samples"] == d.n_samples
    every, k_l, k_t = real(model.constraint(d.X), truth.true_rows(d))
    assert found["median_deg"] == pytest.approx(float(np.median(every)), rel=0.02)
    assert found["p90_deg"] == pytest.approx(float(np.percentile(every, 90)), rel=0.02)
    assert found["k_agrees"] == float(np.mean(k_l == k_t)) == 1.0


def test_a_demonstration_of_one_sample_takes_the_pooled_model_per_demonstration():
    """The 10⁶ crash of the varying toy ("need at least 2 samples, got 1 sample"): the winner of
    the states' geometry is a model per demonstration with a task part, and one demonstration
    held a single sample. It takes the estimator fitted on all the samples; every other
    demonstration keeps its own model, the same as without the scrap."""
    from ccl_cli.learn.constraint import LinearConstraint, PerDemonstration

    d = sim.toy2d(task=True, vary_constraint=True, n_demos=12, n_steps=100, seed=0)
    one = Demonstrations.concatenate([d, d.subset(np.arange(1))])
    assert np.bincount(one.demo)[-1] == 1
    make = lambda: PerDemonstration(LinearConstraint(regressors="identity", task=True,  # noqa: E731
                                                     n_constraints=1))
    model = make().fit(one.X, one.U, groups=one.demo)
    alone = make().fit(d.X, d.U, groups=d.demo)
    scrap = int(one.demo.max())
    assert model.selection_["pooled"] == [scrap] and "pooled" not in alone.selection_
    pooled = LinearConstraint(regressors="identity", task=True, n_constraints=1).fit(one.X, one.U)
    np.testing.assert_allclose(model.models_[scrap].constraint(one.X[-1:]), pooled.constraint(one.X[-1:]))
    for k in alone.models_:
        np.testing.assert_array_equal(model.constraint(d.X[d.demo == k], groups=d.demo[d.demo == k]),
                                      alone.constraint(d.X[d.demo == k], groups=d.demo[d.demo == k]))
    P = model.projection(one.X, groups=one.demo)
    assert P.shape == (one.n_samples, 2, 2) and np.isfinite(P).all()


def test_a_model_per_demonstration_measures_its_held_out_error_on_a_bounded_sample(monkeypatch):
    """The held-out NPOE of a model per demonstration (5 folds of blocks inside each) is measured
    on the bounded sample of whole demonstrations above TUNE_MAX_ROWS samples: the fits it makes
    do not grow with the number of demonstrations (they were 5 per demonstration: 50,000 small
    fits of the varying toy at 10⁶)."""
    from ccl_cli.learn.constraint import LinearConstraint, PerDemonstration
    from ccl_cli.learn.defaults import TUNE_MAX_ROWS

    fits = lengths(monkeypatch, LinearConstraint, "fit", method=True)
    seen = {}
    for n_demos in (200, 2000):
        d = sim.toy2d(task=True, vary_constraint=True, n_demos=n_demos, n_steps=100, seed=0)
        fits.clear()
        model = PerDemonstration(LinearConstraint(regressors="identity", task=True, n_constraints=1)).fit(
            d.X, d.U, groups=d.demo, derivative={"window": 5, "order": 2})
        seen[n_demos] = (d.n_samples, len(fits) - n_demos, sum(fits) - d.n_samples, model.heldout_)
    small, large = seen[200], seen[2000]
    assert small[0] <= TUNE_MAX_ROWS < large[0]
    assert "subset" not in small[3] and "whole demonstrations" in large[3]["subset"]
    assert large[1] <= 1.5 * small[1] and large[2] <= 1.5 * TUNE_MAX_ROWS * 5
    assert 0 < large[3]["mean"] < 0.1 and 0 < small[3]["mean"] < 0.1  # the constraints hold held out


def test_the_noise_levels_of_each_part_are_estimated_once_in_a_run(tmp_path, monkeypatch):
    """The data checks (the rank of the actions, a varying constraint, what π can identify) read
    the training part's noise levels: one estimate per part (was one per check: 3 × 0.2 s of CPU
    at 10⁶ samples), with the values of a fresh estimate."""
    from ccl_cli import config as C
    from ccl_cli.app.stages import Pipeline

    path = tmp_path / "c.yaml"
    path.write_text("data: {files: [data.h5]}\nstages: [learn-v, learn-a, learn-pi]\n")
    cfg = C.load(path)
    data = sim.tracker_plane(n_recordings=4, duration=20.0, seed=0)
    seen: Counter = Counter()
    real = diagnostics._noise_levels
    monkeypatch.setattr(diagnostics, "_noise_levels", lambda d: seen.update([id(d)]) or real(d))
    p = Pipeline(cfg.spec, data)
    p.run(cfg.stages())
    assert sorted(seen.values()) == [1, 1]  # the data (its checks) and the training part
    assert set(seen) == {id(data), id(p.split.train)}
    again = real(p.split.train)
    for key, value in diagnostics.noise_levels(p.split.train).items():
        np.testing.assert_array_equal(value, again[key])


def test_the_repairs_are_read_once_per_data_and_each_caller_gets_its_own_copy(monkeypatch):
    from ccl_cli.dataset import Repair
    from ccl_cli.io import summary

    dropped = Repair.ACTIONS.index("dropped")  # the third of six samples seen: a spike dropped
    rep = Repair(np.array([0, 0, dropped, 0, 0, 0], np.uint8), np.array([0, 0, 1, 0, 0, 0], np.uint8),
                 ("", "spike"), np.array([0, 1, -1, 2, 3, 4]))
    data = Demonstrations(np.zeros((5, 2)), np.zeros((5, 2)), t=np.arange(5) * 0.1, repair=rep)
    calls = []
    real = summary._repairs
    monkeypatch.setattr(summary, "_repairs", lambda d: calls.append(1) or real(d))
    first, second = summary.repairs(data), summary.repairs(data)
    assert len(calls) == 1 and first == second == real(data) and first
    first[0]["samples"] = -1
    assert summary.repairs(data)[0]["samples"] != -1  # a copy each
    assert second[0]["times"] == [[pytest.approx(0.15)] * 2]  # between 0.1 and 0.2 s
    data.t = data.t * 2  # a field set anew: computed again
    assert summary.repairs(data)[0]["times"] == [[pytest.approx(0.3)] * 2] and len(calls) == 2


def test_demo_ids_in_order_of_first_appearance_without_a_sort_of_contiguous_groups():
    from ccl_cli.dataset import first_appearance

    ids = np.repeat([7, 3, 9, 1], [3, 1, 4, 2])
    np.testing.assert_array_equal(first_appearance(ids), [7, 3, 9, 1])
    np.testing.assert_array_equal(first_appearance(np.array([5, 5, 2, 5, 2, 8])), [5, 2, 8])  # not contiguous
    assert first_appearance(np.zeros(0, np.int64)).shape == (0,)
    d = Demonstrations(np.zeros((10, 1)), np.zeros((10, 1)), ids)
    assert d.demo_ids is d.demo_ids  # computed once


def test_a_metrics_groups_are_indexed_without_a_sort_when_in_order(monkeypatch):
    from ccl_cli import metrics

    rng = np.random.default_rng(0)
    ordered = np.sort(rng.integers(0, 50, 1000))
    shuffled = rng.permutation(ordered)
    for groups in (ordered, shuffled, ordered[:1]):
        _, inverse, counts = np.unique(groups, return_inverse=True, return_counts=True)
        got = metrics.group_index(groups)
        np.testing.assert_array_equal(got[0], inverse)
        np.testing.assert_array_equal(got[1], counts)
    sorts = []
    real = np.unique
    monkeypatch.setattr(np, "unique", lambda *a, **k: sorts.append(1) or real(*a, **k))
    diff = rng.normal(size=(1000, 2))
    m = metrics._metric("NPE", diff, 2.0, "u", ordered)  # the pieces of groups_of: in order
    assert not sorts and m.n_groups == len(real(ordered))
    per = [np.mean(np.sum(diff[ordered == g] ** 2, 1)) / 2.0 for g in real(ordered)]
    assert m.se == pytest.approx(np.std(per, ddof=1) / np.sqrt(len(per)))


def test_a_constant_true_constraint_is_scored_as_one_matrix():
    """NCPE and NPPE of a constant ground truth use one (q, q) projection, not N copies of it
    (72 MB at 10⁶ samples of q = 3, twice per part): the same matrix, the same figures."""
    from ccl_cli import metrics

    d = sim.tracker_plane(n_recordings=2, duration=5.0, seed=0)
    assert d.truth["A"].ndim == 2  # constant
    one = d.true_projection(per_sample=False)
    assert one.shape == (3, 3)
    np.testing.assert_allclose(d.true_projection(), np.broadcast_to(one, (d.n_samples, 3, 3)), atol=1e-15)
    est = d.truth["pi"] + 0.1
    a, b = (metrics.ncpe(N, d.truth["pi"], est).value for N in (one, d.true_projection()))
    assert a == pytest.approx(b, rel=1e-12)
    varying = sim.toy2d(vary_constraint=True, n_demos=3, n_steps=50, seed=0)
    assert varying.true_projection(per_sample=False).shape == (varying.n_samples, 2, 2)


def test_a_constant_learnt_constraint_is_scored_as_one_matrix_and_a_varying_one_per_sample():
    """learn-a's and learn-pi's figures (NPOE, NPPE, NCPE_obs) take one (q, q) Ñ from a model
    whose Ã is constant and holds everywhere — N × q² floats fewer — with the same figures."""
    from ccl_cli.app import scoring
    from ccl_cli.learn.constraint import AutoConstraint, PerWindow, StateIndependentConstraint

    d = sim.tracker_plane(n_recordings=2, duration=10.0, seed=0)
    nhat = StateIndependentConstraint().fit(d.X, d.U, groups=d.demo, t=d.t)
    auto = AutoConstraint().fit(d.X, d.U, groups=d.demo, t=d.t, derivative=d.derivative)
    for model in (nhat, auto):
        applied = scoring.applied_on(model, d, d.U)
        one, every = scoring.projection_on(applied, d, per_sample=False), scoring.projection_on(applied, d)
        assert one.shape == (3, 3) and every.shape == (d.n_samples, 3, 3)
        np.testing.assert_allclose(every, np.broadcast_to(one, every.shape), atol=1e-15)
    figures = scoring.constraint_metrics(scoring.applied_on(nhat, d, d.U), d, d.U)
    every = nhat.projection(d.X)
    by_hand = np.mean(np.sum((d.U - np.einsum("nij,nj->ni", every, d.U)) ** 2, 1)) / d.U.var(0, ddof=1).sum()
    assert figures["NPOE"]["value"] == pytest.approx(by_hand, rel=1e-12)
    varying = sim.toy2d(vary_constraint=True, n_demos=4, n_steps=60, seed=0)
    per_window = PerWindow(window=None).fit(varying.X, varying.U, groups=varying.demo, t=varying.t)
    applied = scoring.applied_on(per_window, varying, varying.U)
    assert scoring.projection_on(applied, varying, per_sample=False).shape == (varying.n_samples, 2, 2)


def test_a_run_keeps_the_ground_truth_in_its_parts_only_and_reads_the_repairs_once(tmp_path, monkeypatch):
    """After the split the recording's own ground truth is dropped (the parts hold copies: 80 MB
    of the 10⁶-sample tracker's); its arrays and what was computed of them stay shared."""
    from ccl_cli import config as C
    from ccl_cli.app import run
    from ccl_cli.io import summary

    path = tmp_path / "c.yaml"
    path.write_text("data: {files: [data.h5]}\nstages: [learn-a]\noutput: {plots: false}\n")
    data = sim.tracker_plane(n_recordings=4, duration=10.0, seed=0)
    monkeypatch.setattr(run, "read_data", lambda cfg, files: (data, None))
    calls = []
    real = summary._repairs
    monkeypatch.setattr(summary, "_repairs", lambda d: calls.append(1) or real(d))
    result = run.execute("run", C.load(path), None)
    assert result.data.truth == {} and result.pipeline.data is result.data
    assert result.data.X is data.X and result.data.demo is data.demo and data.truth  # the caller's intact
    assert {"pi", "A"} <= set(result.pipeline.split.train.truth) and result.pipeline.split.test.truth
    assert "NPPE" in result.metrics["learn-a"]["test"]  # scored against the parts' truth
    assert len(calls) == 1  # the data checks' read, shared with run.json's


def test_a_parts_pieces_are_found_once_for_all_its_figures(monkeypatch):
    from ccl_cli.app import scoring

    d = sim.tracker_plane(n_recordings=2, duration=10.0, seed=0)
    calls = []
    real = scoring._pieces
    monkeypatch.setattr(scoring, "_pieces", lambda data: calls.append(1) or real(data))
    first = scoring.groups_of(d)
    for w in (d.U, 0.5 * d.U):
        scoring.nullspace_metrics(w, d)
    assert len(calls) == 1 and scoring.groups_of(d) is first
    np.testing.assert_array_equal(first, real(d))


def test_total_variance_is_the_sum_of_the_sample_variances():
    from ccl_cli.learn.linalg import total_variance

    Y = np.random.default_rng(1).normal(size=(1000, 4)) * [1, 10, 1e-3, 1e6] + 1e3
    for ddof in (0, 1):
        assert total_variance(Y, ddof) == pytest.approx(np.var(Y, 0, ddof=ddof).sum(), rel=1e-13)
    assert np.isnan(total_variance(Y[:1])) and total_variance(np.arange(5.0)) == 2.5


class Compared(np.ndarray):
    """Ids that count the elements their == and != compare."""

    elements = 0

    def __eq__(self, other):
        Compared.elements += self.size
        return np.asarray(self) == other

    def __ne__(self, other):
        Compared.elements += self.size
        return np.asarray(self) != other


def test_the_per_demonstration_figures_compare_the_ids_a_bounded_number_of_times():
    """describe_constraint (the angle of each demonstration's model) and phases (the stretches of
    each demonstration) read every demonstration's rows from one sort: a mask per demonstration
    compared N ids D times (8·10⁹ at the varying toy's 10⁶ samples in 10⁴ demonstrations)."""
    from ccl_cli.app.views import describe_constraint
    from ccl_cli.learn.constraint import PerDemonstration, StateIndependentConstraint

    d = sim.toy2d(vary_constraint=True, n_demos=200, n_steps=20, seed=0)
    model = PerDemonstration(StateIndependentConstraint(n_constraints=1)).fit(d.X, d.U, groups=d.demo)
    plain = describe_constraint(model, d)
    d.demo = d.demo.view(Compared)
    Compared.elements = 0
    counted = describe_constraint(model, d)
    assert Compared.elements <= 3 * d.n_samples  # was 200 × N
    assert counted == plain and len(counted["per_demo_angle_deg"]) == 200


def test_each_figures_data_are_the_rows_it_draws_at_any_size():
    """The figures over time get the samples they draw (of their first demonstrations, through at
    most LINE_POINTS), the 3-D trajectory about TRAJECTORY_POINTS states, the phases figure its
    first demonstrations, none the file's ground truth: at 10⁶ samples
    their data took 56–77 MB each, over the drawer's message limit, and ccl drew them itself
    after its stages (importing matplotlib a second time); now the drawer draws every one."""
    from ccl_cli.app import views
    from ccl_cli.app.stages import Pipeline
    from ccl_cli.config import from_mapping
    from ccl_cli.render.drawing import MAX_MESSAGE, data_bytes

    d = sim.tracker_plane(duration=300.0, n_recordings=4, seed=1)  # 60,000 samples, 3-D
    cfg = from_mapping({"data": {"files": []}, "stages": ["learn-v", "learn-a", "learn-pi"]})
    pipeline = Pipeline(cfg.spec, d, None)
    pipeline.run(cfg.stages())
    shown = {v.name: v for v in pipeline.views()}
    names = {"learn-v-time.png", "learn-a-time.png", "learn-a-trajectory.png", "learn-pi-time.png"}
    assert names <= set(shown)
    test = pipeline.split.test
    for name in ("learn-v-time.png", "learn-a-time.png", "learn-pi-time.png"):
        args = shown[name].args
        assert args["ids"] == test.demo_ids[: views.TIME_DEMOS].tolist()
        for k, panel in zip(args["ids"], args["panels"], strict=True):  # the samples as drawn
            rows = np.flatnonzero(test.demo == k)
            assert len(rows) > views.LINE_POINTS
            for _, drawn in panel.values():
                assert [len(x) for x, _ in drawn] <= [views.LINE_POINTS + 2] * test.n_action
                x, t0, t1 = drawn[0][0], test.t[rows[0]], test.t[rows[-1]]  # the whole demonstration
                assert t0 <= np.nanmin(x) and np.nanmax(x) <= t1
                assert np.nanmax(x) - np.nanmin(x) > 0.99 * (t1 - t0)
    trajectory = shown["learn-a-trajectory.png"].args
    assert trajectory["d"].n_samples <= views.TRAJECTORY_POINTS + views.TRAJECTORY_ARROWS + test.n_demos
    at = np.unique(np.linspace(0, test.n_samples - 1, views.TRAJECTORY_ARROWS).astype(int))
    assert np.array_equal(trajectory["d"].X[trajectory["at"]], test.X[at])  # the arrows' states
    assert trajectory["d"].n_demos == test.n_demos
    assert all(data_bytes(v.args) <= MAX_MESSAGE / 4 for v in shown.values())
