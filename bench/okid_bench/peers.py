"""Peer identification methods, wrapped to one calling convention.

``peer_identify(name, u, y, sample_time_s, n_states) -> (model or None, reason)``

``model`` is a dict with ``A`` (n, n), ``B`` (n, m), ``C`` (p, n), ``D`` (p, m),
``predictor_gain`` (n, p) or ``None``, ``K`` (n, p) in the paper's convention
(``predictor_gain = A K``) or ``None``, and ``info`` (settings used).  ``reason`` is ``""`` on
success, otherwise a one-line explanation (the wrapper never raises).

Peers and their conventions (checked against the installed sources):

``control-era`` (python-control >= 0.10)
    ``control.markov(Y, U, m)`` fits ``[D, CB, CAB, ...]`` (m terms) by least squares on the
    input convolution (an FIR / output-error fit: assumes ``C A^j B = 0`` for ``j > m - 2``,
    no noise model); arrays are (channels, time).  ``control.eigensys_realization(H, r, m, n)``
    is plain ERA on those terms (Hankel of ``m`` block rows, ``n`` block columns).
    Deterministic: no gain, so ``K = None`` and the prediction ratio is not defined.

``sippy-n4sid``, ``sippy-moesp``, ``sippy-cva`` (sippy-unipi 1.0.x)
    ``sippy_unipi.system_identification(y, u, "N4SID"|"MOESP"|"CVA", SS_fixed_order=n,
    SS_f=f, SS_D_required=True)``.  Orientation is guessed from the longer axis.  It
    estimates A, B, C, D by least squares on the subspace state sequence, takes the residual
    covariances Q, R, S and returns ``K = (A P C^T + S)(C P C^T + R)^{-1}`` from the Riccati
    equation: the *predictor* gain of ``x_{k+1} = A x + B u + K e``.  Hence paper
    ``K = A^{-1} K_sippy``; this wrapper returns ``predictor_gain = K_sippy`` and the paper's K.
    ``SS_D_required=True`` because accelerometer data have ``D != 0`` (SIPPY's default forces
    ``D = 0``).  SIPPY rescales each channel to unit variance internally and scales back.

``nfoursid`` (nfoursid 1.0.x)
    ``NFourSID(df, output_columns, input_columns, num_block_rows=f)``;
    ``subspace_identification()``; ``system_identification(rank=n)`` returns a ``StateSpace``
    (``.a .b .c .d``) and the residual covariance ``[[R, S^T], [S, Q]]`` (output block first).
    Its model is ``x_{k+1} = A x + B u + K e`` but no ``K`` is returned; the wrapper computes
    the predictor gain from (Q, R, S) with the same Riccati equation (as its ``Kalman`` class
    does in steady state).
"""

from __future__ import annotations

import contextlib
import io
import warnings
from typing import Callable, Optional

import numpy as np

from okid_ros.core.kalman_gain import riccati_predictor_gain as _riccati_predictor_gain

__all__ = ["PEERS", "BIC", "peer_identify", "available_peers"]

#: ``n_states`` for a peer's own order choice by BIC (the SIPPY peers only).
BIC = "bic"


def _paper_K(A: np.ndarray, L: Optional[np.ndarray]) -> Optional[np.ndarray]:
    if L is None:
        return None
    if np.linalg.cond(A) > 1e10:
        return None
    return np.linalg.solve(A, L)


def _model(A, B, C, D, L, info) -> dict:
    A = np.atleast_2d(np.asarray(A, dtype=float))
    L = None if L is None else np.asarray(L, dtype=float)
    return {
        "A": A,
        "B": np.asarray(B, dtype=float).reshape(A.shape[0], -1),
        "C": np.asarray(C, dtype=float).reshape(-1, A.shape[0]),
        "D": np.atleast_2d(np.asarray(D, dtype=float)),
        "predictor_gain": L,
        "K": _paper_K(A, L),
        "info": info,
    }


def _control_era(u, y, dt, n, n_markov: Optional[int] = None, **_):
    import control

    N, m = u.shape
    if n_markov is None:
        n_markov = int(min(200, max(2 * n + 3, N // (5 * m))))
    H = control.markov(y.T, u.T, n_markov)
    H = np.asarray(H).reshape(y.shape[1], m, n_markov)
    rows = cols = (n_markov - 1) // 2
    sysd, _sv = control.eigensys_realization(H, n, m=rows, n=cols)
    return _model(sysd.A, sysd.B, sysd.C, sysd.D, None,
                  {"n_markov": n_markov, "hankel_rows": rows, "hankel_cols": cols})


def _sippy(method: str):
    def run(u, y, dt, n, horizon: int = 20, max_order: int = 20, **_):
        from sippy_unipi import system_identification

        if n == BIC:  # SIPPY's own order choice: BIC over orders 1..max_order, horizon f = p = horizon
            f = int(horizon)
            order = {"IC": "BIC", "SS_orders": [1, int(max_order)], "SS_p": f}
        else:
            f = int(max(horizon, n + 1))
            order = {"SS_fixed_order": int(n)}
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mod = system_identification(y, u, method, SS_f=f, SS_D_required=True, tsample=dt, **order)
        K = mod.K
        L = None if (K is None or np.size(K) == 0) else np.asarray(K, dtype=float)
        if L is not None and not np.all(np.isfinite(L)):
            L = None
        return _model(mod.A, mod.B, mod.C, mod.D, L, {"horizon": f, **({"order": "BIC"} if n == BIC else {})})
    return run


def _nfoursid(u, y, dt, n, horizon: int = 20, **_):
    import pandas as pd
    from nfoursid.nfoursid import NFourSID

    m, p = u.shape[1], y.shape[1]
    f = int(max(horizon, int(np.ceil((n + 1) / p))))
    ucols = [f"u{i}" for i in range(m)]
    ycols = [f"y{i}" for i in range(p)]
    df = pd.DataFrame(np.hstack([u, y]), columns=ucols + ycols)
    nf = NFourSID(df, output_columns=ycols, input_columns=ucols, num_block_rows=f)
    nf.subspace_identification()
    ss, cov = nf.system_identification(rank=int(n))
    A, B, C, D = ss.a, ss.b, ss.c, ss.d
    R = cov[:p, :p]
    S = cov[p:, :p]
    Q = cov[p:, p:]
    try:
        L, _Re, _P = _riccati_predictor_gain(A, C, Q, R, S)
    except Exception:  # noqa: BLE001 - no stabilizing Riccati solution: report without gain
        L = None
    return _model(A, B, C, D, L, {"num_block_rows": f})


#: name -> callable(u, y, dt, n_states, **options) -> model dict
PEERS: dict[str, Callable] = {
    "control-era": _control_era,
    "sippy-n4sid": _sippy("N4SID"),
    "sippy-moesp": _sippy("MOESP"),
    "sippy-cva": _sippy("CVA"),
    "nfoursid": _nfoursid,
}


def available_peers() -> list[str]:
    """Names of the peers whose package imports."""
    names = []
    mods = {"control-era": "control", "nfoursid": "nfoursid"}
    for name in PEERS:
        mod = mods.get(name, "sippy_unipi")
        try:
            __import__(mod)
        except Exception:  # noqa: BLE001
            continue
        names.append(name)
    return names


def peer_identify(name: str, u: np.ndarray, y: np.ndarray, sample_time_s: float, n_states: int | str,
                  **options) -> tuple[Optional[dict], str]:
    """Identify a model with a peer package, given the (true) state dimension.

    Parameters
    ----------
    name : one of :data:`PEERS` (``control-era``, ``sippy-n4sid``, ``sippy-moesp``,
        ``sippy-cva``, ``nfoursid``).
    u : (N, m) inputs; y : (N, p) outputs; time along axis 0.
    sample_time_s : sample period in seconds.
    n_states : model order n, or :data:`BIC` (the SIPPY peers: their own choice by BIC).
    options : ``horizon`` (subspace past/future block rows, default 20) for the subspace
        peers; ``max_order`` (largest order of the BIC choice, default 20); ``n_markov``
        (number of Markov parameters, default ``min(200, N / (5 m))``) for
        ``control-era``.

    Returns
    -------
    (model, reason) : ``model`` as described in the module docstring, or ``None`` with a
    one-line ``reason`` when the peer fails or returns non-finite matrices.
    """
    if name not in PEERS:
        return None, f"unknown peer {name!r}"
    u = np.asarray(u, dtype=float).reshape(len(u), -1)
    y = np.asarray(y, dtype=float).reshape(len(y), -1)
    if n_states == BIC and not name.startswith("sippy-"):
        return None, f"{name} has no order choice of its own"
    try:
        with np.errstate(all="ignore"):
            model = PEERS[name](u, y, float(sample_time_s), n_states if n_states == BIC else int(n_states), **options)
    except Exception as exc:  # noqa: BLE001 - a peer failure is a result, not a crash
        msg = str(exc).splitlines()[0] if str(exc) else ""
        return None, f"{name} failed: {type(exc).__name__}: {msg}"[:200]
    for key in ("A", "B", "C", "D"):
        if not np.all(np.isfinite(model[key])):
            return None, f"{name} returned non-finite {key}"
    if n_states != BIC and model["A"].shape != (n_states, n_states):
        return None, f"{name} returned order {model['A'].shape[0]} instead of {n_states}"
    return model, ""
