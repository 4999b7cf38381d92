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
    """Packs and unpacks the parameter vector; evaluates the one-step prediction errors.

    Layout of ``theta``: per pair ``[Re lambda, Im lambda, Re g (w), Im g (w), Re c (p), Im c (p)]``,
    per real pole ``[lambda, g (w), c (p)]``, then ``D`` (p m) row by row. The index arrays of
    that layout are built once, so every evaluation reads the parameters as arrays.
    """

    def __init__(self, n_pairs: int, n_real: int, p: int, m: int):
        self.n_pairs, self.n_real, self.p, self.m = n_pairs, n_real, p, m
        self.w = w = p + m
        pair = n_pairs * (2 + 2 * w + 2 * p)
        start = np.arange(n_pairs) * (2 + 2 * w + 2 * p)
        self._lam = start
        self._g = start[:, None] + 2 + np.arange(w)  # Re g; Im g at + w
        self._c = start[:, None] + 2 + 2 * w + np.arange(p)  # Re c; Im c at + p
        real = pair + np.arange(n_real) * (1 + w + p)
        self._real_lam = real
        self._real_g = real[:, None] + 1 + np.arange(w)
        self._real_c = real[:, None] + 1 + w + np.arange(p)
        self._d = pair + n_real * (1 + w + p) + np.arange(p * m)
        self.size = pair + n_real * (1 + w + p) + p * m
        # Columns of signals(): per pair d xi (2), f (2 w), xi (2); per real pole 1, w, 1; then u (m).
        self._pair_columns = np.arange(n_pairs) * (4 + 2 * w)
        self._real_columns = n_pairs * (4 + 2 * w) + np.arange(n_real) * (2 + w)
        self._input_columns = n_pairs * (4 + 2 * w) + n_real * (2 + w) + np.arange(m)
        self._n_signals = n_pairs * (4 + 2 * w) + n_real * (2 + w) + m
        self._coef_template = self._constant_coefficients()

    def pack(self, pairs, reals, D) -> np.ndarray:
        parts = []
        for lam, g, c in pairs:
            parts += [[lam.real, lam.imag], g.real, g.imag, c.real, c.imag]
        for lam, g, c in reals:
            parts += [[lam], g, c]
        parts.append(D.ravel())
        return np.concatenate([np.ravel(x) for x in parts])

    def unpack(self, theta: np.ndarray):
        lam, g, c, real_lam, real_g, real_c, D = self.arrays(theta)
        pairs = [(complex(lam[i]), g[i], c[i]) for i in range(self.n_pairs)]
        reals = [(float(real_lam[i]), real_g[i].copy(), real_c[i].copy()) for i in range(self.n_real)]
        return pairs, reals, D

    def arrays(self, theta: np.ndarray):
        """The parameters as arrays.

        Returns
        -------
        lam (P,), g (P, w), c (P, p) of the pairs (complex); real_lam (R,), real_g (R, w),
        real_c (R, p) of the real poles; D (p, m).
        """
        w, p = self.w, self.p
        lam = theta[self._lam] + 1j * theta[self._lam + 1]
        g = theta[self._g] + 1j * theta[self._g + w]
        c = theta[self._c] + 1j * theta[self._c + p]
        return (lam, g, c, theta[self._real_lam], theta[self._real_g], theta[self._real_c],
                theta[self._d].reshape(p, self.m))

    def radius(self, theta: np.ndarray) -> float:
        """Spectral radius of the predictor ``Abar``: its eigenvalues are the parameters ``lambda``."""
        lam, _, _, real_lam, _, _, _ = self.arrays(theta)
        return float(max(np.max(np.abs(lam), initial=0.0), np.max(np.abs(real_lam), initial=0.0)))

    def _constant_coefficients(self) -> np.ndarray:
        """The entries of ``coefficients`` that do not depend on ``theta``: those of ``c`` and ``D``."""
        p, m, w = self.p, self.m, self.w
        pair, real, inputs = self._pair_columns, self._real_columns, self._input_columns
        coef = np.zeros((p, self._n_signals, self.size))
        outputs = np.arange(p)
        for i in range(self.n_pairs):  # 2 Re(c xi) = 2 Re c Re xi - 2 Im c Im xi
            xi = pair[i] + 2 + 2 * w
            coef[outputs, xi, self._c[i]] = 2.0
            coef[outputs, xi + 1, self._c[i] + p] = -2.0
        for i in range(self.n_real):
            coef[outputs, real[i] + 1 + w, self._real_c[i]] = 1.0
        for k in range(p):
            coef[k, inputs, self._d[k * m : (k + 1) * m]] = 1.0
        return coef

    def signals(self, theta: np.ndarray, v: np.ndarray, u: np.ndarray, burn_in: int
                ) -> tuple[np.ndarray, np.ndarray]:
        """The Jacobian in factored form: ``d yhat[k, out] / d theta = signals[k] @ coefficients[out]``.

        With ``f_j = z^-1 / (1 - lambda z^-1) v_j`` and ``xi = sum_j g_j f_j``:
        ``d xi / d lambda = z^-1 / (1 - lambda z^-1) xi``, ``d xi / d g_j = f_j``; a pair's
        real parameters enter through ``2 Re(c xi)`` (an imaginary part through ``-2 Im``).
        Every column of the Jacobian is a combination of the real and imaginary parts of these
        filtered signals weighted by one output's ``c``, so ``J^T J`` follows from the Gram of
        the signals (N' s^2 flops, s about the parameters per output) instead of the tall
        Jacobian's (N' p P^2).

        ``f`` of a pair is run as one real all-pole filter of the real ``v``, ``q = v / ((1 -
        lambda z^-1)(1 - conj(lambda) z^-1))``, then ``f = z^-1 (1 - conj(lambda) z^-1) q``: the
        same signal as the complex first-order filter, at a third of its cost (scipy's
        ``lfilter`` has no batch of filters with different coefficients). The difference of
        ``q`` terms loses digits only for a predictor pole very near the unit circle (about
        ``-2 log10(1 - |lambda|)``), which a Jacobian can spare; the cost itself
        (:meth:`predict`) keeps the first-order filter.

        Returns
        -------
        signals : (N', s) real, rows ``burn_in:``; coefficients : (p, s, len(theta)).
        """
        lam, g, c, real_lam, real_g, real_c, _ = self.arrays(theta)
        w, n = self.w, v.shape[0]
        pair, real, inputs = self._pair_columns, self._real_columns, self._input_columns
        # Rows of the transpose are the signals: contiguous writes, and the Gram is as fast.
        sig = np.empty((self._n_signals, n - burn_in))
        coef = self._coef_template.copy()
        v_rows = np.ascontiguousarray(v.T)  # (w, N)
        for i in range(self.n_pairs):
            re, im = lam[i].real, lam[i].imag
            q = signal.lfilter([1.0], [1.0, -2.0 * re, re * re + im * im], v_rows, axis=-1)
            f_re = np.zeros_like(q)  # f = z^-1 (1 - conj(lambda) z^-1) q
            f_re[:, 1:] = q[:, :-1]
            f_re[:, 2:] -= re * q[:, :-2]
            f_im = np.zeros_like(q)
            f_im[:, 2:] = im * q[:, :-2]
            xi = (g[i].real @ f_re - g[i].imag @ f_im) + 1j * (g[i].imag @ f_re + g[i].real @ f_im)
            dxi = signal.lfilter([0.0, 1.0], [1.0, -lam[i]], xi)
            s = pair[i]
            sig[s], sig[s + 1] = dxi.real[burn_in:], dxi.imag[burn_in:]
            sig[s + 2 : s + 2 + w], sig[s + 2 + w : s + 2 + 2 * w] = f_re[:, burn_in:], f_im[:, burn_in:]
            sig[s + 2 + 2 * w], sig[s + 3 + 2 * w] = xi.real[burn_in:], xi.imag[burn_in:]
        self._pair_coefficients(coef, c, pair)
        for i in range(self.n_real):
            f = signal.lfilter([0.0, 1.0], [1.0, -real_lam[i]], v_rows, axis=-1)
            xi = real_g[i] @ f
            dxi = signal.lfilter([0.0, 1.0], [1.0, -real_lam[i]], xi)
            s = real[i]
            sig[s], sig[s + 1 : s + 1 + w], sig[s + 1 + w] = dxi[burn_in:], f[:, burn_in:], xi[burn_in:]
            coef[:, s, self._real_lam[i]] = real_c[i]
            coef[:, s + 1 + np.arange(w), self._real_g[i]] = real_c[i][:, None]
        sig[inputs] = u[burn_in:].T
        return sig.T, coef

    def _pair_coefficients(self, coef: np.ndarray, c: np.ndarray, pair: np.ndarray) -> None:
        """The pairs' ``c``-dependent entries of ``coefficients`` (in place), all pairs at once.

        ``2 Re(c s) = 2 Re c Re s - 2 Im c Im s`` and ``-2 Im(c s) = -2 Re c Im s - 2 Im c Re s``
        for ``s`` each pair's ``d xi`` (parameters ``lambda``) and ``f_j`` (parameters ``g_j``).
        """
        if not self.n_pairs:
            return
        w = self.w
        cr, ci = 2.0 * c.real.T, 2.0 * c.imag.T  # (p, P)
        lam, dxi = self._lam, pair
        coef[:, dxi, lam], coef[:, dxi + 1, lam] = cr, -ci
        coef[:, dxi + 1, lam + 1], coef[:, dxi, lam + 1] = -cr, -ci
        f_re = pair[:, None] + 2 + np.arange(w)  # (P, w)
        f_im, g_re, g_im = f_re + w, self._g, self._g + w
        cr, ci = cr[:, :, None], ci[:, :, None]
        coef[:, f_re, g_re], coef[:, f_im, g_re] = cr, -ci
        coef[:, f_im, g_im], coef[:, f_re, g_im] = -cr, -ci

    def jacobian(self, theta: np.ndarray, v: np.ndarray, u: np.ndarray, burn_in: int) -> np.ndarray:
        """D yhat / d theta, (N' p, len(theta)), rows ordered like ``yhat[burn_in:].ravel()``."""
        sig, coef = self.signals(theta, v, u, burn_in)
        return np.einsum("ks,osj->koj", sig, coef).reshape(sig.shape[0] * self.p, theta.size)

    def predict(self, theta: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        lam, g, c, real_lam, real_g, real_c, D = self.arrays(theta)
        y_hat = u @ D.T
        if self.n_pairs:
            drive = g @ v.T  # (P, N)
            xi = np.empty_like(drive)
            for i in range(self.n_pairs):
                xi[i] = signal.lfilter([0.0, 1.0], [1.0, -lam[i]], drive[i])
            y_hat += 2.0 * (xi.T @ c).real
        if self.n_real:
            drive = real_g @ v.T  # (R, N)
            for i in range(self.n_real):
                drive[i] = signal.lfilter([0.0, 1.0], [1.0, -real_lam[i]], drive[i])
            y_hat += drive.T @ real_c
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
        if not _stable(*_to_real(self.predictor, theta)[:3], self.radii,
                       predictor_radius=self.predictor.radius(theta)):
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
            gram = sig.T @ sig
            if not np.all(np.isfinite(np.diag(gram))):  # a signal holds Inf or NaN: zeroed there
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
    lam, g, c, real_lam, real_g, real_c, D = predictor.arrays(theta)
    p, n_pairs = predictor.p, predictor.n_pairs
    n = 2 * n_pairs + predictor.n_real
    Abar = np.zeros((n, n))
    first, second = np.arange(0, 2 * n_pairs, 2), np.arange(1, 2 * n_pairs, 2)
    Abar[first, first], Abar[first, second] = lam.real, -lam.imag
    Abar[second, first], Abar[second, second] = lam.imag, lam.real
    reals = np.arange(2 * n_pairs, n)
    Abar[reals, reals] = real_lam
    G = np.empty((n, predictor.w))
    G[first], G[second], G[reals] = g.real, g.imag, real_g
    C = np.empty((p, n))
    C[:, first], C[:, second], C[:, reals] = 2 * c.real.T, -2 * c.imag.T, real_c.T
    return Abar, G[:, :p], C, G[:, p:], D


def _stable(Abar: np.ndarray, L: np.ndarray, C: np.ndarray, radii: tuple[float, float], *,
            predictor_radius: float | None = None) -> bool:
    """``A = Abar + L C`` inside ``radii[0]`` and the predictor ``Abar`` inside ``radii[1]``.

    ``predictor_radius``: ``Abar``'s spectral radius when known (:meth:`_Predictor.radius`).
    """
    with np.errstate(all="ignore"):
        if not (np.all(np.isfinite(Abar)) and np.all(np.isfinite(L)) and np.all(np.isfinite(C))):
            return False
        radius = spectral_radius(Abar) if predictor_radius is None else predictor_radius
        return radius < radii[1] and spectral_radius(Abar + L @ C) < radii[0]
