"""The model published in Chen, Huang & Juang (1991), "Experimental Example".

Ten-bay truss (NASA Langley CSI), two tip thrusters, two tip accelerometers, data decimated
to 125 Hz (``sample_time_s = 0.008``).  The paper prints the identified model in normalized
modal form::

    A = diag{[0.9555 0.2922; -0.2922 0.9555], [0.9229 0.3568; -0.3568 0.9229],
             [-0.7538 0.6423; -0.6423 -0.7538]}
    B^T, C, D, K^T  (the paper prints B and K transposed; here they are (6, 2))

in the innovation form of its Eqs. 30-31::

    x_{k+1} = A x_k + B u_k + A K e_k,     y_k = C x_k + D u_k + e_k.

Modes computed from the printed A (continuous poles ``s = ln(z) / dt``, natural frequency
``|s|``, damping ratio ``-Re(s) / |s|``; see :func:`paper_modes`):

======  ==================  ==============  ===============  ============
mode    frequency (rad/s)   frequency (Hz)  damping ratio    paper says
======  ==================  ==============  ===============  ============
1       37.0973             5.9042          0.2763 %         37.0988, 0.27 %
2       46.1325             7.3422          2.8684 %         46.1175, 2.87 %
3       304.4888            48.4609         0.3987 %         (not listed)
======  ==================  ==============  ===============  ============

The differences to the paper's table (0.004 % and 0.03 % in frequency) come from the
four-digit rounding of the printed A.  The third block is a pole pair at 48.5 Hz, close to the
62.5 Hz Nyquist frequency and above the 20 Hz Bessel anti-alias filter of the experiment; the
paper does not list it as a structural mode.  It is part of the published model, so it is part
of the simulated truth here.

Innovation covariance (not given in the paper)
----------------------------------------------
The default is ``Re = I`` (unit innovation variance on both accelerometers, in the model's
output units).  Reasons, with numbers computed from the published matrices:

* the published ``K`` fixes how strongly the innovations drive the modes: the stochastic part
  ``H(z) = I + C (zI - A)^{-1} A K`` amplifies ``Re = r I`` to an output covariance of
  ``r * [[164.9, 77.6], [77.6, 56.3]]`` (output 1 is driven mostly through the 0.28 % mode);
* so the innovation can never be more than ``1/164.9 = 0.61 %`` (output 1) and ``1.8 %``
  (output 2) of the output variance, however large ``r`` is: the paper's statement that the
  prediction-error covariance is "less than 1.5 % of the covariance of the output" is
  consistent with any ``r``, and a target of 1-2 % of the *total* output variance is not
  reachable with the published ``K`` (the trace ratio tends to 0.9 % as ``r -> inf``);
* with unit-variance inputs low-passed at 15 Hz the deterministic output covariance is about
  ``[[399, 197], [197, 116]]``; ``r = 1`` then makes the noise-driven response 30 % of the
  output variance and the innovation 0.18 % (output 1) and 0.58 % (output 2) of it (trace
  0.27 %), i.e. a clearly noisy but input-dominated experiment.  With the 50 Hz input the
  deterministic covariance is about ``[[137, 45], [45, 51]]`` and the innovation is 0.33 % /
  0.93 % of the output variance.

Use ``paper_model(innovation_variance=r)`` for other noise levels.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from okid_ros.core.statespace import InnovationModel

__all__ = [
    "PAPER_SAMPLE_TIME_S",
    "PAPER_A",
    "PAPER_B",
    "PAPER_C",
    "PAPER_D",
    "PAPER_K",
    "PAPER_PUBLISHED_MODES",
    "paper_model",
    "paper_modes",
]

#: Sample period after the paper's decimation 250 Hz -> 125 Hz.
PAPER_SAMPLE_TIME_S = 0.008

#: State matrix, three 2x2 blocks as printed.
PAPER_A = scipy.linalg.block_diag(
    np.array([[0.9555, 0.2922], [-0.2922, 0.9555]]),
    np.array([[0.9229, 0.3568], [-0.3568, 0.9229]]),
    np.array([[-0.7538, 0.6423], [-0.6423, -0.7538]]),
)

#: Input matrix (6, 2); the paper prints its transpose.
PAPER_B = np.array([
    [0.1725, -0.1117, 0.1122, -0.0321, 0.3241, -0.1871],
    [-0.1789, 0.1267, -0.1522, 0.0556, 0.3309, -0.2725],
]).T

#: Output matrix (2, 6) as printed (zero in row 1 at each mode's second state).
PAPER_C = np.array([
    [1.7754, 0.0000, 1.0023, 0.0000, 1.3946, 0.0000],
    [0.9201, 0.0362, -1.6909, -0.3692, -1.4287, 0.1185],
])

#: Direct feed-through (2, 2) as printed.
PAPER_D = np.array([
    [-0.0012, 0.0165],
    [0.0215, 0.0009],
])

#: The paper's estimator gain K (6, 2) (predictor gain is A K); the paper prints K^T.
PAPER_K = np.array([
    [0.2787, 0.1807, 0.3437, 0.1072, 0.0065, 0.0357],
    [0.2277, -0.0685, 0.1236, -0.0884, -0.0874, -0.0182],
]).T

#: The paper's table: (frequency rad/s, damping ratio as a fraction).
PAPER_PUBLISHED_MODES = ((37.0988, 0.0027), (46.1175, 0.0287))


def paper_model(innovation_variance: float = 1.0) -> InnovationModel:
    """The published model as a true innovation-form system.

    Parameters
    ----------
    innovation_variance : ``r`` in ``Re = r I`` (2x2).  The paper does not give ``Re``; see the
        module docstring for why the default is 1.

    Returns
    -------
    InnovationModel with A (6, 6), B (6, 2), C (2, 6), D (2, 2), K (6, 2), Re (2, 2),
    ``sample_time_s = 0.008``.
    """
    return InnovationModel(
        A=PAPER_A.copy(), B=PAPER_B.copy(), C=PAPER_C.copy(), D=PAPER_D.copy(),
        K=PAPER_K.copy(), innovation_covariance=float(innovation_variance) * np.eye(2),
        sample_time_s=PAPER_SAMPLE_TIME_S,
    )


def paper_modes() -> list[dict]:
    """Modes of the published A, one per complex pair, sorted by frequency.

    Returns
    -------
    list of dicts with ``frequency_rad_s`` (``|s|``), ``frequency_hz``, ``damping_ratio``
    (fraction), ``damped_frequency_rad_s`` (``Im s``) and the discrete eigenvalue ``z``,
    where ``s = ln(z) / 0.008``.
    """
    z = np.linalg.eigvals(PAPER_A)
    z = z[z.imag > 0]
    s = np.log(z) / PAPER_SAMPLE_TIME_S
    out = []
    for zi, si in sorted(zip(z, s), key=lambda t: abs(t[1])):
        wn = abs(si)
        out.append({
            "frequency_rad_s": wn,
            "frequency_hz": wn / (2 * np.pi),
            "damping_ratio": -si.real / wn,
            "damped_frequency_rad_s": si.imag,
            "z": zi,
        })
    return out
