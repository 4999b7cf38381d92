"""Structural change: detection delay, re-identification time and false alarms (issue 13).

Run:  python bench/change_detection.py [--part track delay stationary jump calibration] [--seeds 0] [--threads 1]

Systems: ``okid_bench.changes`` (250 Hz, 2 inputs, 3 accelerometers, 5 % sensor noise,
disturbance forces): a 4-mode structure whose frequencies drop by 6 % or 2 % or whose damping
doubles, and a 4-storey shear frame whose second storey loses 20 % of its stiffness.

Parts:

- ``track``: each change case through the `okid-ros track` command (``--order 100 --window
  4000 --every 250``, everything else at its defaults, change detection on), the change one
  sample before an update (the record's first window full at sample 4099, the change at
  4099 + 6 * 250 - 1 = 5598), the record running 4500 samples past the change. Per case: the
  detection delay (declared sample - true change), the error of the estimated change point, and
  per mode the settling time (first update from which on the identified mode nearest to the new
  true frequency stays within 0.5 % of it for every later update), and when the model lists
  exactly one mode per true mode within 0.5 % ("clean"). Goals: detection within 1000 samples
  of the 6 % drop; every mode within 0.5 % at most 2000 samples after the change.
- ``delay``: detection delay against the size of the change, with the detector of `track`
  armed with the model of a full window (4000 rows, q = 100) of the structure before, on
  changes of several sizes (no re-identification: what is measured is the test alone).
- ``stationary``: false alarms of that detector over 120 000 stationary samples (8 minutes
  at 250 Hz) per system and seed; after an alarm the detector is re-armed with the same model,
  so every alarm is counted. In `track` the reference model stays the same once the window is
  full (it is only replaced by models of twice as many rows), so this is what `track` sees.
- ``jump``: the state-jump test (``okid_ros/core/state_jump.py``) on each system and seed: the
  record looped back on itself 3000 samples after the arming (a seam: the state jumps, the
  structure does not change) and every change size of ``delay``; the reference model's whitened
  innovations from 5 samples before the seam or change (its first loud sample searched over the
  first judgement's samples), ``--jump-lengths`` samples of them, fitted
  by a jump of the state: power before -> after over the calibration's (first 1000 samples), and
  whether the test takes it for a jump (``*``). The steel subframe looped (a model of samples
  0-5999, ARX order 20) closes the table.
- ``louder``: the disturbance forces of the 4-mode structure made 1.5, 2 and 3 times as strong at
  the change sample, the structure unchanged (the optimal predictor gain changes with the
  disturbances against the sensor noise), with the detector of ``delay``: declared (a false
  alarm) or taken for a noise change (``core/noise_change.py``) and re-armed, and alarms after.
- ``output-only``: the delay part's changes and the input forces made 0.5-3 times as strong or
  low-passed (first order, pole a, unit variance) at the change sample, with the inputs unmeasured:
  the reference is ``identify_output_only`` of the first full window, the monitor that of node 2
  for a model without inputs (the detector's defaults), 10000 samples after the change.
- ``calibration``: the detector alone on white unit innovations (2 outputs), calibrated on
  200 or 1000 samples: runs with an alarm within 20 000 samples, with the threshold of an exact
  calibration against the one that allows for the calibration's error (the default), 300 runs each.
"""

from __future__ import annotations

import argparse
import os
import sys

import checkout

_parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
_parser.add_argument("--part", nargs="+",
                     choices=("track", "delay", "stationary", "jump", "calibration", "short-reference", "louder",
                              "output-only"),
                     default=["track", "delay", "stationary"], help="what to run (default: all)")
_parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="noise seeds (default 0)")
_parser.add_argument("--cases", nargs="+", default=["frequency:0.06", "frequency:0.02", "damping:2", "stiffness:0.2"],
                     help="track cases KIND:SIZE (default: the four of the issue)")
_parser.add_argument("--stationary-samples", type=int, default=120_000, help="per system and seed")
_parser.add_argument("--no-change-detection", action="store_true",
                     help="track part without change detection (the sliding window alone), for comparison")
_parser.add_argument("--variance-ratio", type=float, default=None,
                     help="CUSUM design ratio of the delay and stationary parts (default: the core's)")
_parser.add_argument("--false-alarm-samples", type=float, default=None,
                     help="expected samples between false alarms of the delay and stationary parts "
                     "(default: the core's)")
_parser.add_argument("--no-model-error-check", dest="model_error_check", action="store_false",
                     help="delay and stationary parts: every alarm of the power test declared (the test before "
                     "the model-error check)")
_parser.add_argument("--no-state-jump-test", dest="state_jump_test", action="store_false",
                     help="delay and stationary parts: no state-jump judgement of confirmed alarms (the test "
                     "before it)")
_parser.add_argument("--no-noise-change-test", dest="noise_change_test", action="store_false",
                     help="delay, stationary and louder parts: no noise-change judgement of confirmed alarms (the "
                     "test before it)")
_parser.add_argument("--jump-lengths", type=int, nargs="+", default=[90, 100, 150],
                     help="jump part: samples fitted from 5 before the seam or change (default 90 100 150)")
_parser.add_argument("--reference-seeds", type=int, default=30, help="short-reference part: references (default 30)")
_parser.add_argument("--output-only-window", type=int, default=None,
                     help="output-only part: the reference from the last N samples before the arming (default: all)")
_parser.add_argument("--threads", type=int, default=1, help="BLAS threads (default 1)")
_args = _parser.parse_args()
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = str(_args.threads)

import contextlib  # noqa: E402
import dataclasses  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.signal import lfilter  # noqa: E402

checkout.add()
from okid_bench.changes import change_case  # noqa: E402
from okid_bench.switching import settling, simulate_switched  # noqa: E402
from okid_ros.cli import main as okid_ros_main  # noqa: E402
from okid_ros.core.arx import fit_arx  # noqa: E402
from okid_ros.core.change_detection import ChangeDetector, whitening_matrix  # noqa: E402
from okid_ros.core.change_monitor import StructuralChangeMonitor  # noqa: E402
from okid_ros.core.output_only import identify_output_only  # noqa: E402
from okid_ros.core.pipeline import identify, identify_from_arx  # noqa: E402
from okid_ros.core.state_jump import StateJumpTest  # noqa: E402
from okid_ros.core.statespace import InnovationPredictor  # noqa: E402
from okid_ros.records import save_record  # noqa: E402

# Rejected trial steps of the refinement may overflow; they are part of its normal work.
warnings.filterwarnings("ignore", category=RuntimeWarning, module=r"okid_ros\.core\.refine")

ORDER, WINDOW, EVERY, TOLERANCE = 100, 4000, 250, 0.005
REAL_RECORD = Path(__file__).resolve().parents[2] / "shared/data/real/daisy-steel-subframe/steel_subframe.npz"
FIRST = WINDOW + ORDER - 1
CHANGE = FIRST + 6 * EVERY - 1
AFTER = 4500


def parse_case(text: str):
    kind, _, size = text.partition(":")
    return change_case(kind, float(size))


def run_track(case, seed: int, workdir: Path) -> tuple[list, float]:
    u, y = case.simulate(CHANGE + AFTER, CHANGE, seed)
    data, out = workdir / f"{case.name}-{seed}.npz", workdir / f"{case.name}-{seed}.jsonl"
    save_record(data, u, y, case.sample_time_s)
    started = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        status = okid_ros_main(["track", str(data), "--order", str(ORDER), "--window", str(WINDOW),
                                "--every", str(EVERY), "--jsonl", str(out), "--no-progress"]
                               + (["--no-change-detection"] if _args.no_change_detection else []))
    if status != 0:
        raise SystemExit(f"okid-ros track failed on {case.name} seed {seed}")
    return [json.loads(line) for line in out.read_text().splitlines()], time.perf_counter() - started


def part_track() -> None:
    print(f"## track: okid-ros track --order {ORDER} --window {WINDOW} --every {EVERY}; change at sample "
          f"{CHANGE} (1 sample before an update); record {CHANGE + AFTER} samples")
    print()
    print("| case | seed | declared after (samples) | change point error (samples) | false alarms before | "
          "settling per mode (samples after the change) | worst | clean from "
          "| max error after settling (%) | run (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for text in _args.cases:
            case = parse_case(text)
            for seed in _args.seeds:
                lines, elapsed = run_track(case, seed, Path(tmp))
                declared = [e for e in lines if e["change_detected"]]
                early = [e for e in declared if e["change_declared_index"] < CHANGE]
                late = [e for e in declared if e["change_declared_index"] >= CHANGE]
                delay = late[0]["change_declared_index"] - CHANGE if late else None
                point = late[0]["change_sample_index"] - CHANGE if late else None
                per_mode, clean = settling(lines, CHANGE, case.old_frequencies_hz, case.new_frequencies_hz, TOLERANCE)
                settle = [m.settle_samples for m in per_mode]
                worst = None if None in settle else max(settle)
                errors = [100 * m.max_error_after for m in per_mode if m.settle_samples is not None]
                print(f"| {case.name} | {seed} | {delay if delay is not None else 'not detected'} | "
                      f"{point if point is not None else '-'} | {len(early)} | "
                      f"{', '.join('never' if s is None else str(s) for s in settle)} | "
                      f"{worst if worst is not None else 'never'} | "
                      f"{clean - CHANGE if clean is not None else 'never'} | "
                      f"{max(errors) if errors else float('nan'):.3f} | {elapsed:.0f} |")
                sys.stdout.flush()
    print()


def reference_model(case, u, y):
    """The model `track` arms the detector with: the pipeline on the record's first full window."""
    u, y = u[:WINDOW + ORDER], y[:WINDOW + ORDER]
    return identify_from_arx(fit_arx(u, y, ORDER, "ridge", "gcv"), u, y, case.sample_time_s,
                             n_states="auto", max_states=40)


def armed(model, u_window, y_window, reference_rows: int = WINDOW) -> StructuralChangeMonitor:
    warm = InnovationPredictor(model)
    warm.run(u_window, y_window)
    options = {}
    if _args.variance_ratio is not None:
        options["variance_ratio"] = _args.variance_ratio
    if _args.false_alarm_samples is not None:
        options["false_alarm_samples"] = _args.false_alarm_samples
    monitor = StructuralChangeMonitor(model.C.shape[0], model_error_check=_args.model_error_check,
                                      state_jump_test=_args.state_jump_test,
                                      noise_change_test=_args.noise_change_test, **options)
    monitor.arm(model, warm.x, reference_rows=reference_rows)
    return monitor


DELAY_SIZES = {"frequency": [0.005, 0.01, 0.02, 0.04, 0.06], "damping": [1.1, 1.25, 1.5, 2.0, 3.0],
               "stiffness": [0.02, 0.05, 0.1, 0.2, 0.3]}


def part_delay() -> None:
    limit = 10_000
    print(f"## delay: detection delay (samples at 250 Hz) against the size of the change; the detector armed "
          f"with the model of a full window, calibrated over the next 1000 samples; the change 2000 samples "
          f"after that; 'not within {limit}' if no alarm {limit} samples after it")
    print()
    print("| kind | size | seed | delay (samples) | delay (s) | change point error (samples) | variance ratio |")
    print("|---|---|---|---|---|---|---|")
    for kind, sizes in DELAY_SIZES.items():
        for seed in _args.seeds:
            model = None
            for size in sizes:
                case = change_case(kind, size)
                change = WINDOW + ORDER + 3000
                u, y = case.simulate(change + limit, change, seed)  # the same samples before the change
                if model is None:
                    model = reference_model(case, u, y)
                monitor = armed(model, u[:WINDOW + ORDER], y[:WINDOW + ORDER])
                start = WINDOW + ORDER
                alarm = monitor.process(u[start:], y[start:], start)
                if alarm is not None and alarm.alarm_index < change:
                    print(f"| {kind} | {size:g} | {seed} | false alarm at {alarm.alarm_index - change} | - | - | - |")
                    continue
                if alarm is None:
                    print(f"| {kind} | {size:g} | {seed} | not within {limit} | - | - | - |")
                    continue
                delay = alarm.alarm_index - change
                print(f"| {kind} | {size:g} | {seed} | {delay} | {delay * case.sample_time_s:.2f} | "
                      f"{alarm.change_index - change} | {alarm.variance_ratio:.2f} |")
                sys.stdout.flush()
    print()


def part_stationary() -> None:
    n = _args.stationary_samples
    print(f"## stationary: false alarms over {n} samples per system and seed (expected samples between false "
          f"alarms: the default 1e7)")
    print()
    print("| system | seed | samples monitored | false alarms | largest statistic / threshold | run (s) |")
    print("|---|---|---|---|---|---|")
    for kind in ("frequency", "stiffness"):
        case = change_case(kind, 0.06 if kind == "frequency" else 0.2)
        system = "4-mode structure" if kind == "frequency" else "shear frame"
        for seed in _args.seeds:
            started = time.perf_counter()
            start = WINDOW + ORDER
            u, y = case.simulate(start + n, None, seed)
            model = reference_model(case, u, y)
            monitor = armed(model, u[:start], y[:start])
            alarms, index, peak, monitored = 0, start, 0.0, 0
            block = 5000
            while index < start + n:
                stop = min(index + block, start + n)
                alarm = monitor.process(u[index:stop], y[index:stop], index)
                if monitor.state == "monitoring":
                    monitored += stop - index
                peak = max(peak, monitor.statistic / monitor.threshold)
                if alarm is not None:
                    alarms += 1
                    peak = max(peak, alarm.statistic / alarm.threshold)
                    monitor = armed(model, u[:alarm.alarm_index + 1], y[:alarm.alarm_index + 1])
                    stop = alarm.alarm_index + 1
                index = stop
            print(f"| {system} | {seed} | {monitored} | {alarms} | {peak:.2f} | {time.perf_counter() - started:.0f} |")
            sys.stdout.flush()
    print()


def _jump_row(label: str, model, u, y, start: int, onset: int) -> str:
    """One row of the jump part: the fit's power before -> after at each length, ``*`` if a jump."""
    predictor, whiten = InnovationPredictor(model), whitening_matrix(model.innovation_covariance)
    z = predictor.run(u, y) @ whiten.T
    baseline = float(np.mean(z[start:start + 1000] ** 2))
    test = StateJumpTest(predictor.F, whiten @ predictor.C)
    cells = []
    for length in _args.jump_lengths:  # loud samples searched up to the first judgement's end, as the detector's
        jump = test.judge(z[onset - 5:onset - 5 + length], onset - 5, baseline_power=baseline,
                          loud_until=onset - 5 + test.needed_samples - 1)
        cells.append("too few" if jump is None else
                     f"{jump.power_before:.2f} -> {jump.power_after:.2f}{' *' if jump.explained else ''}")
    return f"| {label} | {model.n_states} | {baseline:.2f} | " + " | ".join(cells) + " |"


def part_jump() -> None:
    print("## jump: a jump of the state fitted to the excursion; power over the calibration's, before -> after "
          "(* taken for a jump)")
    print()
    print("| record | states | calibration power | " + " | ".join(f"{n} samples" for n in _args.jump_lengths) + " |")
    print("|---|---|---|" + "---|" * len(_args.jump_lengths))
    start = WINDOW + ORDER
    change = start + 3000
    for kind, sizes in DELAY_SIZES.items():
        for seed in _args.seeds:
            u, y = change_case(kind, sizes[0]).simulate(change + 2000, change, seed)
            model = reference_model(change_case(kind, sizes[0]), u, y)
            looped_u, looped_y = u.copy(), y.copy()
            rest = len(u) - change
            looped_u[change:], looped_y[change:] = u[start + 200:start + 200 + rest], y[start + 200:start + 200 + rest]
            print(_jump_row(f"{kind} seed {seed}: seam", model, looped_u, looped_y, start, change))
            for size in sizes:
                u, y = change_case(kind, size).simulate(change + 2000, change, seed)
                print(_jump_row(f"{kind} seed {seed}: {size:g}", model, u, y, start, change))
            sys.stdout.flush()
    record = np.load(REAL_RECORD)
    u, y, dt = record["u"], record["y"], float(record["sample_time_s"])
    model = identify(u[:6000], y[:6000], dt, order=20)
    print(_jump_row("steel subframe, looped", model, np.vstack([u, u]), np.vstack([y, y]), 6000, len(u)))
    print()


def part_calibration(runs: int = 300, samples: int = 20_000, n_outputs: int = 2) -> None:

    print(f"## calibration: runs of white innovations ({n_outputs} outputs) with an alarm within {samples} "
          f"samples, of {runs} (expected at the default 1e7 samples between false alarms: "
          f"{runs * (1 - np.exp(-samples / 1e7)):.1f})")
    print()
    print("| calibration samples | exact-calibration threshold | threshold allowing for the calibration's error |")
    print("|---|---|---|")
    for reference in (200, 1000):
        counts = []
        for confidence in (None, "default"):
            options = {} if confidence == "default" else {"calibration_confidence": None}
            alarms = 0
            for run in range(runs):
                z = np.random.default_rng(run).standard_normal((reference + samples, n_outputs))
                detector = ChangeDetector(n_outputs, reference_samples=reference, **options)
                alarms += detector.process(z, 0) is not None
            counts.append(alarms)
        print(f"| {reference} | {counts[0]} | {counts[1]} |")
        sys.stdout.flush()
    print()


def part_short_reference(samples: int = 20_000) -> None:

    from okid_ros.core.pipeline import identify
    from okid_ros.sim import lowpass_input, paper_model, simulate_innovation

    truth = paper_model()
    seeds = range(_args.reference_seeds)
    print(f"## short-reference: false alarms of references from 1000-sample windows of the paper's structure, "
          f"{len(seeds)} seeds, {samples} stationary samples each (expected at the default 1e7 samples between "
          f"false alarms: {len(seeds) * (1 - np.exp(-samples / 1e7)):.2f} runs with an alarm)")
    print()
    print("| whitening | runs with an alarm | references whitened (order > 0) | median order | "
          "largest statistic / threshold (median, max) |")
    print("|---|---|---|---|---|")
    rows = {0: [], None: []}
    for seed in seeds:
        u = lowpass_input(samples + 1000, 2, 50.0, truth.sample_time_s, seed=seed)
        y, _ = simulate_innovation(truth, u, seed=100 + seed)
        model = identify(u[:1000], y[:1000], truth.sample_time_s, order=20, n_states=6, refine=False)
        warm = InnovationPredictor(model)
        warm.run(u[:1000], y[:1000])
        for max_order in rows:
            options = {} if max_order is None else {"whitening_max_order": max_order}
            monitor = StructuralChangeMonitor(2, **options)
            monitor.arm(model, warm.x)
            largest, alarm = 0.0, None
            for lo in range(1000, samples + 1000, 250):  # blocks, to follow the statistic
                alarm = monitor.process(u[lo:lo + 250], y[lo:lo + 250], lo)
                detector = monitor.detector
                if alarm is not None:
                    largest = alarm.statistic / alarm.threshold
                    break
                if detector.calibrated:
                    largest = max(largest, detector.statistic / detector.threshold)
            rows[max_order].append((alarm is not None, detector.whitening_order, largest))
    for max_order, label in ((0, "none (before)"), (None, "AR, BIC order (default)")):
        alarms = sum(r[0] for r in rows[max_order])
        orders = [r[1] for r in rows[max_order]]
        ratios = [r[2] for r in rows[max_order]]
        print(f"| {label} | {alarms} | {sum(o > 0 for o in orders)} | {np.median(orders):.0f} | "
              f"{np.median(ratios):.2f}, {max(ratios):.2f} |")
    print()


def part_louder(factors=(1.5, 2.0, 3.0), after_samples: int = 10_000) -> None:
    print(f"## louder: the disturbance forces times a factor at the change, the structure unchanged; the detector "
          f"of the delay part over {after_samples} samples after it (noise-change test "
          f"{'on' if _args.noise_change_test else 'off'})")
    print()
    print("| factor | seed | declared after (samples) | noise changes | alarms in all |")
    print("|---|---|---|---|---|")
    case = change_case("frequency", 0.06)
    for factor in factors:
        louder = dataclasses.replace(case.before,
                                     process_noise_covariance=factor**2 * case.before.process_noise_covariance)
        for seed in _args.seeds:
            change = WINDOW + ORDER + 3000
            u = case.make_input(change + after_samples, 100 + seed)
            y = simulate_switched([case.before, louder], change, u, seed=200 + seed)
            model = reference_model(case, u, y)
            start = WINDOW + ORDER
            monitor, alarms, noise, first = armed(model, u[:start], y[:start]), 0, 0, None
            while start < len(u):  # after an alarm: re-armed with the same model at the next sample
                alarm = monitor.process(u[start:], y[start:], start)
                noise += monitor.noise_changes
                if alarm is None:
                    break
                alarms += 1
                first = alarm.alarm_index - change if first is None else first
                start = alarm.alarm_index + 1
                monitor = armed(model, u[:start], y[:start])
            print(f"| {factor:g} | {seed} | {'none' if first is None else first} | {noise} | {alarms} |")
            sys.stdout.flush()
    print()


#: The output-only part's changes of the unmeasured forces: their level, and their colour (a first-order pole).
FORCE_CHANGES = {"forces x": [0.5, 2.0, 3.0], "forces low-passed, pole": [0.5, 0.8, 0.9, -0.5]}


def _output_only_record(kind: str, size: float, seed: int, n_samples: int, change: int):
    """``(case, y)``: a change of the structure (the delay part's) or of its forces at ``change``."""
    if kind not in FORCE_CHANGES:
        case = change_case(kind, size)
        return case, case.simulate(n_samples, change, seed)[1]
    case = change_case("frequency", 0.06)
    u = case.make_input(n_samples, 100 + seed)
    if kind == "forces x":
        u[change:] *= size
    else:
        u[change:] = lfilter([np.sqrt(1 - size**2)], [1, -size], u[change:], axis=0)
    return case, simulate_switched([case.before], [], u, seed=200 + seed)


def part_output_only(after_samples: int = 10_000) -> None:
    start, change = WINDOW + ORDER, WINDOW + ORDER + 3000
    rows = _args.output_only_window or start
    source = f"the first {start}" if rows == start else f"the {rows} before the arming, of the first {start}"
    print(f"## output-only: the inputs unmeasured; the reference identify_output_only of {source} "
          f"samples, armed at their end, calibrated over the next 1000, the change 3000 samples after the "
          f"arming; 'none' if not declared within {after_samples} samples after it")
    print()
    print("| change | size | seed | declared after (samples) | change point error (samples) | noise changes | "
          "excitation changes |")
    print("|---|---|---|---|---|---|---|")
    for kind, sizes in {**DELAY_SIZES, **FORCE_CHANGES}.items():
        for seed in _args.seeds:
            model = None
            for size in sizes:
                case, y = _output_only_record(kind, size, seed, change + after_samples, change)
                no_inputs = np.zeros((y.shape[0], 0))
                if model is None:
                    model = identify_output_only(y[start - rows:start], case.sample_time_s)
                monitor = armed(model, no_inputs[:start], y[:start], min(rows, WINDOW))
                alarm = monitor.process(no_inputs[start:], y[start:], start)
                declared = "none" if alarm is None else str(alarm.alarm_index - change)
                point = "-" if alarm is None else str(alarm.change_index - change)
                print(f"| {kind} | {size:g} | {seed} | {declared} | {point} | {monitor.noise_changes} | "
                      f"{getattr(monitor, 'excitation_changes', '-')} |")
                sys.stdout.flush()
    print()


def main() -> int:
    for part in _args.part:
        {"track": part_track, "delay": part_delay, "stationary": part_stationary, "jump": part_jump,
         "calibration": part_calibration, "short-reference": part_short_reference, "louder": part_louder,
         "output-only": part_output_only}[part]()
    return 0


if __name__ == "__main__":
    sys.exit(main())
