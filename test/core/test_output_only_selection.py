"""Output-only mode selection: harmonics are not modes, noise poles are not modes, low modes are found.

The seeds are the ones on which the selection of the previous session failed
(docs/benchmarks-output-only.md): a harmonic listed (harmonic, seed 14), a mode lost next to the
harmonic (seed 11), noise poles listed at 18-34 Hz and a split pole at 1.66 Hz (low-modes, seeds
3, 4, 8).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from okid_bench.output_only_cases import output_only_case
from okid_ros.core.output_only import identify_output_only
from okid_ros.core.output_only_harmonics import find_harmonics, remove_harmonics


def _check_modes(case, model) -> None:
    """Every true mode within 0.5 %, damping within 30 %, MAC >= 0.95; nothing else listed."""
    truth = case.truth()
    true_f = np.array([t["frequency_hz"] for t in truth])
    for mode in model.modes:
        assert np.min(np.abs(true_f - mode.frequency_hz) / true_f) < 0.02, f"spurious mode at {mode.frequency_hz} Hz"
    found_f = np.array([m.frequency_hz for m in model.modes])
    for t in truth:
        j = int(np.argmin(np.abs(found_f - t["frequency_hz"])))
        mode = model.modes[j]
        assert abs(mode.frequency_hz / t["frequency_hz"] - 1) < 0.005, f"mode {t['frequency_hz']:.3f} Hz missed"
        assert abs(mode.damping_ratio / t["damping_ratio"] - 1) < 0.3
        shape = mode.shape
        mac = abs(np.vdot(t["shape"], shape)) ** 2 / (np.vdot(shape, shape).real * np.vdot(t["shape"], t["shape"]).real)
        assert mac >= 0.95


@pytest.mark.parametrize("seed", [11, 14])
def test_harmonic_is_removed_not_listed_and_its_neighbour_found(seed: int) -> None:
    case = output_only_case("harmonic")
    model = identify_output_only(case.simulate(seed), case.sample_time_s)
    _check_modes(case, model)
    assert any("harmonic" in w and "6.3" in w for w in model.warnings)


@pytest.mark.parametrize("seed", [3, 4, 8])
def test_low_modes_found_without_noise_poles(seed: int) -> None:
    case = output_only_case("low-modes")
    _check_modes(case, identify_output_only(case.simulate(seed), case.sample_time_s))


def _lightly_damped_response(n: int, seed: int, frequency_hz: float = 10.0, zeta: float = 0.002,
                             sample_time_s: float = 0.01) -> np.ndarray:
    """(n, 2) a randomly excited single mode seen by two sensors, 5 % sensor noise."""
    rng = np.random.default_rng(seed)
    w = 2 * np.pi * frequency_hz * sample_time_s
    r = np.exp(-zeta * w)
    response = signal.lfilter([1.0], [1.0, -2 * r * np.cos(w), r * r], rng.standard_normal(n + 5000))[5000:]
    y = np.column_stack([response, -0.6 * response])
    return y + 0.05 * y.std(axis=0) * rng.standard_normal(y.shape)


def test_a_lightly_damped_mode_is_no_harmonic() -> None:
    # 0.2 % damping at 10 Hz, 60 s: 75 decay times, a line ratio in the tens; its response is Gaussian.
    for seed in range(3):
        assert find_harmonics(_lightly_damped_response(6000, seed), 0.01) == []


def test_a_mode_over_less_than_a_decay_time_is_no_harmonic() -> None:
    # 3 Hz at 0.2 % damping over 20 s (60 cycles, 0.75 decay times): its envelope hardly changes
    # and its kurtosis nears a sinusoid's; 1 of these 8 records was taken for a harmonic before
    # lines with fewer than ~160 cycles in the record were left untested.
    for seed in range(8):
        y = _lightly_damped_response(1000, seed, frequency_hz=3.0, zeta=0.002, sample_time_s=0.02)
        assert find_harmonics(y, 0.02) == []


def test_a_sinusoid_is_found_refined_and_removed() -> None:
    y = _lightly_damped_response(30_000, 5)
    t = np.arange(y.shape[0]) * 0.01
    line = np.outer(np.sin(2 * np.pi * 12.3456 * t + 0.4), [0.5, 0.2]) * y.std(axis=0).max()
    found = find_harmonics(y + line, 0.01)
    assert len(found) == 1
    assert abs(found[0].frequency_hz - 12.3456) < 1e-4 and found[0].kurtosis < 1.6
    cleaned = remove_harmonics(y + line, 0.01, found)
    assert np.sum((cleaned - y) ** 2) < 1e-3 * np.sum(line ** 2)


def _twin_poles(n_orders: int = 30):
    """A PoleSet of two families at every order, one shape: 187.0 Hz at 3.1 % and 188.3 Hz at 0.2 %."""
    from okid_ros.core.output_only_modes import PoleSet

    dt, rng = 1e-3, np.random.default_rng(0)
    orders = np.repeat(np.arange(10, 10 + 2 * n_orders, 2), 2)
    f = np.tile([187.0, 188.3], n_orders) * (1 + 2e-4 * rng.standard_normal(orders.size))
    z = np.tile([0.031, 0.002], n_orders) * (1 + 0.05 * rng.standard_normal(orders.size))
    s = 2 * np.pi * f * (-z + 1j * np.sqrt(1 - z ** 2))
    shape = np.tile([0.5, 0.5, 0.5, 0.5], (orders.size, 1)).astype(complex)
    return PoleSet(orders, f, z, np.exp(s * dt), shape, np.ones(orders.size), np.ones(orders.size, bool))


def test_a_cluster_with_two_poles_per_order_is_two_modes() -> None:
    from okid_ros.core.output_only_modes import cluster_modes

    modes, _ = cluster_modes(_twin_poles())
    assert [round(m.frequency_hz, 1) for m in modes] == [187.0, 188.3]
    assert modes[0].damping_ratio == pytest.approx(0.031, rel=0.1)
    assert modes[1].damping_ratio == pytest.approx(0.002, rel=0.1)
    assert modes[0].group == modes[1].group  # split from one linkage cluster


def test_of_a_modes_twins_the_one_that_dominates_the_spectrum_is_kept() -> None:
    from okid_ros.core.output_only import ROUTES, _drop_noise_modes
    from okid_ros.core.output_only_modes import cluster_modes

    poles = _twin_poles()
    modes, _ = cluster_modes(poles)

    class Quiet:  # every candidate passes the jackknife
        def screened_std(self, target, n, dt, *, scattered):
            return 0.0, 0.0

    def share(n, pole):  # both would pass MIN_SPECTRAL_DOMINANCE on their own
        return 0.8 if abs(np.log(pole)) / (2 * np.pi * 1e-3) < 187.6 else 0.6

    kept = _drop_noise_modes(modes, poles, Quiet(), 1e-3, dominance=share, once=False,
                             steady_width=ROUTES["ssi-cov"].steady_frequency_std_per_width)
    assert [round(m.frequency_hz, 1) for m in kept] == [187.0]


def test_a_mode_beside_a_noise_pole_of_its_shape_is_found() -> None:
    """A mode whose noise twin shares its cluster is found.

    5 modes, 4 accelerometers at 1 kHz, 60 s: the 186.5 Hz mode (2.9 %) gets a 188.3 Hz noise
    pole of its shape at most orders; the two were one cluster and the mode was lost.
    """
    from okid_bench.output_only_cases import OutputOnlyCase
    from okid_ros.sim.models import modal_structure

    system = modal_structure([11.9114, 19.2368, 37.0717, 57.1692, 186.4959],
                             [0.005547, 0.025307, 0.004298, 0.021711, 0.028618], 1, 4, 1e-3, seed=534420,
                             output="acceleration", disturbance_std=1.0, measurement_noise_ratio=0.0113)
    case = OutputOnlyCase("twin", system, 60_000, "")
    _check_modes(case, identify_output_only(case.simulate(29), case.sample_time_s))


def test_a_mode_whose_high_order_poles_fall_into_other_clusters_is_found() -> None:
    """The demo's ambient structure, 60 s of seed 2: its 21.0 Hz mode was lost.

    The mode (1 %) is one cluster at orders 6-48 (20.99 Hz, 0.96 %); above, noise poles beside
    it pull its poles' damping and shape into three other clusters, so no cluster held half the
    orders from its first one on (a CI run of the output-only demo saw it: 21 Hz "not found").
    """
    from okid_ros.tools.simulate_ambient import AMBIENT_FREQUENCIES_HZ, simulate_ambient

    experiment = simulate_ambient(90.0, seed=2, start_ns=0)
    model = identify_output_only(experiment.y[-12000:], experiment.sample_time_s)
    found = np.array([mode.frequency_hz for mode in model.modes])
    assert found.size == len(AMBIENT_FREQUENCIES_HZ), found
    np.testing.assert_allclose(np.sort(found), AMBIENT_FREQUENCIES_HZ, rtol=0.005)


@pytest.mark.parametrize("method", ["ssi-cov", "ssi-cva"])
def test_a_weak_mode_beside_a_strong_one_of_its_shape_is_found(method: str) -> None:
    """Two outputs: 9.64 Hz (1.8 %) 1.4 % above 9.51 Hz (0.45 %), and 49.5 Hz beside 47.4 Hz.

    The weak modes' poles are steady (jackknife scatter 0.06-0.09 of their width) but their share
    of the spectrum along their shape is ~0: the strong neighbour owns it. They were dropped as
    noise; a steady pole is kept whatever its share. Under ssi-cva the 49.5 Hz pole scatters 0.27
    width, steady by that route's limit (``ROUTES["ssi-cva"].steady_frequency_std_per_width``).
    """
    from okid_bench.output_only_cases import random_case

    case = random_case(98)
    _check_modes(case, identify_output_only(case.simulate(98), case.sample_time_s, method=method))


def test_a_mode_whose_share_its_noise_twin_holds_is_found() -> None:
    """12 displacement outputs: the 65.3 Hz mode (1.4 %) and a noise family of its shape beside it.

    The mode's share of the spectrum along its shape was 0.34 (below 0.4): the twin's terms held
    the rest, not a flat noise floor. Measured against what the other candidates' poles leave of
    the spectrum it stands out again; a noise pole does not (random records 0-239: at most 0.23).
    """
    from okid_bench.output_only_cases import random_case

    case = random_case(51)
    _check_modes(case, identify_output_only(case.simulate(51), case.sample_time_s))


def _two_families(frequencies_hz, damping_ratios, orders, *, together, scatter: float, seed: int = 1):
    """A PoleSet of two families of one shape, both at the orders ``together``, one pole between them at the others."""
    from okid_ros.core.output_only_modes import PoleSet

    dt, rng = 0.01, np.random.default_rng(seed)
    both = np.isin(orders, together)
    order = np.concatenate([np.repeat(orders[both], 2), orders[~both]])
    f = np.concatenate([np.tile(frequencies_hz, both.sum()), np.full((~both).sum(), np.mean(frequencies_hz))])
    z = np.concatenate([np.tile(damping_ratios, both.sum()), np.full((~both).sum(), np.mean(damping_ratios))])
    f = f * (1 + scatter * rng.standard_normal(f.size))
    z = z * (1 + 0.05 * rng.standard_normal(z.size))
    s = 2 * np.pi * f * (-z + 1j * np.sqrt(1 - z ** 2))
    shape = np.tile([0.6, 0.8], (f.size, 1)).astype(complex)
    return PoleSet(order, f, z, np.exp(s * dt), shape, np.ones(f.size), np.ones(f.size, bool))


@pytest.mark.parametrize("together, scatter", [(np.arange(10, 42, 2), 5e-4), (np.arange(10, 70, 2), 4e-3)])
def test_two_families_close_in_damping_stay_one_mode(together: np.ndarray, scatter: float) -> None:
    """One mode's poles scattered by noise stay one cluster, whose median estimates the mode.

    10.42 Hz at 1.6 % and 10.58 Hz at 1.2 % (true 10.49 Hz): split, the worse half was kept. Noise
    splits a mode at some orders and not at others, or scatters the two families across the gap
    between them; a resolved pair is neither (the next test).
    """
    from okid_ros.core.output_only_modes import cluster_modes

    poles = _two_families([10.42, 10.58], [0.016, 0.012], np.arange(10, 70, 2), together=together, scatter=scatter)
    modes, _ = cluster_modes(poles)
    assert len(modes) == 1 and 10.42 < modes[0].frequency_hz < 10.58


def test_a_close_pair_resolved_at_every_order_is_two_modes() -> None:
    """Two modes 0.75 % apart, of one estimated shape, resolved from order 16 on, were one cluster and one mode.

    Twin chains 94 (held out): 8.040 and 8.067 Hz read 8.023 Hz at 0.90 % and 8.083 Hz at 0.64 % at
    every order from 16 to 100, each steady to 0.001 Hz, their estimated shapes' MAC 0.998; the
    cluster gave one mode (8.083 Hz). A mode has one pole per order and noise does not hold two
    families that steady at every order: the two are modes of their own (not one mode's families).
    """
    from okid_ros.core.output_only_modes import cluster_modes

    orders = np.arange(10, 102, 2)
    poles = _two_families([8.023, 8.083], [0.009, 0.0064], orders, together=orders[orders >= 16], scatter=1e-4)
    modes, _ = cluster_modes(poles)
    assert [round(m.frequency_hz, 2) for m in modes] == [8.02, 8.08]
    assert modes[0].damping_ratio == pytest.approx(0.009, rel=0.1)
    assert modes[1].damping_ratio == pytest.approx(0.0064, rel=0.1)
    assert modes[0].group != modes[1].group  # two modes: the screening judges each on its own


@pytest.mark.parametrize("method", ["ssi-cov", "ssi-cva"])
@pytest.mark.parametrize("index, true_hz", [(13, 55.963), (15, 17.313)])
def test_a_modes_standard_deviation_is_its_own_where_the_model_order_loses_it(index: int, true_hz: float,
                                                                              method: str) -> None:
    """Read at the model order, these modes' jackknife replicates matched other modes' poles.

    Their frequency standard deviations were 47 and 24 half-power widths (a 32 Hz std on a
    55.9 Hz mode 0.1 width off); the scatter at the order where the screening judged them is
    taken instead, and it still covers the truth. The mode is the one listed nearest its true
    frequency (ssi-cov lists 55.879 Hz, ssi-cva 55.956 Hz).
    """
    from okid_bench.output_only_cases import random_case

    case = random_case(index)
    model = identify_output_only(case.simulate(index), case.sample_time_s, method=method)
    true_f = min((t["frequency_hz"] for t in case.truth()), key=lambda f: abs(f - true_hz))
    mode = min(model.modes, key=lambda m: abs(m.frequency_hz - true_f))
    width = mode.damping_ratio * mode.frequency_hz
    assert abs(true_f / true_hz - 1) < 1e-4
    assert abs(mode.frequency_hz / true_f - 1) < 0.005
    assert 0 < mode.frequency_hz_std < 0.5 * width
    assert abs(mode.frequency_hz - true_f) < 2 * mode.frequency_hz_std


def test_a_mode_listed_twice_is_listed_once() -> None:
    """Two modes within their half-power bands and of one shape are one; a true close pair is two."""
    from okid_ros.core.output_only_modes import ModeCluster, drop_listed_twice

    def mode(f: float, zeta: float) -> ModeCluster:
        return ModeCluster({}, f, zeta, 0.0, 0.0, 1.0, 1.0)

    shape = np.array([1.0, 0.5j, -0.2])
    other = np.array([0.3, -1.0, 0.4j])  # MAC with shape 0.27
    # 74.05 Hz at 3.8 % and 73.0 Hz at 2 %: 0.36 of their summed half-widths apart (random record 45).
    twins = [mode(73.0, 0.02), mode(74.05, 0.038)]
    assert [m.frequency_hz for m in drop_listed_twice(twins, [0.77, 0.9], [shape, 1j * shape])] == [74.05]
    assert [m.frequency_hz for m in drop_listed_twice(twins, [0.9, 0.77], [shape, shape])] == [73.0]
    # The same two of different shapes, or one band apart, are two modes.
    assert len(drop_listed_twice(twins, [0.77, 0.9], [shape, other])) == 2
    apart = [mode(73.0, 0.02), mode(77.0, 0.02)]  # 1.35 summed half-widths
    assert len(drop_listed_twice(apart, [0.77, 0.9], [shape, shape])) == 2


@pytest.mark.parametrize("index", [45, 274])
def test_random_records_whose_mode_was_listed_twice_list_only_true_modes(index: int) -> None:
    """Each true mode listed at most once, nothing else listed.

    A mode (73.0 Hz at 3.8 %, one displacement sensor; 13.5 Hz at 3.9 %, two accelerometers) was
    also listed as a second mode 0.5-0.7 of its half-power width beside it.
    """
    from okid_bench.output_only_cases import random_case

    case = random_case(index)
    model = identify_output_only(case.simulate(index), case.sample_time_s)
    true_f = np.array([t["frequency_hz"] for t in case.truth()])
    nearest = [int(np.argmin(abs(true_f - mode.frequency_hz))) for mode in model.modes]
    assert all(abs(mode.frequency_hz / true_f[k] - 1) < 0.02 for mode, k in zip(model.modes, nearest))
    assert len(set(nearest)) == len(nearest)  # one listed mode per true mode


def test_the_screened_jackknife_stops_reading_replicates_once_a_pole_is_scattered() -> None:
    """``Jackknife.screened_std``: the values of ``std`` when not scattered, None when scattered, read lazily."""
    from okid_ros.core.output_only_support import Jackknife
    from okid_ros.core.worker_threads import SERIAL, WorkerThreads

    dt, read = 1e-3, []

    class Replicate:  # one pole per replicate, at 10 Hz plus the replicate's offset
        def __init__(self, j: int, offset_hz: float) -> None:
            self.j, self.offset_hz, self.max_states = j, offset_hz, 10

        def eigenvalues(self, n: int) -> np.ndarray:
            read.append(self.j)
            s = 2 * np.pi * (10.0 + self.offset_hz) * (-0.01 + 1j)
            return np.exp(np.array([s, np.conj(s)]) * dt)

    def jackknife(offsets_hz, threads: WorkerThreads = SERIAL) -> Jackknife:
        made = Jackknife.__new__(Jackknife)
        made._threads = threads
        made._replicates = [SERIAL.submit(Replicate, j, f) for j, f in enumerate(offsets_hz)]
        return made

    target = np.exp(2 * np.pi * 10.0 * (-0.01 + 1j) * dt)
    limit = 0.05  # Hz of frequency std; the damping never scatters here
    def scattered(f_std, z_std):
        return f_std > limit

    steady = jackknife(0.01 * np.sin(np.arange(8)))
    f_std, z_std = steady.std(np.array([target]), 10, dt)
    assert steady.screened_std(target, 10, dt, scattered=scattered) == (f_std[0], z_std[0])
    read.clear()
    noisy = jackknife([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert noisy.std(np.array([target]), 10, dt)[0][0] > limit
    read.clear()
    assert noisy.screened_std(target, 10, dt, scattered=scattered) is None
    assert read == [0, 1]  # the second replicate decides: the other six are not realized
    with WorkerThreads(2) as threads:  # two at a time: the same answer, the pair holding the decision read
        read.clear()
        assert jackknife([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0], threads).screened_std(
            target, 10, dt, scattered=scattered) is None
        assert sorted(read) == [0, 1, 2, 3]
        assert jackknife(0.01 * np.sin(np.arange(8)), threads).screened_std(
            target, 10, dt, scattered=scattered) == (f_std[0], z_std[0])


def test_the_labels_that_can_hold_a_mode_are_those_spanning_enough_orders() -> None:
    """``_labels_with_orders`` against a count of each label's distinct orders, label by label."""
    from okid_ros.core.output_only_modes import MIN_ORDERS, MIN_TOTAL_FRACTION, _labels_with_orders

    rng = np.random.default_rng(5)
    n_orders = 50
    labels = rng.integers(1, 40, 3000)
    order = 2 * rng.integers(1, n_orders + 1, 3000) * (labels % 3 > 0) + 2 * (labels % 3 == 0)  # some at one order
    needed = max(MIN_ORDERS, MIN_TOTAL_FRACTION * n_orders)
    expected = [label for label in np.unique(labels) if len(set(order[labels == label].tolist())) >= needed]
    kept = _labels_with_orders(labels, order, n_orders)
    assert kept.tolist() == expected and 0 < len(expected) < np.unique(labels).size


@pytest.mark.parametrize("seed", [0, 3])
def test_clusters_too_small_for_a_mode_are_not_summarized_and_the_modes_stay(seed: int) -> None:
    """``cluster_modes(keep_rejected=False)`` skips most clusters of a record's diagram and accepts the same modes."""
    from okid_ros.core import output_only as oo
    from okid_ros.core.output_only_modes import cluster_modes, collect_poles, mark_stable

    case = output_only_case("low-modes")
    y = case.simulate(seed)
    y = y - y.mean(axis=0)
    chosen = oo._select_modes(y, case.sample_time_s, method="ssi-cov", top=oo.DEFAULT_MAX_STATES, block_rows=None)
    poles = collect_poles(chosen.realizer.realize, range(2, chosen.realizer.max_states + 1, 2), case.sample_time_s,
                          max_damping=oo.MAX_DAMPING, max_frequency_hz=0.475 / case.sample_time_s)
    mark_stable(poles)
    modes, rejected = cluster_modes(poles)
    lean_modes, lean_rejected = cluster_modes(poles, keep_rejected=False)
    assert repr(lean_modes) == repr(modes) and len(modes) >= 4
    assert len(lean_rejected) < len(rejected) / 4  # most clusters span a few orders only


def test_a_close_pair_member_whose_shape_mixes_with_its_partners_is_found() -> None:
    """Two mistuned chains: 27.78 / 27.94 Hz, 0.56 % apart, their true shapes orthogonal.

    The 27.94 Hz mode's poles stood at 35 orders, its estimated shape mixed with its partner's out
    of phase (median MPC 0.38): the MPC test (0.5) refused it. It is found now, frequency and
    damping within the goals, and nothing else is listed.
    """
    from okid_bench.physical_cases import physical_case

    case = physical_case(31)
    model = identify_output_only(case.simulate(31), case.sample_time_s)
    found = np.array([mode.frequency_hz for mode in model.modes])
    true = next(t for t in case.truth() if abs(t["frequency_hz"] - 27.936) < 0.01)
    nearest = model.modes[int(np.argmin(np.abs(found - true["frequency_hz"])))]
    assert abs(nearest.frequency_hz / true["frequency_hz"] - 1) < 0.005
    assert abs(nearest.damping_ratio / true["damping_ratio"] - 1) < 0.3
    known = np.array([t["frequency_hz"] for t in case.truth()] + case.hidden_hz())
    assert all(np.min(np.abs(known - f) / known) < 0.02 for f in found)


@pytest.mark.parametrize("method", ["ssi-cov", "ssi-cva"])
@pytest.mark.parametrize("index", [7, 15])
def test_physical_structures_whose_noise_poles_were_listed_list_each_mode_once_and_nothing_else(
        index: int, method: str) -> None:
    """No noise pole listed: twin-chains 7's twin of a chain mode, building 15's pole above its modes.

    Twin-chains 7 listed 63.02 Hz beside 64.15 Hz, of its shape (MAC 0.99) 1.09 summed half-widths
    away, beyond the listed-twice band; building 15 listed 17.32 Hz, 6.7 % above its top mode. Both
    failed the spectral share (0.05, 0.26) and their jackknife scatter was not steady; what the other
    candidates' poles leave of the spectrum they held 0.41-0.42, which passed the limit of 0.4.
    ssi-cva listed twin-chains 7's 63.03 Hz mode (62.99 Hz) with its partner's estimated shape (MAC
    0.98 with 64.06 Hz): the weaker twin's shape is now told from its partner's
    (:func:`~okid_ros.core.output_only_twins.separate_twin_shapes`), and both routes keep the strict check.
    """
    from okid_bench.physical_cases import physical_case
    from okid_ros.core.modal import LISTED_TWICE_MAC, mac

    case = physical_case(index)
    modes = identify_output_only(case.simulate(index), case.sample_time_s, method=method).modes
    known = np.array([t["frequency_hz"] for t in case.truth()] + case.hidden_hz())
    assert all(np.min(np.abs(known - m.frequency_hz) / known) < 0.02 for m in modes), "a noise pole is listed"
    for a, b in zip(modes, modes[1:]):
        band = a.damping_ratio * a.frequency_hz + b.damping_ratio * b.frequency_hz
        if abs(b.frequency_hz - a.frequency_hz) > 2 * band or mac(a.shape, b.shape) < LISTED_TWICE_MAC:
            continue
        raise AssertionError(f"{a.frequency_hz:.3f} and {b.frequency_hz:.3f} Hz of one shape listed")


@pytest.mark.parametrize(("index", "found_hz"), [(4, []), (7, [29.970]), (49, [])])
def test_the_weaker_of_twin_modes_is_not_listed_with_its_partners_shape(index: int, found_hz: list[float]) -> None:
    """Twin chains, the forces on one chain: the other chain's modes were listed with their partners' shapes.

    Under ssi-cva twin-chains 4 (51.40, 76.95 Hz), 7 (46.82, 62.99 Hz) and 49 (44.39 Hz) listed a weaker twin
    with MAC 0.90-0.99 to its partner's true shape and 0.007-0.09 to its own (the pole's eigenvector took in
    its partner's). No listed mode now carries another true mode's shape (the twins of 4 and 49: their own at
    MAC 0.93-0.96; 7's 0.84 and 0.39, nearer their own than any other). ``found_hz``: weaker twins below the
    MPC floor, kept beside the partner mixed into their shape and listed with their own (7's 29.970 Hz: MPC
    0.12 at 7 outputs, MAC 0.65 with its partner's estimated shape; missed before, then listed at 0.34).
    """
    from okid_bench.physical_cases import physical_case
    from okid_ros.core.modal import mac

    case = physical_case(index)
    modes = identify_output_only(case.simulate(index), case.sample_time_s).modes
    truth = case.truth()
    true_hz = np.array([t["frequency_hz"] for t in truth])
    for mode in modes:
        own = int(np.argmin(np.abs(true_hz - mode.frequency_hz)))
        if abs(true_hz[own] / mode.frequency_hz - 1) >= 0.005:
            continue  # a hidden mode's
        macs = np.array([mac(mode.shape, t["shape"]) for t in truth])
        others = np.delete(macs, own)  # above the own MAC, a listed mode reads as another true mode
        assert macs[own] > others.max(), f"{mode.frequency_hz:.3f} Hz: MAC {macs[own]:.3f}, another {others.max():.3f}"
    for hz in found_hz:
        mode = min(modes, key=lambda m: abs(m.frequency_hz - hz))
        assert abs(mode.frequency_hz / hz - 1) < 0.005, f"{hz} Hz not found"
        assert mac(mode.shape, truth[int(np.argmin(np.abs(true_hz - hz)))]["shape"]) >= 0.95


@pytest.mark.parametrize("seed", [11, 5])
def test_a_true_close_pair_keeps_both_modes(seed: int) -> None:
    """The bench's close pair (7.00 / 7.07 Hz at 0.5 %; seeds 11, 5: 0.78, 0.83 summed half-widths): both listed."""
    from okid_ros.core.modal import mac

    case = output_only_case("close-pair")
    modes = identify_output_only(case.simulate(seed), case.sample_time_s).modes
    found = np.array([m.frequency_hz for m in modes])
    pair = [t for t in case.truth() if 6.9 < t["frequency_hz"] < 7.2]
    nearest = [int(np.argmin(np.abs(found - t["frequency_hz"]))) for t in pair]
    assert len(pair) == 2 and nearest[0] != nearest[1]
    for t, k in zip(pair, nearest):
        assert abs(found[k] / t["frequency_hz"] - 1) < 0.005
        assert mac(modes[k].shape, t["shape"]) >= 0.9


@pytest.mark.parametrize(("own_part", "estimated_mac", "separated"), [
    (0.1j, 0.976, True), (0.4j, 0.714, True), (0.4, 0.714, False), (0.8j, 0.385, False)])
def test_separate_twin_shapes_gives_the_weaker_twin_the_part_its_partner_leaves(
        own_part: complex, estimated_mac: float, separated: bool) -> None:
    """A weak twin read as its partner's shape + some of its own gets its own where it took in the partner's.

    Took in: one shape (MAC >= 0.9), or the partner's component outweighing the rest (MAC >= ``TOOK_IN_MAC``,
    0.5) of a shape complex below the MPC floor, its own mixed in out of phase (0.4j: MPC 0.18; twin chains
    7's 29.97 Hz read MAC 0.65, MPC 0.12, and kept its partner's shape under the old test). A real mix
    (0.4: MPC 1) of MAC 0.714 may be a true pair of like shapes: kept. Others keep theirs.
    """
    from types import SimpleNamespace

    from okid_ros.core.modal import mac, mpc
    from okid_ros.core.output_only_twins import separate_twin_shapes

    def mode(frequency_hz, msv, shape):
        unit = np.asarray(shape, dtype=complex) / np.linalg.norm(shape)
        return SimpleNamespace(frequency_hz=frequency_hz, damping_ratio=0.007, msv=msv, shape=unit, mpc=mpc(unit))

    own, partner = np.array([1.0, 2.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0, -1.0])
    weak, strong = mode(63.0, 0.3, partner + own_part * own), mode(64.0, 1.0, partner)
    far = mode(70.0, 0.2, partner + 0.1 * own)  # 7 Hz away: 8 summed widths, beyond TWIN_SHAPE_BAND
    lone = [mode(63.0, 0.3, [1.0]), mode(64.0, 1.0, [1.0])]
    weak_shape, far_shape, strong_shape = weak.shape.copy(), far.shape.copy(), strong.shape.copy()
    assert mac(weak.shape, partner) == pytest.approx(estimated_mac, abs=1e-3)
    assert separate_twin_shapes([weak, strong, far]) == [weak, strong, far]
    if separated:
        assert mac(weak.shape, own) > 1 - 1e-12 and abs(weak.shape[0].imag) < 1e-12 < weak.shape[0].real
    else:
        np.testing.assert_array_equal(weak.shape, weak_shape)
    np.testing.assert_array_equal(strong.shape, strong_shape)
    np.testing.assert_array_equal(far.shape, far_shape)
    separate_twin_shapes(lone)
    assert [m.shape[0] for m in lone] == [1.0, 1.0]


def test_a_true_pair_of_nearly_one_shape_keeps_its_shapes() -> None:
    """Random 5's pair 13.67 / 13.91 Hz (4 outputs, true shapes' MAC 0.955): both listed with their own shape.

    The weaker's estimated shape (MAC 0.999 with its own) was given its shape less its partner's
    (MAC 0.043), as a twin's; the jackknife resolves its likeness to the partner's (9 stds), a twin's not.
    """
    from okid_bench.output_only_cases import random_case
    from okid_ros.core.modal import mac

    case = random_case(5)
    y = case.simulate(5)
    modes = identify_output_only(y - y.mean(axis=0), case.sample_time_s).modes
    found = np.array([m.frequency_hz for m in modes])
    pair = [t for t in case.truth() if 13.5 < t["frequency_hz"] < 14.0]
    assert len(pair) == 2 and mac(pair[0]["shape"], pair[1]["shape"]) > 0.95
    for t in pair:
        k = int(np.argmin(np.abs(found - t["frequency_hz"])))
        assert abs(found[k] / t["frequency_hz"] - 1) < 0.005
        assert mac(modes[k].shape, t["shape"]) >= 0.99, f"{found[k]:.3f} Hz: MAC {mac(modes[k].shape, t['shape']):.3f}"


def test_separate_twin_shapes_keeps_a_component_the_jackknife_resolves() -> None:
    """Replicates that agree on the weaker shape's part along its partner's keep it; scattered ones, NaN, not."""
    from types import SimpleNamespace

    from okid_ros.core.modal import mac
    from okid_ros.core.output_only_twins import separate_twin_shapes

    rng = np.random.default_rng(0)
    own, partner = np.array([1.0, 2.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0, -1.0])

    def pair():
        shape = 0.2 * own + partner
        weak = SimpleNamespace(frequency_hz=63.0, damping_ratio=0.007, msv=0.3, shape=shape / np.linalg.norm(shape))
        return [weak, SimpleNamespace(frequency_hz=64.0, damping_ratio=0.007, msv=1.0, shape=partner / np.sqrt(2))]

    def replicates(along_partner):  # each replicate at its own scale and phase
        rows = np.array([0.2 * own + a * partner for a in along_partner], dtype=complex)
        return rows * np.exp(1j * rng.uniform(0, 2 * np.pi, (len(rows), 1))) * rng.uniform(0.5, 2, (len(rows), 1))

    steady = 1.0 + 0.01 * rng.standard_normal(8)  # 1 +- 0.01 per replicate: about 30 jackknife stds
    scattered = 1.0 + 0.5 * rng.standard_normal(8)  # 0.5 per replicate: below 1 std
    for along, separated in ((steady, False), (scattered, True), (np.r_[steady[:7], np.nan], True)):
        modes = pair()
        before = modes[0].shape.copy()
        shapes = replicates(along)
        separate_twin_shapes(modes, replicate_shapes=lambda mode, shapes=shapes: shapes)
        if separated:
            assert mac(modes[0].shape, own) > 1 - 1e-12
        else:
            np.testing.assert_array_equal(modes[0].shape, before)


@pytest.mark.parametrize(("index", "true_hz"), [(40, 84.010), (55, 191.326)])
def test_the_stronger_of_a_close_pair_is_not_listed_with_its_partners_shape(index: int, true_hz: float) -> None:
    """Twin chains of nearly equal strength: the stronger member took in the weaker's shape, the weaker kept its own.

    Twin-chains 40 listed 83.85 Hz (true 84.01) with MAC 0.44 to its own true shape and 55 listed 191.40 Hz
    with 0.19, each beside its partner (82.83, 188.31 Hz) at MAC 1.00 with its own; the jackknife resolves
    the weaker's likeness to the stronger's (14, 391 stds) and not the stronger's to the weaker's (1.5, 0.8).
    """
    from okid_bench.physical_cases import physical_case
    from okid_ros.core.modal import mac

    case = physical_case(index)
    modes = identify_output_only(case.simulate(index), case.sample_time_s).modes
    truth = next(t for t in case.truth() if abs(t["frequency_hz"] - true_hz) < 0.01)
    mode = min(modes, key=lambda m: abs(m.frequency_hz - true_hz))
    assert abs(mode.frequency_hz / true_hz - 1) < 0.005
    own = mac(mode.shape, truth["shape"])
    assert own >= 0.9, f"{mode.frequency_hz:.3f} Hz: MAC {own:.3f} with its own true shape"


def test_separate_twin_shapes_gives_the_stronger_member_its_part_where_only_the_weakers_likeness_is_resolved() -> None:
    """The stronger's part along a weaker of resolved shape is taken out when its replicates scatter, kept when not."""
    from types import SimpleNamespace

    from okid_ros.core.modal import mac
    from okid_ros.core.output_only_twins import separate_twin_shapes

    rng = np.random.default_rng(1)
    own, partner = np.array([1.0, 2.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0, -1.0])

    def unit(shape):
        return np.asarray(shape, dtype=complex) / np.linalg.norm(shape)

    def replicates(first, second, along):  # each replicate at its own scale and phase
        rows = np.array([first + a * second for a in along], dtype=complex)
        return rows * np.exp(1j * rng.uniform(0, 2 * np.pi, (len(rows), 1))) * rng.uniform(0.5, 2, (len(rows), 1))

    steady, scattered = 0.01 * rng.standard_normal(8), 0.5 * rng.standard_normal(8)
    for strong_along, separated in ((1.0 + scattered, True), (1.0 + steady, False)):
        weak = SimpleNamespace(frequency_hz=63.0, damping_ratio=0.007, msv=0.6, shape=unit(own + 0.3 * partner),
                               mpc=1.0)
        strong = SimpleNamespace(frequency_hz=63.5, damping_ratio=0.007, msv=1.0, shape=unit(partner + own))
        reps = {id(weak): replicates(own, partner, 0.3 + steady), id(strong): replicates(partner, own, strong_along)}
        weak_before, strong_before = weak.shape.copy(), strong.shape.copy()
        separate_twin_shapes([weak, strong], replicate_shapes=lambda mode, reps=reps: reps[id(mode)])
        np.testing.assert_array_equal(weak.shape, weak_before)
        if separated:
            own_part = partner - np.vdot(weak_before, partner) * weak_before
            assert mac(strong.shape, own_part) > 1 - 1e-12
        else:
            np.testing.assert_array_equal(strong.shape, strong_before)
    weak = SimpleNamespace(frequency_hz=63.0, damping_ratio=0.007, msv=0.6, shape=unit(own + 0.3 * partner),
                           mpc=1.0)
    strong = SimpleNamespace(frequency_hz=63.5, damping_ratio=0.007, msv=1.0, shape=unit(partner + own))
    strong_before = strong.shape.copy()
    separate_twin_shapes([weak, strong])  # no jackknife: no stronger member is separated
    np.testing.assert_array_equal(strong.shape, strong_before)
    # a stronger mostly of its own shape (MAC 0.35 with the weaker's, below TOOK_IN_MAC) keeps its part
    weak = SimpleNamespace(frequency_hz=63.0, damping_ratio=0.007, msv=0.6, shape=unit(own + 0.3 * partner),
                           mpc=1.0)
    strong = SimpleNamespace(frequency_hz=63.5, damping_ratio=0.007, msv=1.0, shape=unit(partner + 0.3 * own))
    reps = {id(weak): replicates(own, partner, 0.3 + steady), id(strong): replicates(partner, own, 0.3 + scattered)}
    strong_before = strong.shape.copy()
    separate_twin_shapes([weak, strong], replicate_shapes=lambda mode, reps=reps: reps[id(mode)])
    np.testing.assert_array_equal(strong.shape, strong_before)


def test_two_modes_of_one_shape_holding_poles_side_by_side_are_a_close_pair() -> None:
    """Within the listed-twice band and of one shape, two modes with poles together from the first are two.

    A mode listed twice is a mode and a noise pole that the high orders place beside it (random 36: at
    14 of its partner's 41 orders, from its 22nd on); a close pair's modes come in together (random 5:
    46 of 46, from the first).
    """
    from okid_ros.core.output_only_modes import ModeCluster, drop_listed_twice

    def mode(f: float, zeta: float, orders: range, first_pole: int) -> ModeCluster:
        return ModeCluster({n: first_pole + n for n in orders}, f, zeta, 0.0, 0.0, 1.0, 1.0)

    shape = np.array([1.0, 0.5j, -0.2])
    # 13.69 Hz at 1.6 % and 13.90 Hz at 1.1 %: 0.56 of their summed half-widths apart (random record 5).
    pair = [mode(13.69, 0.016, range(10, 102, 2), 0), mode(13.90, 0.011, range(10, 102, 2), 1000)]
    steady = [True, True]
    assert [m.frequency_hz for m in drop_listed_twice(pair, [-0.13, 0.99], [shape, shape], steady=steady)] == [
        13.69, 13.90]
    # The same, the weaker's pole not steady in the jackknife (a mode split in two, beam 83 under ssi-cov).
    assert [m.frequency_hz for m in drop_listed_twice(pair, [-0.13, 0.99], [shape, shape])] == [13.90]
    late = [mode(13.69, 0.016, range(70, 102, 2), 0), mode(13.90, 0.011, range(10, 102, 2), 1000)]
    assert [m.frequency_hz for m in drop_listed_twice(late, [-0.13, 0.99], [shape, shape], steady=steady)] == [13.90]
    # Together at 31 of 46 orders, but from the 16th on (low-modes 8's noise twin: from the 12th).
    later = [mode(13.69, 0.016, range(40, 102, 2), 0), mode(13.90, 0.011, range(10, 102, 2), 1000)]
    assert [m.frequency_hz for m in drop_listed_twice(later, [-0.13, 0.99], [shape, shape], steady=steady)] == [13.90]
    few = [mode(13.69, 0.016, range(10, 18, 2), 0), mode(13.90, 0.011, range(10, 18, 2), 1000)]  # 4 orders
    assert [m.frequency_hz for m in drop_listed_twice(few, [-0.13, 0.99], [shape, shape], steady=steady)] == [13.90]


@pytest.mark.parametrize("family, index, low_hz, high_hz", [("random", 5, 13.5, 14.0), ("physical", 49, 30.4, 31.0),
                                                            ("physical", 109, 31.7, 32.3)])
def test_a_close_pair_of_one_estimated_shape_is_not_listed_as_one_mode(family: str, index: int, low_hz: float,
                                                                       high_hz: float) -> None:
    """Both modes of a close pair whose estimated shapes read as one are listed, and nothing else.

    Random 5 (13.67 / 13.91 Hz, one output), twin-chains 49 (30.54 / 30.86 Hz) and 109 (31.87 / 32.13 Hz):
    the weaker, 0.5-0.6 summed half-widths from its partner at MAC 0.96-0.98, was dropped as the partner
    listed twice, though the two held distinct poles at every order either held one.
    """
    from okid_bench.output_only_cases import random_case
    from okid_bench.physical_cases import physical_case

    case = random_case(index) if family == "random" else physical_case(index)
    modes = identify_output_only(case.simulate(index), case.sample_time_s).modes
    found = np.array([m.frequency_hz for m in modes])
    known = np.array([t["frequency_hz"] for t in case.truth()] + (case.hidden_hz() if family == "physical" else []))
    assert all(np.min(np.abs(known - f) / known) < 0.02 for f in found), "a noise pole is listed"
    pair = [t["frequency_hz"] for t in case.truth() if low_hz < t["frequency_hz"] < high_hz]
    nearest = [int(np.argmin(np.abs(found - f))) for f in pair]
    assert len(pair) == 2 and nearest[0] != nearest[1]
    assert all(abs(found[k] / f - 1) < 0.005 for f, k in zip(pair, nearest))
