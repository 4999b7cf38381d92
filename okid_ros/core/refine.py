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
milliseconds, and the Jacobian is analytic (one more filter per pole). The first ``burn_in``
samples, where the unknown initial predictor state still
matters, are left out of the cost (optionally, the last ``validation_fraction`` of the record is
held out and the iterate that predicts it best is kept). The result is mapped back to the real modal block form, and
``A = Abar + L C``, ``B = Bbar + L D``, ``K = A^{-1} L``.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import linalg, signal

from okid_ros.core.refit import PredictorFit, gain_from_predictor, innovation_covariance
from okid_ros.core.statespace import InnovationModel, free_parameters, spectral_radius, split_poles

__all__ = ["refine_prediction_error", "refinement_flops", "refinement_size"]


def refinement_size(n_states: int, n_outputs: int, n_inputs: int) -> int:
    """Number of real parameters the refinement adjusts (upper bound, all poles complex)."""
    w = n_outputs + n_inputs
    return n_states * (1 + w + n_outputs) + n_outputs * n_inputs


def refinement_flops(n_states: int, n_outputs: int, n_inputs: int, n_samples: int) -> float:
    """Flops of one Levenberg-Marquardt iteration (upper bound, all poles complex).

    The Gram of the filtered signals (``N s^2``, ``s`` signals), the normal equations assembled
    from it per output and their solution (:meth:`_Objective.normal`); the Jacobian itself is
    never formed.
    """
    p, m = n_outputs, n_inputs
    n_par = refinement_size(n_states, p, m)
    s = n_states * (2 + p + m) + m
    return 2.0 * n_samples * s * s + 2.0 * p * (n_par * s * s + s * n_par * n_par) + n_par**3 / 3.0


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

    def signals(self, theta: np.ndarray, v: np.ndarray, u: np.ndarray, burn_in: int
                ) -> tuple[np.ndarray, np.ndarray]:
        """The Jacobian in factored form: ``d yhat[k, out] / d theta = signals[k] @ coefficients[out]``.

        With ``f_j = z^-1 / (1 - lambda z^-1) v_j`` and ``xi = sum_j g_j f_j``:
        ``d xi / d lambda = z^-2 / (1 - lambda z^-1)^2 (v g)``, ``d xi / d g_j = f_j``; a pair's
        real parameters enter through ``2 Re(c xi)`` (an imaginary part through ``-2 Im``).
        Every column of the Jacobian is a combination of the real and imaginary parts of these
        filtered signals weighted by one output's ``c``, so ``J^T J`` follows from the Gram of
        the signals (N' s^2 flops, s about the parameters per output) instead of the tall
        Jacobian's (N' p P^2).

        Returns
        -------
        signals : (N', s) real, rows ``burn_in:``; coefficients : (p, s, len(theta)).
        """
        pairs, reals, _ = self.unpack(theta)
        p, m, w = self.p, self.m, self.w
        n_rows = v.shape[0] - burn_in
        n_sig = len(pairs) * (4 + 2 * w) + len(reals) * (2 + w) + m
        sig = np.empty((n_rows, n_sig))
        coef = np.zeros((p, n_sig, theta.size))
        outputs = np.arange(p)
        col = s = 0
        for lam, g, c in pairs:
            f = signal.lfilter([0.0, 1.0], [1.0, -lam], v, axis=0)[burn_in:]  # (N', w)
            dxi = signal.lfilter([0.0, 0.0, 1.0], [1.0, -2.0 * lam, lam * lam], v @ g)[burn_in:]
            xi = f @ g
            sig[:, s], sig[:, s + 1] = dxi.real, dxi.imag
            sig[:, s + 2 : s + 2 + w], sig[:, s + 2 + w : s + 2 + 2 * w] = f.real, f.imag
            sig[:, s + 2 + 2 * w], sig[:, s + 3 + 2 * w] = xi.real, xi.imag
            cr, ci = 2.0 * c.real, 2.0 * c.imag
            # 2 Re(c s) = 2 cr Re s - 2 ci Im s;  -2 Im(c s) = -2 cr Im s - 2 ci Re s
            coef[:, s, col], coef[:, s + 1, col] = cr, -ci
            coef[:, s + 1, col + 1], coef[:, s, col + 1] = -cr, -ci
            for j in range(w):
                re_s, im_s = s + 2 + j, s + 2 + w + j
                coef[:, re_s, col + 2 + j], coef[:, im_s, col + 2 + j] = cr, -ci
                coef[:, im_s, col + 2 + w + j], coef[:, re_s, col + 2 + w + j] = -cr, -ci
            start = col + 2 + 2 * w
            coef[outputs, s + 2 + 2 * w, start + outputs] = 2.0
            coef[outputs, s + 3 + 2 * w, start + p + outputs] = -2.0
            col, s = start + 2 * p, s + 4 + 2 * w
        for lam, g, c in reals:
            f = signal.lfilter([0.0, 1.0], [1.0, -lam], v, axis=0)[burn_in:]
            dxi = signal.lfilter([0.0, 0.0, 1.0], [1.0, -2.0 * lam, lam * lam], v @ g)[burn_in:]
            sig[:, s], sig[:, s + 1 : s + 1 + w], sig[:, s + 1 + w] = dxi, f, f @ g
            coef[:, s, col] = c
            for j in range(w):
                coef[:, s + 1 + j, col + 1 + j] = c
            start = col + 1 + w
            coef[outputs, s + 1 + w, start + outputs] = 1.0
            col, s = start + p, s + 2 + w
        sig[:, s:] = u[burn_in:]
        for k in range(p):
            coef[k, s + np.arange(m), col + k * m + np.arange(m)] = 1.0
        return sig, coef

    def jacobian(self, theta: np.ndarray, v: np.ndarray, u: np.ndarray, burn_in: int) -> np.ndarray:
        """D yhat / d theta, (N' p, len(theta)), rows ordered like ``yhat[burn_in:].ravel()``."""
        sig, coef = self.signals(theta, v, u, burn_in)
        return np.einsum("ks,osj->koj", sig, coef).reshape(sig.shape[0] * self.p, theta.size)

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


def _levenberg_marquardt(
    residuals, normal, theta: np.ndarray, max_evaluations: int, *, on_accept=None
) -> tuple[np.ndarray, float]:
    """Minimize ``||residuals(theta)||^2`` by Levenberg-Marquardt with Marquardt's diagonal scaling.

    Solves the small normal equations ``(J^T J + mu diag(J^T J)) dx = -J^T r`` instead of an SVD
    of the tall Jacobian: the parameters are tens, the residuals thousands. ``normal(theta, r)``
    gives ``(J^T J, J^T r)`` of the residuals' Jacobian ``J``. ``on_accept(theta)`` is called
    after every accepted step.
    """
    r = residuals(theta)
    cost = float(r @ r)
    mu = 1e-3
    evaluations = 1
    while evaluations < max_evaluations:
        H, g = normal(theta, r)
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
                if on_accept is not None:
                    on_accept(theta)
                mu = max(mu / 3.0, 1e-9)
                break
            mu *= 4.0
            if mu > 1e8:
                return theta, cost
        if not improved:
            break
    return theta, cost


def refine_prediction_error(
    model: InnovationModel,
    u: np.ndarray,
    y: np.ndarray,
    *,
    burn_in: int = 100,
    max_evaluations: int = 40,
    max_radius: float = 1.0,
    validation_fraction: float = 0.0,
) -> PredictorFit | None:
    """Refine a model by minimizing its one-step prediction errors on ``u``, ``y``.

    Parameters
    ----------
    model : the starting innovation model (paper convention, predictor gain ``A K``).
    u : (N, m); y : (N, p) the identification record.
    burn_in : samples excluded from the cost at the start.
    max_evaluations : cap on residual evaluations of the optimizer (the Jacobian is analytic).
    max_radius : a step that puts an eigenvalue of ``A`` at or beyond this modulus is
        rejected, and so is a step that takes the predictor's spectral radius more than half way
        from its start to 1: the result keeps a stable model and a well-damped predictor (a
        refinement that drove the predictor to 0.99997 fitted the record better and predicted
        new data 2.4 times worse than the oracle on the more-outputs benchmark case).
    validation_fraction : the last part of the record held out of the fit; the iterate that
        predicts it best is returned, and only if it predicts it better than the start (0: fit
        all samples and return the last iterate if it lowers the cost).

    Returns
    -------
    The refined fit (in real modal block coordinates), or None if the refinement did not
    improve the held-out prediction (then keep the starting model).
    """
    start = _diagonal_parameters(model)
    if start is None:
        return None
    predictor, theta0, start_radius = start
    radii = (max_radius, min(max_radius, start_radius + 0.5 * (1.0 - start_radius)))
    burn_in = int(min(max(burn_in, 0), y.shape[0] // 4))
    # Optionally the last part of the record is held out: the optimizer fits the rest, and the
    # step kept is the one that predicts the held-out part best (early stopping against
    # overfitting). Off by default: over 5 seeds of the benchmark cases it cost more accuracy
    # (fewer samples fitted) than it saved (docs/method.md).
    split = burn_in + int((y.shape[0] - burn_in) * (1.0 - validation_fraction))
    objective = _Objective(predictor, u, y, burn_in, split, radii)
    if split < y.shape[0]:
        theta = _early_stopped(objective, theta0, max_evaluations)
    else:
        theta, cost = _levenberg_marquardt(objective.residuals, objective.normal, theta0, max_evaluations)
        if not cost < objective.cost(theta0):
            theta = None
    if theta is None or not np.all(np.isfinite(theta)):
        return None
    return _fit_of(predictor, theta, u, y, burn_in, radii)


def _diagonal_parameters(model: InnovationModel) -> tuple[_Predictor, np.ndarray, float] | None:
    """The model's predictor in complex-diagonal coordinates, its parameter vector and radius.

    None when the predictor is unstable or its eigenvalues are repeated or defective (the model
    is then left as it is).
    """
    A, B, C, D, K = model.A, model.B, model.C, model.D, model.K
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
    upper, real = split_poles(lam)
    pairs = [(lam[i], g_all[i], c_all[:, i]) for i in upper]
    reals = [(lam[i].real, g_all[i].real, c_all[:, i].real) for i in real]
    if 2 * len(pairs) + len(reals) != n:
        return None
    predictor = _Predictor(len(pairs), len(reals), p, m)
    return predictor, predictor.pack(pairs, reals, D), float(np.max(np.abs(lam)))


class _Objective:
    """One-step prediction errors of a parameter vector.

    Rows ``burn_in:split`` are fitted,
    rows ``split:`` held out; a parameter vector with an unstable ``A`` or predictor costs 1e50.
    """

    def __init__(self, predictor: _Predictor, u: np.ndarray, y: np.ndarray, burn_in: int, split: int,
                 radii: tuple[float, float]) -> None:
        self.predictor, self.u, self.y = predictor, u, y
        self.v = np.hstack([y, u])
        self.burn_in, self.split, self.radii = burn_in, split, radii
        self.n_fitted = (split - burn_in) * y.shape[1]

    def errors(self, theta: np.ndarray) -> np.ndarray | None:
        """(N, p) one-step prediction errors, None if A or the predictor is unstable."""
        if not _stable(*_to_real(self.predictor, theta)[:3], self.radii):
            return None
        with np.errstate(all="ignore"):
            e = self.y - self.predictor.predict(theta, self.v, self.u)
        return e if np.all(np.isfinite(e[self.burn_in :])) else None

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        e = self.errors(theta)
        return np.full(self.n_fitted, 1e50) if e is None else e[self.burn_in : self.split].ravel()

    def cost(self, theta: np.ndarray) -> float:
        r = self.residuals(theta)
        return float(r @ r)

    def normal(self, theta: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(J^T J, J^T r)`` of the residuals' Jacobian ``J = -d yhat / d theta`` (fitted rows).

        From the Gram of the filtered signals (:meth:`_Predictor.signals`), never the tall ``J``.
        """
        p = self.predictor.p
        with np.errstate(all="ignore"):
            sig, coef = self.predictor.signals(theta, self.v, self.u, self.burn_in)
            sig = sig[: self.n_fitted // p]
            if not np.all(np.isfinite(sig)):
                sig = np.where(np.isfinite(sig), sig, 0.0)
            gram = sig.T @ sig
            cross = sig.T @ r.reshape(-1, p)  # (s, p)
            H = sum(coef[k].T @ gram @ coef[k] for k in range(p))
            g = -sum(coef[k].T @ cross[:, k] for k in range(p))
        return H, g

    def held_out_cost(self, theta: np.ndarray) -> float:
        e = self.errors(theta)
        return np.inf if e is None else float(np.sum(e[self.split :] ** 2))


def _early_stopped(objective: _Objective, theta0: np.ndarray, max_evaluations: int) -> np.ndarray | None:
    """The optimizer's iterate that predicts the held-out rows best, if better than the start."""
    best = [theta0, objective.held_out_cost(theta0)]
    start_cost = best[1]

    def on_accept(theta: np.ndarray) -> None:
        cost = objective.held_out_cost(theta)
        if cost < best[1]:
            best[0], best[1] = theta.copy(), cost

    _levenberg_marquardt(objective.residuals, objective.normal, theta0, max_evaluations, on_accept=on_accept)
    return best[0] if best[1] < start_cost else None


def _fit_of(predictor: _Predictor, theta: np.ndarray, u: np.ndarray, y: np.ndarray, burn_in: int,
            radii: tuple[float, float]) -> PredictorFit | None:
    """The innovation model of a parameter vector (real modal blocks) with its fit statistics."""
    Abar, L, C, Bbar, D = _to_real(predictor, theta)
    if not _stable(Abar, L, C, radii):
        return None
    A = Abar + L @ C
    B = Bbar + L @ D
    innovations = (y - predictor.predict(theta, np.hstack([y, u]), u))[burn_in:]
    refined = InnovationModel(A, B, C, D, gain_from_predictor(A, L), innovation_covariance(innovations))
    n, p, m = A.shape[0], C.shape[0], B.shape[1]
    return PredictorFit(refined, np.zeros(n), innovations, free_parameters(n, p, m))


def _to_real(predictor: _Predictor, theta: np.ndarray):
    """``(Abar, L, C, Bbar, D)`` in real coordinates: a 2x2 block per pair, one state per real pole."""
    pairs, reals, D = predictor.unpack(theta)
    p, m = predictor.p, predictor.m
    n = 2 * len(pairs) + len(reals)
    Abar = np.zeros((n, n))
    G = np.zeros((n, p + m))
    C = np.zeros((p, n))
    pos = 0
    for lam_i, g, c in pairs:
        Abar[pos : pos + 2, pos : pos + 2] = [[lam_i.real, -lam_i.imag], [lam_i.imag, lam_i.real]]
        G[pos], G[pos + 1] = g.real, g.imag
        C[:, pos], C[:, pos + 1] = 2 * c.real, -2 * c.imag
        pos += 2
    for lam_i, g, c in reals:
        Abar[pos, pos] = lam_i
        G[pos], C[:, pos] = g, c
        pos += 1
    return Abar, G[:, :p], C, G[:, p:], D


def _stable(Abar: np.ndarray, L: np.ndarray, C: np.ndarray, radii: tuple[float, float]) -> bool:
    """``A = Abar + L C`` inside ``radii[0]`` and the predictor ``Abar`` inside ``radii[1]``."""
    with np.errstate(all="ignore"):
        if not (np.all(np.isfinite(Abar)) and np.all(np.isfinite(L)) and np.all(np.isfinite(C))):
            return False
        return spectral_radius(Abar) < radii[1] and spectral_radius(Abar + L @ C) < radii[0]
