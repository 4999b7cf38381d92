"""Argument types shared by the `okid-ros` subcommands (argparse `type=` callables)."""

from __future__ import annotations

import argparse

from okid_ros.core.options import OUTPUT_ONLY_METHODS, RealizationOptions

__all__ = ["positive_int", "int_between", "float_between", "positive_finite_float", "states_or_auto",
           "penalty_or_gcv", "node_parameter_range", "NodeParameterDefault", "add_bag_arguments",
           "add_progress_arguments", "namespace", "ignored_for_output_only", "add_output_only_method_argument",
           "output_only_method_ignored"]


def positive_int(text: str) -> int:
    """An integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def int_between(low: int, high: int | None = None):
    """An argparse type: an integer in ``[low, high]`` (``high`` None: no upper bound).

    The message of a refusal names the range, e.g. "expected an integer from 1 to 10000, got 0".
    """
    wanted = f"an integer >= {low}" if high is None else f"an integer from {low} to {high}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}") from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {value}")
        return value

    parse.__name__ = "int"
    return parse


def _float(text: str, wanted: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}") from None


def float_between(low: float, high: float, wanted: str):
    """An argparse type: a number in ``[low, high]`` (NaN is refused: it fails the comparison).

    ``wanted`` describes it, with ``{low}`` and ``{high}`` (e.g. ``"seconds from {low:g} to {high:g}"``).
    """
    wanted = wanted.format(low=low, high=high)

    def parse(text: str) -> float:
        value = _float(text, wanted)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {value}")
        return value

    parse.__name__ = "float"
    return parse


def positive_finite_float(text: str) -> float:
    """A number > 0 and finite (not NaN, not inf)."""
    value = _float(text, "a positive finite number")
    if not 0.0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {value}")
    return value


def states_or_auto(text: str) -> int | str:
    """A model order >= 1, or "auto"."""
    return text if text == "auto" else positive_int(text)


def penalty_or_gcv(text: str) -> float | str:
    """A regularization penalty >= 0, or "gcv"."""
    if text == "gcv":
        return text
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'gcv' or a number >= 0, got {text!r}") from None
    low, high = node_parameter_range("arx.penalty")
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"expected 'gcv' or a number from {low:g} to {high:g}, got {value}")
    return value


def node_parameter_range(name: str) -> tuple[float, float]:
    """The range ``(low, high)`` of the nodes' parameter ``name``.

    An option of a command that does what the parameter does takes the same range (inf once
    went through to a singular matrix).
    """
    spec = _node_parameter(name)
    return spec.low, spec.high


def _node_parameter(name: str):
    """The parameter table's spec of the nodes' parameter ``name`` (imported only when asked)."""
    from okid_ros.service.params import ARX_NODE, ESTIMATOR_NODE, node_params

    return next(spec for node in (ARX_NODE, ESTIMATOR_NODE) for spec in node_params(node) if spec.name == name)


class NodeParameterDefault:
    """The default of the nodes' parameter ``name`` as an option's default, looked up when used.

    ``float(default)`` (a command's run) or ``str(default)`` (``%(default)s`` in its help) reads
    the parameter table; building the parser does not, so ``okid-ros`` starts without importing
    the numerical modules the table's defaults come from.
    """

    def __init__(self, name: str) -> None:
        self.name = name

    def __float__(self) -> float:
        return float(_node_parameter(self.name).default)

    def __str__(self) -> str:
        return f"{float(self):g}"


#: Options of the input-output chain and whether each was given (differs from its default, as in
#: `identify`; `track` has the same defaults for those it passes over, see ignored_for_output_only).
_INPUT_OUTPUT_OPTIONS = {
    "--order": lambda args: args.order != "auto",
    "--states": lambda args: args.states != "auto",
    "--ar-order": lambda args: args.ar_order is not None,
    "--method": lambda args: args.method != "okid",
    "--regularization": lambda args: args.regularization is not None,
    "--no-refine": lambda args: args.no_refine,
    "--gain": lambda args: args.gain != RealizationOptions.gain,
    "--max-states": lambda args: args.max_states != RealizationOptions.max_states,
}


def ignored_for_output_only(args: argparse.Namespace, options) -> str:
    """The warning for those of ``options`` given to an output-only run, which passes them over ("" if none).

    One sentence for `identify` and `track` (each names the options its output-only route ignores).
    """
    given = [option for option in options if _INPUT_OUTPUT_OPTIONS[option](args)]
    if not given:
        return ""
    verb = "applies" if len(given) == 1 else "apply"  # "--order apply to" was said of one option
    return f"{', '.join(given)} {verb} to input-output identification; ignored for this output-only one"


def add_output_only_method_argument(parser) -> None:
    """``--output-only-method``, as node 2's ``realization.output_only_method`` (`identify` and `track`)."""
    parser.add_argument("--output-only-method", choices=OUTPUT_ONLY_METHODS, default=OUTPUT_ONLY_METHODS[0],
                        help="how an output-only model is realized, as node 2's realization.output_only_method: "
                        "ssi-cva (covariance-driven SSI with canonical-variate weighting, default: the measured "
                        "winner), ssi-cov (unweighted, faster on long lags) or var (the paper's vector-AR route); "
                        "docs/benchmarks-output-only.md")


def output_only_method_ignored(args: argparse.Namespace) -> str:
    """The warning for ``--output-only-method`` given to an input-output run ("" if not given)."""
    if args.output_only_method == OUTPUT_ONLY_METHODS[0]:
        return ""
    return ("--output-only-method applies to output-only identification (--output-only, or a record without u); "
            "ignored for this input-output one")


def path_text(text: str) -> str:
    """A file or folder argument: not empty (an unset shell variable would otherwise mean here)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path")
    return text


def add_bag_arguments(parser) -> None:
    """``--params``, ``--param`` and ``--source`` for commands that read a bag like `process`."""
    parser.add_argument("--params", action="append", default=[], metavar="FILE",
                        help="for a bag: the nodes' parameter YAML (input sources, sample time; default: the "
                        "built-in defaults, equal to config/okid.yaml)")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="for a bag: override a parameter, as for `okid-ros process`")
    parser.add_argument("--source", action="append", default=[], metavar="SPEC",
                        help="for a bag: replace inputs.sources, one 'KIND TOPIC [FIELD=CHANNEL ...]' per option")


def namespace(text: str) -> str:
    """A rig namespace, as `okid-ros up --namespace` takes it (validated, normalized)."""
    from okid_ros.service.topics import validate_namespace

    try:
        return validate_namespace(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_progress_arguments(parser) -> None:
    """``--progress`` / ``--no-progress`` (default: a progress bar only when stderr is a terminal)."""
    progress = parser.add_mutually_exclusive_group()
    progress.add_argument("--progress", dest="progress", action="store_true", default=None,
                          help="always show the progress bar (default: only when stderr is a terminal)")
    progress.add_argument("--no-progress", dest="progress", action="store_false", help="never show it")
