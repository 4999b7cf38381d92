"""Node 1's logic without ROS: okid_ros/service/identification.py."""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
import pytest

from okid_ros.core.arx import fit_arx
from okid_ros.service.change_restarts import restart_window
from okid_ros.service.identification import ArxIdentificationParams, ArxIdentificationService
from okid_ros.service.params import ARX_NODE, resolve_parameters
from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

Q, W = 8, 300


@pytest.fixture(scope="module")
def record():
    model = paper_model()
    u = lowpass_input(900, 2, 50.0, model.sample_time_s, seed=3)
    y, _ = simulate_innovation(model, u, seed=4)
    return model.sample_time_s, u, y


def make_service(dt: float, **overrides) -> ArxIdentificationService:
    values = {"sample_time_s": dt, "arx.order": Q, "arx.window_length": W, **overrides}
    return ArxIdentificationService(ArxIdentificationParams.from_parameters(resolve_parameters(ARX_NODE, values)))


def test_snapshot_equals_the_batch_fit_on_the_window(record):
    dt, u, y = record
    service = make_service(dt)
    n = 700
    assert service.push_block(10.0 + dt * np.arange(n), u[:n], y[:n]) == n
    snap = service.snapshot()
    assert snap.valid and snap.window_rows == W and snap.window_fill == 1.0
    assert snap.stamp_s == pytest.approx(10.0 + (n - 1) * dt)
    # Node 1 fits an intercept by default (offsets: "remove"), so the batch fit does too.
    batch = fit_arx(u[n - W - Q : n], y[n - W - Q : n], Q, "ridge", "gcv", center=True)
    # Same rows, same prior; the GCV penalty comes from a bounded scalar search (tolerance ~1e-5).
    assert snap.penalty == pytest.approx(batch.penalty, rel=1e-3)
    np.testing.assert_allclose(snap.fit.theta, batch.theta, atol=1e-5 * np.abs(batch.theta).max())
    assert snap.condition_number == pytest.approx(batch.condition_number, rel=1e-6)


def test_bad_samples_are_counted_and_never_enter_the_window(record):
    dt, u, y = record
    clean, dirty = make_service(dt), make_service(dt)
    n = 500
    clean.push_block(dt * np.arange(n), u[:n], y[:n])
    for k in range(n):
        t = k * dt
        assert dirty.push(t, u[k], y[k])
        if k == 100:
            assert not dirty.push(t + 0.2 * dt, u[k] + 1, y[k])  # duplicate stamp
            assert not dirty.push(t - 3 * dt, u[k], y[k])  # out of order
            assert not dirty.push(t + dt, [math.nan, 0.0], y[k])
            assert not dirty.push(t + dt, u[k], y[k][:1])  # wrong size
    d = dirty.diagnostics()
    rejected = ("rejected_duplicate", "rejected_out_of_order", "rejected_nonfinite", "rejected_wrong_size")
    assert [d[name] for name in rejected] == [1, 1, 1, 1]
    assert d["samples_rejected"] == 4 and d["samples_used"] == n
    np.testing.assert_array_equal(dirty.snapshot().fit.theta, clean.snapshot().fit.theta)


def test_a_gap_breaks_the_lag_history(record):
    dt, u, y = record
    service = make_service(dt, **{"arx.window_length": 1000, "arx.min_window_fill": 0.0})
    keep = np.ones(600, dtype=bool)
    keep[250:253] = False  # three samples never arrive: a stamp jump of 4 sample times
    idx = np.flatnonzero(keep)
    service.push_block(idx * dt, u[idx], y[idx])
    snap = service.snapshot()
    assert service.diagnostics()["gaps"] == 1
    # Rows: 600 - 3 samples, minus q lags at the start and q again after the gap.
    assert snap.window_rows == 600 - 3 - 2 * Q
    batch = fit_arx(u[:600], y[:600], Q, "ridge", "gcv", valid=keep, center=True)
    np.testing.assert_allclose(snap.fit.theta, batch.theta, atol=1e-5 * np.abs(batch.theta).max())


def test_invalid_until_filled_then_unexcited_window_keeps_the_last_good_fit(record):
    dt, u, y = record
    service = make_service(dt, **{"arx.max_condition_number": 1e8})
    service.push_block(dt * np.arange(100), u[:100], y[:100])
    first = service.snapshot()
    assert not first.valid and "window fill" in first.reason and first.fit is None
    service.push_block(dt * np.arange(100, 500), u[100:500], y[100:500])
    good = service.snapshot()
    assert good.valid and good.model_id == first.model_id + 1
    # A window of constant samples: rank deficient.
    for k in range(500, 500 + W + Q):
        service.push(k * dt, [1.0, 1.0], [0.5, 0.5])
    bad = service.snapshot()
    assert not bad.valid and "unexcited" in bad.reason
    assert bad.fit is good.fit  # the last good fit travels on
    assert service.diagnostics()["has_good_model"]


def test_adaptation_off_freezes_the_window_and_reset_restarts(record):
    dt, u, y = record
    service = make_service(dt)
    service.push_block(dt * np.arange(400), u[:400], y[:400])
    frozen = service.snapshot().fit.theta
    service.set_adaptation(False)
    service.push_block(dt * np.arange(400, 800), u[400:800], y[400:800])
    np.testing.assert_array_equal(service.snapshot().fit.theta, frozen)
    service.set_adaptation(True)
    service.push_block(dt * np.arange(800, 900), u[800:900], y[800:900])
    assert not np.array_equal(service.snapshot().fit.theta, frozen)
    service.reset()
    assert service.diagnostics()["samples_used"] == 0
    snap = service.snapshot()
    assert snap.model_id == 1 and not snap.valid


def test_due_fires_once_per_publish_period():
    service = make_service(0.01, **{"publish_rate_hz": 2.0})
    fired = [k for k in range(301) if service.due(k * 0.01)]
    assert fired == [50, 100, 150, 200, 250, 300]
    assert not service.due(0.0)  # time went back: the clock restarts
    assert service.due(0.5)


def test_a_structural_change_stamped_in_the_future_is_ignored(record):
    dt, u, y = record
    svc = make_service(dt)
    svc.push_block(np.arange(900) * dt, u, y)
    newest = 899 * dt
    # An hour ahead (a bad clock, a forged message): the window would be emptied and every real
    # change before that stamp ignored as "already restarted".
    assert svc.restart_at(newest + 3600.0) == -1
    d = svc.diagnostics()
    assert d["window_restarts"] == 0 and d["window_restarts_ignored"] == 1
    assert svc.restart_at(newest - 100 * dt) == 101  # a real change still restarts the window
    assert svc.restart_at(newest + 1.0) == 0  # within node 1's lag behind node 2: an empty window for now


def test_a_structural_change_stamped_before_the_samples_held_is_ignored(record):
    # Stamped -1 s (a forged message) or before the oldest sample held, a change counted as a restart
    # that replayed every sample held and set last_restart_stamp_s to -1.
    dt, u, y = record
    svc = make_service(dt)
    assert svc.restart_at(-1.0) == -1  # nothing held yet: still no sample's stamp
    svc.push_block(10.0 + np.arange(900) * dt, u, y)
    assert svc.restart_at(-1.0) == -1
    assert svc.restart_at(10.0 - 1.0) == -1
    d = svc.diagnostics()
    assert d["window_restarts"] == 0 and d["window_restarts_ignored"] == 3, d
    assert math.isnan(d["last_restart_stamp_s"]), d
    assert svc.restart_at(10.0 + 800 * dt) == 100  # a change among the samples held restarts the window


def test_a_structural_change_while_no_sample_is_held_is_ignored(record):
    # Just started, reset or activated: one stamped an hour ahead was taken as a restart (of an empty
    # window) and became the last restart's stamp, so every real change after it was ignored.
    dt, u, y = record
    for reset in (False, True):
        svc = make_service(dt)
        if reset:
            svc.push_block(np.arange(900) * dt, u, y)
            svc.reset()
        assert svc.restart_at(3600.0) == -1
        d = svc.diagnostics()
        assert d["window_restarts"] == 0 and d["window_restarts_ignored"] == 1 and math.isnan(d["last_restart_stamp_s"])
        svc.push_block(10.0 + np.arange(900) * dt, u, y)
        assert svc.restart_at(10.0 + 800 * dt) == 100  # the first real change restarts the window


def test_a_structural_change_the_window_starts_after_already_is_ignored_and_counted(record):
    # A replayed or misbehaving publisher: the same change again and again, or one the window has
    # slid past. Each was a restart replaying the samples held (~9 ms at order 40, window 2000) and a
    # new window generation (the solve running dropped), so a flood kept node 1 from publishing.
    dt, u, y = record
    svc = make_service(dt)
    svc.push_block(np.arange(600) * dt, u[:600], y[:600])
    assert svc.restart_at(400 * dt) == 200
    svc.push_block(np.arange(600, 900) * dt, u[600:], y[600:])  # its W = 300 rows reach back to sample 592
    generation = svc.capture().generation  # the samples held (W + Q + 64) from 528 on
    for stamp in (400, 530, 560, 560, 592):  # the same change; ones the window has slid past, once or twice
        assert svc.restart_at(stamp * dt) == -1, stamp
    d = svc.diagnostics()
    assert d["window_restarts"] == 1 and d["window_restarts_ignored"] == 5, d
    assert d["window_restarts_ignored_why"] == (
        "1 stamped before the samples node 1 holds (the last: structural change at 3.200 s, before the oldest "
        "sample node 1 holds (4.224 s): they are all of the new structure); 4 whose stamp the window starts at or "
        "after already (the same change again, or an older one) (the last: structural change at 4.736 s: the "
        "window's 300 rows are all of samples from it on already)"), d
    assert svc.capture().generation == generation and d["window_fill"] == 1.0  # the window and its solve kept
    assert svc.restart_at(593 * dt) == 307  # a change among the window's rows still restarts it
    assert svc.restart_at(593 * dt) == -1  # ... once
    assert svc.last_ignored_change == "structural change at 4.744 s, at or before the last restart's (4.744 s)"
    assert svc.restart_at(899 * dt + 3600.0) == -1  # refused as a change from the future, said as such
    why = svc.diagnostics()["window_restarts_ignored_why"]
    assert "; 1 stamped far after node 1's newest sample (the last: structural change at 3607.192 s, " in why, why


def test_a_structural_change_after_adaptation_was_off_is_not_judged_by_the_window_rows(record):
    # Frozen from sample 600 to 800, the window holds rows from 400 to 599 and from 800 on: a change at
    # 550 leaves more rows after it (342) than the window holds (300), yet the window reaches before it.
    dt, u, y = record
    svc = make_service(dt)
    svc.push_block(np.arange(600) * dt, u[:600], y[:600])
    svc.set_adaptation(False)
    svc.push_block(np.arange(600, 800) * dt, u[600:800], y[600:800])
    svc.set_adaptation(True)
    svc.push_block(np.arange(800, 900) * dt, u[800:], y[800:])
    assert svc.restart_at(550 * dt) == 350


def flood(svc: ArxIdentificationService, record, *, solve_every: int, lead: int = 100,
          apply_each: bool = False) -> list:
    """Samples 400 to 899, each followed by a structural change stamped ``lead`` samples before it; the snapshots.

    A replayed or misbehaving publisher: 500 distinct changes, increasing, each among the window's rows.
    ``apply_each``: each restart applied at once, as the old code did.
    """
    dt, u, y = record
    svc.push_block(np.arange(400) * dt, u[:400], y[:400])
    snapshots = []
    for k in range(400, 900):
        svc.push(k * dt, u[k], y[k])
        assert svc.restart_at((k - lead) * dt) == lead + 1, k
        if apply_each:
            assert svc.apply_pending_restart() == lead + 1
        if k % solve_every == solve_every - 1:
            snapshots.append(svc.snapshot())
    return snapshots


def test_a_flood_of_increasing_structural_changes_costs_one_replay_a_solve(record, monkeypatch):
    # Each was a restart: the samples from its stamp on replayed under the lock node 1's input thread
    # needs, so 1000 a second cost seconds of CPU a second (bench/change_flood.py).
    import okid_ros.service.identification as identification

    replays = []
    monkeypatch.setattr(identification, "restart_window",
                        lambda window, u, *args: replays.append(u.shape[0]) or restart_window(window, u, *args))
    svc = make_service(record[0])
    snapshots = flood(svc, record, solve_every=100)
    assert len(snapshots) == 5 and len(replays) == 5, replays  # the newest change before each solve, once
    assert replays == [101] * 5  # from the newest change on
    d = svc.diagnostics()
    assert d["window_restarts"] == 5 and d["window_restarts_ignored"] == 495, d
    assert d["window_restarts_ignored_why"] == (
        "495 superseded by a later one before the window's next solve (the last: structural change at 6.384 s, "
        "superseded by the one at 6.392 s before the window's restart was applied)"), d
    assert d["last_restart_stamp_s"] == 799 * record[0] and math.isnan(d["pending_restart_stamp_s"])


def test_the_window_after_a_flood_is_the_one_restarting_at_each_change_in_turn_gives(record):
    """The changes between two solves cost one replay, of the newest, and the models are those of a replay each."""
    dt = record[0]
    coalesced, each = make_service(dt), make_service(dt)
    snapshots = flood(coalesced, record, solve_every=70), flood(each, record, solve_every=70, apply_each=True)
    assert [s.window_rows for s in snapshots[0]] == [s.window_rows for s in snapshots[1]] == [101 - Q] * 7
    for ours, theirs in zip(*snapshots):
        assert ours.valid and theirs.valid
        np.testing.assert_array_equal(ours.fit.theta, theirs.fit.theta)
    assert each.diagnostics()["window_restarts"] == 500 and coalesced.diagnostics()["window_restarts"] == 7
    assert coalesced.restart_at(899 * dt) == 1 and coalesced.restart_at(899 * dt) == -1  # pending: once
    assert coalesced.last_ignored_change == "structural change at 7.192 s, at or before the last restart's (7.192 s)"
    coalesced.reset()
    assert math.isnan(coalesced.diagnostics()["pending_restart_stamp_s"])  # forgotten with the window


@pytest.mark.parametrize("value", [1e151, 1e300])
def test_a_sample_beyond_the_window_bound_is_a_counted_rejection_without_warnings(record, value):
    """As a NaN sample: refused, counted, a gap.

    1e300 printed numpy's overflow warning into node 1's log, and both values counted as used
    and were kept for a restart's replay.
    """
    dt, u, y = record
    n, bad = 500, 100
    with_nan, with_huge = make_service(dt), make_service(dt)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for k in range(n):
            y_nan, y_huge = (y[k], y[k]) if k != bad else ([math.nan, 0.0], [value, 0.0])
            assert with_nan.push(k * dt, u[k], y_nan) == with_huge.push(k * dt, u[k], y_huge) == (k != bad)
        d = with_huge.diagnostics()
        snapshot = with_huge.snapshot()
    assert d["rejected_magnitude"] == 1 and d["samples_rejected"] == 1 and d["samples_used"] == n - 1
    assert d["gaps"] == with_nan.diagnostics()["gaps"] == 1
    np.testing.assert_array_equal(snapshot.fit.theta, with_nan.snapshot().fit.theta)


def test_a_capture_is_current_only_for_its_own_window(record):
    """Node 1 publishes a solve only when its capture is current: not after a reset or restart, nor another's.

    A lifecycle cleanup and configure builds a new service; node 1 counted generations from 0 in each
    build, so a solve of the old window still running passed for the new one's.
    """
    dt, u, y = record
    old = make_service(dt)
    old.push_block(np.arange(600) * dt, u[:600], y[:600])
    capture = old.capture()
    assert old.is_current(capture)
    new = make_service(dt)  # the service of a reconfigured node, at the same point of its own history
    new.push_block(np.arange(600) * dt, u[:600], y[:600])
    assert not new.is_current(capture) and new.is_current(new.capture())
    old.push_block(600 * dt + np.arange(10) * dt, u[600:610], y[600:610])
    assert old.is_current(capture)  # more samples: the solve is of an earlier instant of the same window
    assert old.restart_at(500 * dt) > 0 and not old.is_current(capture)
    capture = old.capture()
    old.reset()
    assert not old.is_current(capture)


@pytest.mark.parametrize("regularization", ["ridge", "tc"])
@pytest.mark.parametrize("blow", [50.0, 1e6])
def test_a_hammers_blow_in_the_windows_newest_sample_alone_is_refused_as_unexcited_without_warnings(
        record, regularization, blow):
    """An input exactly 0 but for a blow in the newest sample: only its feedthrough column holds it.

    Its lagged columns are zero, so its mean square, which scales its prior, was floored at the smallest
    normal float: the whitening multiplied the blow's square by 4.5e307, numpy printed `overflow
    encountered in multiply` into node 1's log and the window was refused as `solve failed: array must not
    contain infs or NaNs`.
    """
    dt, u, y = record
    hammer = u.copy()
    hammer[:, 0] = 0.0
    hammer[-1, 0] = blow
    service = make_service(dt, **{"arx.regularization": regularization})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        service.push_block(dt * np.arange(u.shape[0]), hammer, y)
        snapshot = service.snapshot()
        batch = fit_arx(hammer[-W - Q:], y[-W - Q:], Q, regularization, center=True)
    assert not snapshot.valid
    assert snapshot.reason.startswith("unexcited window: condition number inf > arx.max_condition_number")
    assert np.all(np.isfinite(batch.theta)) and batch.condition_number == math.inf


def test_a_blow_after_one_that_forgetting_decayed_below_the_float_range_is_solved_without_warnings(record):
    """Forgetting 0.5: a blow 1040 samples old weighs 2^-1040 (1e-313) of a new one in the newest sample.

    The input's lagged mean square, subnormal, was floored at 2.2e-308: the whitening overflowed as for a
    blow in a window of zeros (numpy's warning, `solve failed`); a blow 1000 samples old was solved.
    """
    dt, u, y = record
    for age in (1000, 1040):
        hammer = np.tile(u, (2, 1))
        hammer[:, 0] = 0.0
        hammer[[-1 - age, -1], 0] = 50.0
        # Past the start's check (node 2 realizes no window of 2 rows' memory): node 1's solve alone.
        params = dataclasses.replace(make_service(dt).params, window_length=0, forgetting_factor=0.5)
        service = ArxIdentificationService(params)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            service.push_block(dt * np.arange(hammer.shape[0]), hammer, np.tile(y, (2, 1)))
            snapshot = service.snapshot()
        assert snapshot.valid and np.all(np.isfinite(snapshot.fit.theta)), snapshot.reason
