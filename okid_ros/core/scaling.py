"""Units of each channel: identification on channels of unit spread, models restored to physical units.

Physical units span many decades (raw counts, nanometres, kilonewtons): a record times 1e150
overflows the normal equations (``Phi^T Phi`` holds squares) and one times 1e-150 underflows them,
and channels of different units weight the ridge penalty, the ERA weighting and the order
criteria differently. The batch identification therefore divides each channel by its spread
(:func:`okid_ros.core.channels.channel_scales`), identifies, and restores the model to physical
units (:func:`restore_model`). With the diagonal scalings ``Su`` (inputs) and ``Sy``
(outputs), ``u_s = Su^-1 u`` and ``y_s = Sy^-1 y``, the same state ``x`` gives

    ``B = B_s Su^-1,  C = Sy C_s,  D = Sy D_s Su^-1,  K = K_s Sy^-1,  Re = Sy Re_s Sy``

(``K`` in the paper's convention, predictor gain ``A K``); ``A`` and the state are unchanged, so
the poles, frequencies and damping ratios are those of the scaled identification: the same for
any choice of units, within rounding. Physical mode blocks are then re-normalized to the modal
form's convention (unit output norm, reference row real) in physical units, so mode shapes and
modal coordinates are in output units as documented in :mod:`okid_ros.core.modal`.

What stays in the scaled units (unit spread per channel): the Hankel singular values, the order
criteria, the ARX penalty and condition number, the stabilization diagram and the mode
indicators MPC, MSV and EMAC (so they do not depend on the choice of units either).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from okid_ros.core.arx import ArxFit
from okid_ros.core.channels import ChannelScales, channel_scales, channel_spread
from okid_ros.core.excitation import LiveInputs, excitation_warnings, output_problem
from okid_ros.core.identified_model import IdentificationError, IdentifiedModel
from okid_ros.core.modal import phase_reference_row
from okid_ros.core.output_spikes import MAD_TO_STD

__all__ = ["IdentificationFrame", "covariance_range_problem", "restore_model"]


def restore_model(model: IdentifiedModel, scales: ChannelScales, *,
                  offset_warnings: list[str] | None = None) -> IdentifiedModel:
    """``model`` identified on scaled data, in physical units (see the module docstring).

    Parameters
    ----------
    model : identified from ``scales.scale(u, y)``; scales : the channel scales used.
    offset_warnings : the large-offset warnings computed on the physical data; they replace
        the scaled ones (whose values would be in scaled units).
    """
    su, sy = scales.input, scales.output
    with np.errstate(over="ignore", under="ignore"):
        covariance = _covariance_in_units(model.innovation_covariance, sy)
    b, d = _input_gains_in_units(model, su, sy)
    warnings = list(model.warnings)
    if offset_warnings is not None:
        warnings = offset_warnings + [w for w in warnings if not w.startswith("large offsets")]
    physical = replace(
        model,
        B=b, C=model.C * sy[:, None], D=d,
        K=model.K / sy[None, :], innovation_covariance=covariance,
        input_offset=None if model.input_offset is None else model.input_offset * su,
        output_offset=None if model.output_offset is None else model.output_offset * sy,
        system_markov=None if model.system_markov is None
        else model.system_markov * sy[None, :, None] / su[None, None, :],
        arx=None if model.arx is None else scales.restore_arx(model.arx),
        warnings=warnings,
    )
    return _normalize_mode_blocks(physical)


def _covariance_in_units(scaled: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """``Sy scaled Sy``, or IdentificationError when float64 cannot hold it (overflow, underflow)."""
    physical = scaled * np.outer(scales, scales)
    lost = ~np.isfinite(physical) | ((physical == 0) & (scaled != 0))
    if lost.any():
        raise IdentificationError(_beyond_range(scales))
    return physical


def covariance_range_problem(y: np.ndarray) -> str:
    """Why no covariance of the outputs ``y`` (N, p) fits float64 in their units ("" if one does).

    Said before the work where a command would fail on it later (``track``: in the windows' sums;
    ``identify`` refuses the model at the end, :func:`restore_model`). Judged on each output's
    robust spread (normalized median absolute deviation, else its spread): a glitch of 1e200 is
    a glitch, not the record's units.
    """
    y = np.asarray(y, dtype=float)
    with np.errstate(over="ignore", under="ignore"):  # outputs about 1e308: their deviations overflow, refused
        deviation = MAD_TO_STD * np.median(np.abs(y - np.median(y, axis=0)), axis=0) if y.shape[0] \
            else np.ones(y.shape[1])
        spreads = np.where(deviation > 0, deviation, channel_spread(y))
        squares = np.square(spreads)
    return "" if np.all(np.isfinite(squares) & (squares > 0)) else _beyond_range(spreads)


def _input_gains_in_units(model: IdentifiedModel, su: np.ndarray, sy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``B Su^-1`` and ``Sy D Su^-1``, or IdentificationError when float64 cannot hold them.

    Inputs of a spread near 1e-308 (a subnormal unit) give gains beyond 1e308: they were written
    as NaN in ``B`` with exit 0, the fits NaN, and numpy's overflow warning the only word.
    """
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        b, d = model.B / su[None, :], model.D * sy[:, None] / su[None, :]
    if np.isfinite(b).all() and np.isfinite(d).all():
        return b, d
    raise IdentificationError(f"the input gains B and D in the record's units are beyond the float64 range (input "
                              f"spreads {', '.join(f'{v:.3g}' for v in su)}; gains beyond 1e+308 cannot be "
                              f"represented): express the inputs in other units, e.g. multiplied by 1e100")


def _beyond_range(spreads: np.ndarray) -> str:
    """The refusal of outputs whose squared spreads float64 cannot hold, with the units that would hold them.

    It said "divided by 1e100" of spreads of 1e-200 too, which takes them further out of range.
    """
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        squares = np.square(spreads)
    beyond = ~(np.isfinite(squares) & (squares > 0))
    large, small = beyond & ~(np.abs(spreads) < 1.0), beyond & (np.abs(spreads) < 1.0)  # NaN/Inf: overflowed
    advice = ("the large ones divided and the small ones multiplied by 1e100" if large.any() and small.any()
              else "multiplied by 1e100" if small.any() else "divided by 1e100")
    return (f"the innovation covariance in the record's units is beyond the float64 range (output spreads "
            f"{', '.join(f'{v:.3g}' for v in spreads)}; squares beyond 1e+-308 cannot be represented): express "
            f"the outputs in other units, e.g. {advice}")


def _normalize_mode_blocks(model: IdentifiedModel) -> IdentifiedModel:
    """Re-normalize each physical mode's 2x2 block: ``||C [a, b]||_F = 1``, reference row real > 0.

    A per-block similarity ``x_old = P x_new`` with ``P = [[g_r, g_i], [-g_i, g_r]]`` (a rotation
    and scaling of the block's basis ``psi = a + i b`` by ``g``) commutes with the block's
    ``[[sigma, omega], [-omega, sigma]]`` form, so ``A`` keeps its blocks.
    """
    n = model.A.shape[0]
    transform = np.eye(n)
    modes = []
    for index, mode in enumerate(model.modes):
        i = 2 * index
        shape = model.C[:, i] + 1j * model.C[:, i + 1]
        norm = np.linalg.norm(shape)
        if not norm > 0:
            modes.append(mode)
            continue
        g = np.exp(-1j * np.angle(shape[phase_reference_row(shape)])) / norm
        transform[i:i + 2, i:i + 2] = [[g.real, g.imag], [-g.imag, g.real]]
        modes.append(replace(mode, shape=shape * g))
    inverse = np.linalg.inv(transform)
    return replace(
        model, A=inverse @ model.A @ transform, B=inverse @ model.B, C=model.C @ transform, K=inverse @ model.K,
        x0=None if model.x0 is None else inverse @ model.x0, modes=modes,
    )


@dataclass
class IdentificationFrame:
    """The frame a record is identified in: live inputs only, each channel of unit spread.

    ``enter`` takes the record (and an ARX fit of it) into the frame, ``leave`` brings the model
    back: to the record's units (:func:`restore_model`) and to all its inputs (dead ones with
    zero ``B``, ``D``; :class:`~okid_ros.core.excitation.LiveInputs`).

    Attributes
    ----------
    live : the live inputs; scales : the channel scales of the live record;
    u_all : (N, m) the record's inputs; physical : (u, y) of the live record in its units;
    warnings : the dead inputs named, with what to do.
    excited : whether some input varies (False only with ``refuse_unexcited=False``).
    """

    live: LiveInputs
    scales: ChannelScales
    u_all: np.ndarray
    physical: tuple[np.ndarray, np.ndarray]
    warnings: list[str]
    excited: bool = True

    @classmethod
    def of(cls, u: np.ndarray, y: np.ndarray, *, refuse_unexcited: bool = True) -> IdentificationFrame:
        """The frame of ``u`` (N, m), ``y`` (N, p); IdentificationError when it cannot be identified.

        Refused: no input varies; an output is dead or a combination of the others
        (:func:`~okid_ros.core.excitation.output_problem`). With ``refuse_unexcited=False`` a
        record without excitation keeps all its inputs (the caller refuses it after its own
        checks, :attr:`excited`).
        """
        problem = output_problem(y)
        if problem:
            raise IdentificationError(problem)
        live, warnings = LiveInputs.of(u), excitation_warnings(u)
        excited = bool(live.keep)
        if not excited:
            if refuse_unexcited:
                raise IdentificationError(warnings[0])
            live = LiveInputs(tuple(range(u.shape[1])), u.shape[1])
        u_live = live.select(u)
        return cls(live, channel_scales(u_live, y), u, (u_live, y), warnings, excited)

    def enter(self, u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``u`` (N, m), ``y`` (N, p) in the frame: live inputs, unit spread."""
        return self.scales.scale(self.live.select(u), y)

    def enter_arx(self, arx: ArxFit) -> ArxFit:
        """An ARX fit of the record, in the frame."""
        return self.scales.inverse().restore_arx(self.live.select_arx(arx))

    def leave(self, model: IdentifiedModel, offsets: str, *, offset_warnings: list[str]) -> IdentifiedModel:
        """``model`` identified in the frame, for the record: its units, all its inputs."""
        model = restore_model(model, self.scales, offset_warnings=offset_warnings)
        return self.live.restore(model, self.u_all, offsets)
