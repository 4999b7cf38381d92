"""The Cramer-Rao bound of some modes' frequencies from an output-only record of a known system.

The record's spectrum is ``S(z) = H(z) H(z)^H`` with ``H(z) = I + C (zI - A)^-1 A K`` the true system's steady
Kalman predictor, the outputs whitened by its innovation covariance: the innovation form parametrises every
stationary spectrum of the order. In modal coordinates ``H(z) = I + sum_k c_k g_k^T / (z - lambda_k)``. The
free parameters are, for each mode asked for, its continuous pole ``s`` (real and imaginary part), its output
residue ``c_k`` and its input residue ``g_k`` (complex, one component of ``g_k`` held: the scale ``c g^T``
leaves free); every other mode and the innovation covariance are held at the truth, so the bound is that of
a method told the rest. Whittle's asymptotic information of ``N`` samples::

    I_ij = N / (4 pi) int_{-pi}^{pi} tr(S^-1 dS_i S^-1 dS_j) dw
         = N / (2 pi) int_0^pi [2 Re tr(E_i E_j) + 2 Re tr(E_i E_j^H)] dw,   E_i = H^-1 dH_i.

:func:`independent_modal_forces` gives the same modes, shapes and energies with each mode driven by a force
of its own (the excitation an output-only method assumes) where a record's few point forces drive several
modes coherently.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg

from okid_ros.sim.models import NoisyStateSpace

__all__ = ["ModalPredictor", "frequency_covariance", "independent_modal_forces", "modal_predictor"]


@dataclass
class ModalPredictor:
    """The whitened steady predictor in modal coordinates: poles ``lam`` (n,), ``c`` (p, n), ``g`` (n, p)."""

    lam: np.ndarray
    c: np.ndarray
    g: np.ndarray
    sample_time_s: float

    def upper_by_frequency(self) -> np.ndarray:
        """Indices of the upper-half-plane poles by ``|s|`` (the order of ``system_modes``)."""
        upper = np.flatnonzero(self.lam.imag > 0)
        return upper[np.argsort(np.abs(np.log(self.lam[upper])))]


def modal_predictor(system: NoisyStateSpace) -> ModalPredictor:
    """The steady Kalman predictor of ``system``, outputs whitened, in modal coordinates."""
    inner = system.to_innovation_form()
    whiten = np.linalg.inv(np.linalg.cholesky(inner.innovation_covariance))
    lam, vectors = linalg.eig(inner.A)
    gain = inner.A @ inner.K @ np.linalg.inv(whiten)
    return ModalPredictor(lam, whiten @ inner.C @ vectors, np.linalg.solve(vectors, gain), inner.sample_time_s)


def independent_modal_forces(system: NoisyStateSpace) -> NoisyStateSpace:
    """``system`` with each mode driven by a force of its own: the modal process noise's cross-mode blocks zeroed.

    ``A`` is block diagonal in real modal coordinates, so each mode's own stationary covariance, hence its
    energy in every channel, is the record's; only the coherence of modes that share a force (and the
    forces' direct path to the outputs, ``S``) is gone.
    """
    z, psi = linalg.eig(system.A)
    columns, sizes = [], []
    for i in np.argsort(np.abs(np.log(z))):
        if z[i].imag > 0:
            columns += [psi[:, i].real, psi[:, i].imag]
            sizes.append(2)
        elif z[i].imag == 0:
            columns.append(psi[:, i].real)
            sizes.append(1)
    T = np.column_stack(columns)
    T_inv = np.linalg.inv(T)
    modal = T_inv @ system.process_noise_covariance @ T_inv.T
    own = linalg.block_diag(*[np.ones((k, k)) for k in sizes])
    Q = T @ (modal * own) @ T.T
    return NoisyStateSpace(system.A, system.B, system.C, system.D, (Q + Q.T) / 2,
                           system.measurement_noise_covariance, system.sample_time_s)


def _grid(model: ModalPredictor, free: list[int], *, coarse: int = 800, per_width: int = 5,
          widths: int = 25) -> np.ndarray:
    """Frequencies (rad/sample) in [0, pi]: a uniform grid and a dense one around each free pole."""
    parts = [np.linspace(0.0, np.pi, coarse)]
    for i in free:
        s = np.log(model.lam[i])
        half = max(-s.real, 1e-6)  # the half-power half-width in rad/sample
        parts.append(np.arange(max(s.imag - widths * half, 0.0), min(s.imag + widths * half, np.pi),
                               half / per_width))
    return np.unique(np.concatenate(parts))


def _rank_one_terms(model: ModalPredictor, free: list[int], z: np.ndarray):
    """Each parameter's ``dH`` as rank-one terms ``u w^T`` on the grid ``z``.

    Returns ``U``, ``W`` (F, p, R), ``owner`` (R,) the parameter of each term, and per free mode the column
    of its ``Re s`` and the gradient of its frequency (Hz) in ``(Re s, Im s)``.
    """
    p = model.c.shape[0]
    eye = np.eye(p)
    us, ws, owner, grads = [], [], [], []

    def add(u, w):
        us.append(np.broadcast_to(u, (z.size, p)))
        ws.append(np.broadcast_to(w, (z.size, p)))
        owner.append(owner[-1] + 1 if owner else 0)

    for i in free:
        lam, c, g = model.lam[i], model.c[:, i], model.g[i, :]
        r1, r2 = 1.0 / (z - lam), 1.0 / (z - np.conj(lam))
        s = np.log(lam) / model.sample_time_s
        grads.append((owner[-1] + 1 if owner else 0, np.array([s.real, s.imag]) / (abs(s) * 2 * np.pi)))
        for fac in (1.0, 1j):  # Re s, Im s: the pole and its conjugate, two terms of one parameter
            dl = fac * model.sample_time_s * lam
            add(c[None, :] * (dl * r1 ** 2)[:, None], g)
            us.append(np.conj(c)[None, :] * (np.conj(dl) * r2 ** 2)[:, None])
            ws.append(np.broadcast_to(np.conj(g), (z.size, p)))
            owner.append(owner[-1])
        for fac in (1.0, 1j):  # the output residue's components
            w = (fac * r1)[:, None] * g[None, :] + (np.conj(fac) * r2)[:, None] * np.conj(g)[None, :]
            for k in range(p):
                add(eye[k], w)
        anchor = int(np.argmax(np.abs(g)))
        for fac in (1.0, 1j):  # the input residue's components but the one held
            u = (fac * r1)[:, None] * c[None, :] + (np.conj(fac) * r2)[:, None] * np.conj(c)[None, :]
            for k in range(p):
                if k != anchor:
                    add(u, eye[k])
    return np.stack(us, axis=2), np.stack(ws, axis=2), np.array(owner), grads


def _term_density(model: ModalPredictor, z: np.ndarray, U: np.ndarray, W: np.ndarray) -> np.ndarray:
    """(F, R, R) ``2 Re [tr(E_a E_b) + tr(E_a E_b^H)]`` of the rank-one terms ``E_a = H^-1 u_a w_a^T`` at ``z``."""
    p = model.c.shape[0]
    H = np.eye(p)[None] + np.einsum("pn,fn,nq->fpq", model.c, 1.0 / (z[:, None] - model.lam[None, :]), model.g)
    X = np.linalg.solve(H, U)                            # x_a = H^-1 u_a
    T1 = np.einsum("fpa,fpb->fab", W, X)                 # w_a^T x_b
    G1 = np.einsum("fpa,fpb->fab", W, np.conj(W))        # w_a^T conj(w_b)
    G2 = np.einsum("fpa,fpb->fab", np.conj(X), X)        # x_a^H x_b
    return 2.0 * (T1 * np.swapaxes(T1, 1, 2) + G1 * np.conj(G2)).real


def frequency_covariance(model: ModalPredictor, free: list[int], n_samples: int) -> np.ndarray:
    """(len(free), len(free)) Cramer-Rao covariance of the free modes' frequencies in Hz.

    ``free`` indexes ``model.lam`` (upper-half-plane poles); the record has ``n_samples`` samples.
    """
    omega = _grid(model, free)
    z = np.exp(1j * omega)
    U, W, owner, grads = _rank_one_terms(model, free, z)
    n_par = int(owner[-1]) + 1
    P = np.zeros((owner.size, n_par))
    P[np.arange(owner.size), owner] = 1.0
    weights = np.zeros(omega.size)  # the trapezoidal rule's
    weights[:-1] += np.diff(omega) / 2
    weights[1:] += np.diff(omega) / 2
    info = np.zeros((owner.size, owner.size))
    chunk = max(1, int(2e7 // (owner.size ** 2 * model.c.shape[0] + 1)))
    for a in range(0, omega.size, chunk):
        part = slice(a, a + chunk)
        info += np.einsum("f,fab->ab", weights[part], _term_density(model, z[part], U[part], W[part]))
    info = n_samples / (2 * np.pi) * (P.T @ info @ P)
    scale = np.sqrt(np.diag(info))  # parameters of very different units: invert the correlation form
    cov = np.linalg.pinv(info / np.outer(scale, scale), rcond=1e-12, hermitian=True) / np.outer(scale, scale)
    D = np.zeros((len(free), n_par))
    for k, (column, gradient) in enumerate(grads):
        D[k, column:column + 2] = gradient
    return D @ cov @ D.T
