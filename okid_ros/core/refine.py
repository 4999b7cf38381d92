"""Prediction-error refinement of an identified innovation model (optional last step).

The least-squares steps before this one are consistent but not efficient. Minimizing the sum
of squared one-step prediction errors over the predictor's parameters (the prediction-error
method) brings the estimate close to the statistically best one for Gaussian innovations; it is
started from the realized model, so it converges in a few Gauss-Newton iterations.

Parametrization: the predictor ``xhat_{k+1} = Abar xhat_k + [L, Bbar] v_k``, ``yhat_k = C xhat_k
+ D u_k`` (``v = [y; u]``) in complex-diagonal coordinates. A pole pair ``lambda`` with input row
``g`` (w,) and output column ``c`` (p,) contributes

    yhat_k += 2 Re(c xi_k),      xi_{k+1} = lambda xi_k + g^T v_k,

and a real pole the same without the factor 2 and real parts. Each ``xi`` is a first-order
recursive filter, run by ``scipy.signal.lfilter``, so a residual evaluation costs a few
milliseconds, and the Jacobian is analytic (one more filter per pole). The first ``burn_in`` samples, where the unknown initial predictor state still
matters, are left out of the cost. The result is mapped back to the real modal block form, and
``A = Abar + L C``, ``B = Bbar + L D``, ``K = A^{-1} L``.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import linalg, signal

from okid_ros.core.refit import PredictorFit, gain_from_predictor

__all__ = ["refine_prediction_error", "refinement_size"]


def _split_poles(eigenvalues: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    tol = 1e-9 * max(1.0, np.abs(eigenvalues).max())
    return np.flatnonzero(eigenvalues.imag > tol), np.flatnonzero(np.abs(eigenvalues.imag) <= tol)


def refinement_size(n_states: int, n_outputs: int, n_inputs: int) -> int:
    """Number of real parameters the refinement adjusts (upper bound, all poles complex)."""
    w = n_outputs + n_inputs
    return n_states * (1 + w + n_outputs) + n_outputs * n_inputs


class _Predictor:
    """Packs and unpacks the parameter vector; evaluates the one-step prediction errors."""

    def __init__(self, n_pairs: int, n_real: int, p: int, m: int):
        self.n_pairs, self.n_real, self.p, self.m = n_pairs, n_real, p, m
        self.w = p + m

    def pack(self, pairs, reals, D) -> np.ndarray:
        parts = []
        for lam, g, c in pairs:
            parts += [[lam.real, lam.imag], g.real, g.imag, c.real, c.imag]
        for lam, g, c in reals:
            parts += [[lam], g, c]
        parts.append(D.ravel())
        return np.concatenate([np.ravel(x) for x in parts])

    def unpack(self, theta: np.ndarray):
        w, p, m = self.w, self.p, self.m
        pos = 0
        pairs, reals = [], []

        def take(k: int) -> np.ndarray:
            nonlocal pos
            out = theta[pos : pos + k]
            pos += k
            return out

        for _ in range(self.n_pairs):
            re, im = take(2)
            g = take(w) + 1j * take(w)
            c = take(p) + 1j * take(p)
            pairs.append((complex(re, im), g, c))
        for _ in range(self.n_real):
            lam = take(1)[0]
            reals.append((lam, take(w).copy(), take(p).copy()))
        D = take(p * m).reshape(p, m)
        return pairs, reals, D

    def jacobian(self, theta: np.ndarray, v: np.ndarray, u: np.ndarray, burn_in: int) -> np.ndarray:
        """d yhat / d theta, (N' p, len(theta)), rows ordered like ``yhat[burn_in:].ravel()``.

        With ``f_j = z^-1 / (1 - lambda z^-1) v_j`` and ``xi = sum_j g_j f_j``:
        ``d xi / d lambda = z^-2 / (1 - lambda z^-1)^2 (v g)``, ``d xi / d g_j = f_j``; a pair's
        real parameters enter through ``2 Re(c xi)`` (an imaginary part through ``-2 Im``).
        """
        pairs, reals, _ = self.unpack(theta)
        p, m, w = self.p, self.m, self.w
        n_rows = v.shape[0] - burn_in
        columns: list[np.ndarray] = []  # each (N', p)

        for lam, g, c in pairs:
            f = signal.lfilter([0.0, 1.0], [1.0, -lam], v, axis=0)[burn_in:]  # (N', w)
            drive = v @ g
            dxi = signal.lfilter([0.0, 0.0, 1.0], [1.0, -2.0 * lam, lam * lam], drive)[burn_in:]
            xi = f @ g
            cd = np.outer(dxi, c)
            columns += [2.0 * cd.real, -2.0 * cd.imag]
            for j in range(w):
                columns.append(2.0 * np.outer(f[:, j], c).real)
            for j in range(w):
                columns.append(-2.0 * np.outer(f[:, j], c).imag)
            eye = np.eye(p)
            for k in range(p):
                columns.append(2.0 * np.outer(xi.real, eye[k]))
            for k in range(p):
                columns.append(-2.0 * np.outer(xi.imag, eye[k]))
        for lam, g, c in reals:
            f = signal.lfilter([0.0, 1.0], [1.0, -lam], v, axis=0)[burn_in:]
            dxi = signal.lfilter([0.0, 0.0, 1.0], [1.0, -2.0 * lam, lam * lam], v @ g)[burn_in:]
            xi = f @ g
            columns.append(np.outer(dxi, c))
            for j in range(w):
                columns.append(np.outer(f[:, j], c))
            eye = np.eye(p)
            for k in range(p):
                columns.append(np.outer(xi, eye[k]))
        u_used = u[burn_in:]
        for k in range(p):
            for j in range(m):
                col = np.zeros((n_rows, p))
                col[:, k] = u_used[:, j]
                columns.append(col)
        return np.column_stack([col.ravel() for col in columns])

    def predict(self, theta: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        pairs, reals, D = self.unpack(theta)
        y_hat = u @ D.T
        for lam, g, c in pairs:
            drive = v @ g  # (N,) complex
            xi = signal.lfilter([0.0, 1.0], [1.0, -lam], drive)
            y_hat += 2.0 * np.real(np.outer(xi, c))
        for lam, g, c in reals:
            xi = signal.lfilter([0.0, 1.0], [1.0, -lam], v @ g)
            y_hat += np.outer(xi, c)
        return y_hat


def _levenberg_marquardt(residuals, jacobian, theta: np.ndarray, max_evaluations: int) -> tuple[np.ndarray, float]:
    """Minimize ``||residuals(theta)||^2`` by Levenberg-Marquardt with Marquardt's diagonal scaling.

    Solves the small normal equations ``(J^T J + mu diag(J^T J)) dx = -J^T r`` instead of an SVD
    of the tall Jacobian: the parameters are tens, the residuals thousands.
    """
    r = residuals(theta)
    cost = float(r @ r)
    mu = 1e-3
    evaluations = 1
    while evaluations < max_evaluations:
        J = jacobian(theta)
        with np.errstate(all="ignore"):
            g = J.T @ r
            H = J.T @ J
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(H))):
            break
        diag = np.maximum(np.diag(H), 1e-12 * max(np.diag(H).max(), 1e-300))
        improved = False
        while evaluations < max_evaluations:
            try:
                with warnings.catch_warnings():
                    # A damped system that is merely ill-conditioned still gives a usable step.
                    warnings.simplefilter("ignore", linalg.LinAlgWarning)
                    step = -linalg.solve(H + mu * np.diag(diag), g, assume_a="pos")
            except (linalg.LinAlgError, ValueError):
                step = None
            if step is None or not np.all(np.isfinite(step)):
                mu *= 10.0
                if mu > 1e8:
                    return theta, cost
                continue
            trial = theta + step
            r_trial = residuals(trial)
            evaluations += 1
            cost_trial = float(r_trial @ r_trial)
            if cost_trial < cost:
                improved = cost - cost_trial > 1e-10 * cost
                theta, r, cost = trial, r_trial, cost_trial
                mu = max(mu / 3.0, 1e-9)
                break
            mu *= 4.0
            if mu > 1e8:
                return theta, cost
        if not improved:
            break
    return theta, cost


def refine_prediction_error(
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    D: np.ndarray,
    K: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    burn_in: int = 100,
    max_evaluations: int = 40,
) -> PredictorFit | None:
    """Refine ``(A, B, C, D, K)`` by minimizing the one-step prediction errors on ``u``, ``y``.

    Parameters
    ----------
    A, B, C, D, K : the starting innovation model (paper convention, predictor gain ``A K``).
    u : (N, m); y : (N, p) the identification record.
    burn_in : samples excluded from the cost at the start.
    max_evaluations : cap on residual evaluations of the optimizer (the Jacobian is analytic).

    Returns
    -------
    The refined model (in real modal block coordinates), or None if the refinement did not
    lower the cost or left an unstable predictor (then keep the starting model).
    """
    n = A.shape[0]
    p, m = D.shape
    L = A @ K
    Abar = A - L @ C
    G = np.hstack([L, B - L @ D])
    lam, W = linalg.eig(Abar)
    if np.max(np.abs(lam)) >= 1.0:
        return None
    try:
        W_inv = linalg.inv(W)
    except linalg.LinAlgError:
        return None
    g_all = W_inv @ G  # (n, w)
    c_all = C @ W  # (p, n)
    upper, real = _split_poles(lam)
    pairs = [(lam[i], g_all[i], c_all[:, i]) for i in upper]
    reals = [(lam[i].real, g_all[i].real, c_all[:, i].real) for i in real]
    if 2 * len(pairs) + len(reals) != n:
        return None  # repeated or defective eigenvalues: leave the model as it is
    model = _Predictor(len(pairs), len(reals), p, m)
    v = np.hstack([y, u])
    burn_in = int(min(max(burn_in, 0), y.shape[0] // 4))

    def residuals(theta: np.ndarray) -> np.ndarray:
        # Trial steps may put a pole outside the unit circle; the overflow just rejects the step.
        with np.errstate(all="ignore"):
            r = (y - model.predict(theta, v, u))[burn_in:].ravel()
        return np.where(np.isfinite(r), r, 1e50)

    def jacobian(theta: np.ndarray) -> np.ndarray:
        with np.errstate(all="ignore"):
            jac = -model.jacobian(theta, v, u, burn_in)
        return np.where(np.isfinite(jac), jac, 0.0)

    theta0 = model.pack(pairs, reals, D)
    cost0 = float(np.sum(residuals(theta0) ** 2))
    theta, cost = _levenberg_marquardt(residuals, jacobian, theta0, max_evaluations)
    if not np.all(np.isfinite(theta)) or cost >= cost0:
        return None
    pairs, reals, D_new = model.unpack(theta)
    # Back to real coordinates: one 2x2 block per pair (states Re xi, Im xi), one state per real pole.
    Abar_r = np.zeros((n, n))
    G_r = np.zeros((n, p + m))
    C_r = np.zeros((p, n))
    pos = 0
    for lam_i, g, c in pairs:
        Abar_r[pos : pos + 2, pos : pos + 2] = [[lam_i.real, -lam_i.imag], [lam_i.imag, lam_i.real]]
        G_r[pos], G_r[pos + 1] = g.real, g.imag
        C_r[:, pos], C_r[:, pos + 1] = 2 * c.real, -2 * c.imag
        pos += 2
    for lam_i, g, c in reals:
        Abar_r[pos, pos] = lam_i
        G_r[pos], C_r[:, pos] = g, c
        pos += 1
    if np.max(np.abs(linalg.eigvals(Abar_r))) >= 1.0:
        return None
    L_new, Bbar_new = G_r[:, :p], G_r[:, p:]
    A_new = Abar_r + L_new @ C_r
    B_new = Bbar_new + L_new @ D_new
    innovations = y - model.predict(theta, v, u)
    used = innovations[burn_in:]
    cov = used.T @ used / used.shape[0]
    n_free = n * (2 * p + m) + p * m
    return PredictorFit(
        A_new, B_new, C_r, D_new, gain_from_predictor(A_new, L_new), np.zeros(n), 0.5 * (cov + cov.T), used, n_free
    )
