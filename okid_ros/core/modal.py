"""Modes of an identified model and its normalized real modal form.

Discrete eigenvalues ``z = exp(s dt)`` give continuous poles ``s = ln(z) / dt = -zeta w + i w_d``,
so ``frequency_rad_s = |s|`` (undamped natural frequency) and ``damping_ratio = -Re(s) / |s|``.

Normalized modal form
    One real 2x2 block per complex pair ``z = sigma + i omega`` (``omega > 0``) with eigenvector
    ``psi = a + i b``: in the basis ``[a, b]``

        A_i = [[ sigma, omega],
               [-omega, sigma]]                  (the paper's published blocks have this form).

    ``psi`` is fixed up to a complex factor, which rotates and scales ``[a, b]`` without changing
    ``A_i``. We fix it deterministically so that re-identifying the same structure gives the
    same modal coordinates:

    - rotation: the reference output row ``c_ref`` (row 0 unless that row sees less than 10 % of
      the mode's largest output, then the first row that sees at least 10 %) has
      ``C[c_ref] b = 0`` and ``C[c_ref] a > 0`` (the paper's C has a zero in row 1 at each mode's
      second state);
    - scale: ``||C [a, b]||_F = 1``, so a modal coordinate is in output units (e.g. m/s^2 for
      accelerometers) and its amplitude is the share of the output carried by that mode.

    Physical modes come first, by increasing frequency; the remaining states (real poles and
    non-physical pairs) follow.

Accuracy indicators per mode
    - MPC, modal phase collinearity of the shape ``C psi`` (1: a real normal mode);
    - MSV, modal singular value ``|C psi| |chi B| / sqrt(1 - |z|^2)``, the mode's share of the
      pulse response's energy, reported relative to the largest mode (0..1];
    - EMAC, extended modal amplitude coherence: the mode's residue refitted (poles fixed) to the
      *late* half of a reference Markov sequence (from the ARX model, Eq. 24) compared in amplitude
      and phase with the model's residue (1: the mode keeps decaying as predicted);
    - dominance, the share of the model's frequency response at the mode's own frequency that
      its pole pair makes up, along its output shape (:func:`response_dominance`; about 1 for a
      resonance, small for a broad pole under stronger modes).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg

from okid_ros.core.options import ModeCriteria

__all__ = [
    "LISTED_TWICE_BAND",
    "LISTED_TWICE_MAC",
    "Mode",
    "ModalForm",
    "continuous_poles",
    "modes_listed_once",
    "identify_modes",
    "modal_form",
    "mac",
    "mpc",
    "match_modes",
    "phase_reference_row",
    "response_dominance",
]

#: MPC says something about a shape only with this many outputs (with one it is always 1).
MIN_OUTPUTS_FOR_MPC = 3


@dataclass
class Mode:
    """One vibration mode (a complex-conjugate pole pair) of an identified model."""

    frequency_rad_s: float
    frequency_hz: float
    damping_ratio: float
    eigenvalue: complex
    shape: np.ndarray  # (p,) complex output shape, normalized (unit norm, reference row real > 0)
    mpc: float
    msv: float
    emac: float
    stable: bool
    physical: bool
    id: int = 0
    mac_previous: float = float("nan")
    stability: float = float("nan")  # fraction of neighbouring model orders with the same pole
    extras: dict = field(default_factory=dict)
    # Standard deviations (okid_ros.core.uncertainty); NaN until computed or when not computable.
    frequency_hz_std: float = float("nan")
    damping_ratio_std: float = float("nan")
    dominance: float = float("nan")  # response_dominance; NaN without inputs

    def as_dict(self) -> dict:
        """JSON-ready summary (no complex numbers)."""
        return {
            "id": int(self.id),
            "frequency_rad_s": float(self.frequency_rad_s),
            "frequency_hz": float(self.frequency_hz),
            "damping_ratio": float(self.damping_ratio),
            "mpc": float(self.mpc),
            "msv": float(self.msv),
            "emac": float(self.emac),
            "mac_previous": None if np.isnan(self.mac_previous) else float(self.mac_previous),
            "stability": None if np.isnan(self.stability) else float(self.stability),
            "stable": bool(self.stable),
            "dominance": None if np.isnan(self.dominance) else float(self.dominance),
            "frequency_hz_std": None if np.isnan(self.frequency_hz_std) else float(self.frequency_hz_std),
            "damping_ratio_std": None if np.isnan(self.damping_ratio_std) else float(self.damping_ratio_std),
            "shape_real": [float(x) for x in self.shape.real],
            "shape_imag": [float(x) for x in self.shape.imag],
        }


@dataclass
class ModalForm:
    """A model in normalized real modal form, ``x_modal = T^{-1} x``.

    Attributes
    ----------
    A, B, C, K : transformed matrices (D is unchanged).
    T : (n, n) the transform, ``A_modal = T^{-1} A T``.
    modes : the physical modes, in the order of their blocks.
    n_physical_states : ``2 len(modes)``; states beyond it are non-physical.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    K: np.ndarray
    T: np.ndarray
    modes: list[Mode]
    n_physical_states: int


def continuous_poles(eigenvalues: np.ndarray, sample_time_s: float) -> np.ndarray:
    """``s = ln(z) / dt`` for discrete eigenvalues ``z``."""
    z = np.asarray(eigenvalues, dtype=complex)
    with np.errstate(divide="ignore"):
        return np.log(z) / sample_time_s


def mpc(shape: np.ndarray) -> float:
    """Modal phase collinearity of a complex shape: 1 when all components share one phase."""
    re, im = shape.real, shape.imag
    sxx, syy, sxy = re @ re, im @ im, re @ im
    tr = sxx + syy
    if tr <= 0:
        return 0.0
    disc = np.sqrt(max((sxx - syy) ** 2 + 4 * sxy**2, 0.0))
    return float((disc / tr) ** 2)


def mac(a: np.ndarray, b: np.ndarray) -> float:
    """Modal assurance criterion ``|a^H b|^2 / (|a|^2 |b|^2)`` of two (complex) shapes."""
    den = np.vdot(a, a).real * np.vdot(b, b).real
    if den <= 0:
        return 0.0
    return float(abs(np.vdot(a, b)) ** 2 / den)


def phase_reference_row(c_psi: np.ndarray) -> int:
    """The row a shape ``c_psi`` (p,) is made real at: the first whose magnitude is at least a tenth of the largest."""
    mags = np.abs(c_psi)
    if mags[0] >= 0.1 * mags.max():
        return 0
    return int(np.flatnonzero(mags >= 0.1 * mags.max())[0])


def _emac(
    eigenvalues: np.ndarray, residues: np.ndarray, reference_markov: np.ndarray
) -> np.ndarray:
    """EMAC of each pole from a reference Markov sequence ``Y_j = C A^{j-1} B`` (J, p, m)."""
    n_terms = reference_markov.shape[0]
    j = np.arange(n_terms // 2, n_terms)
    if j.size < eigenvalues.size:
        return np.full(eigenvalues.size, np.nan)
    basis = eigenvalues[None, :] ** (j[:, None] - 1)  # (J/2, n)
    target = reference_markov[j].reshape(j.size, -1)  # (J/2, p m)
    fitted, *_ = linalg.lstsq(basis, target.astype(complex))  # (n, p m)
    out = np.empty(eigenvalues.size)
    for i in range(eigenvalues.size):
        model = residues[i].ravel()
        ref = fitted[i]
        weight = np.abs(model) ** 2
        if weight.sum() <= 0:
            out[i] = 0.0
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.minimum(np.abs(ref) / np.abs(model), np.abs(model) / np.abs(ref))
        ratio = np.nan_to_num(ratio)
        dphase = np.abs(np.angle(ref * np.conj(model)))
        phase_weight = np.clip(1.0 - dphase / (np.pi / 4), 0.0, 1.0)
        out[i] = float(np.sum(weight * ratio * phase_weight) / weight.sum())
    return out


def identify_modes(
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    sample_time_s: float,
    reference_markov: np.ndarray | None = None,
    *,
    criteria: ModeCriteria | None = None,
    eigen: tuple[np.ndarray, np.ndarray] | None = None,
    D: np.ndarray | None = None,
) -> tuple[list[Mode], np.ndarray]:
    """All complex-pair modes of ``A``, with indicators and a physical flag.

    A mode is *physical* if it is stable, its damping ratio is in [0, max_damping), its
    frequency is below ``max_nyquist_fraction`` of Nyquist, its relative MSV is at least
    ``min_msv`` (the input reaches it and the output sees it) and, with at least
    ``MIN_OUTPUTS_FOR_MPC`` outputs, its MPC is at least ``min_mpc``, and with inputs its
    response dominance is at least ``min_dominance`` (criteria of
    :class:`okid_ros.core.options.ModeCriteria`; the stability across model orders is judged
    by :mod:`okid_ros.core.stabilization`).

    Parameters
    ----------
    A : (n, n); B : (n, m); C : (p, n).
    reference_markov : optional (J, p, m) ``Y_j = C A^{j-1} B`` for EMAC (``Y_0 = D`` excluded).
    criteria : the physical-mode criteria (default: :class:`ModeCriteria` defaults).
    eigen : optional ``(eigenvalues (n,), eigenvectors (n, n))`` of ``A`` already computed.
    D : optional (p, m) feedthrough, part of the frequency response the dominance compares with.

    Returns
    -------
    modes : list of Mode sorted by frequency (physical and not).
    eigenvectors : (n, len(modes)) complex eigenvectors ``psi`` of the listed modes, normalized
        as described in the module docstring.
    """
    criteria = ModeCriteria() if criteria is None else criteria
    check_mpc = C.shape[0] >= MIN_OUTPUTS_FOR_MPC
    z, psi = linalg.eig(A) if eigen is None else eigen
    chi = linalg.inv(psi)
    s = continuous_poles(z, sample_time_s)
    nyquist_rad_s = np.pi / sample_time_s
    upper = np.flatnonzero(z.imag > 1e-12 * max(1.0, np.abs(z).max()))
    c_psi = C @ psi
    b_chi = chi @ B
    residues = np.einsum("pi,im->ipm", c_psi, b_chi)
    msv_rel = _relative_msv(z, c_psi, b_chi, upper)
    dominance = response_dominance(z, c_psi, b_chi, upper, D)
    emac = (
        _emac(z, residues, reference_markov)[upper]
        if reference_markov is not None
        else np.full(upper.size, np.nan)
    )
    modes: list[Mode] = []
    vectors = []
    for idx, i in enumerate(upper):
        vec, shape_unit = _normalized_shape(psi[:, i], c_psi[:, i], C)
        w = abs(s[i])
        zeta = -s[i].real / w if w > 0 else 1.0
        stable = bool(abs(z[i]) < 1.0)
        physical = bool(
            stable
            and 0.0 <= zeta < criteria.max_damping
            and w < criteria.max_nyquist_fraction * nyquist_rad_s
            and msv_rel[idx] >= criteria.min_msv
            and (not check_mpc or mpc(shape_unit) >= criteria.min_mpc)
            and not dominance[idx] < criteria.min_dominance  # NaN (no inputs): not judged
        )
        modes.append(Mode(frequency_rad_s=float(w), frequency_hz=float(w / (2 * np.pi)), damping_ratio=float(zeta),
                          eigenvalue=complex(z[i]), shape=shape_unit, mpc=mpc(shape_unit), msv=float(msv_rel[idx]),
                          emac=float(emac[idx]), stable=stable, physical=physical,
                          dominance=float(dominance[idx])))
        vectors.append(vec)
    order = np.argsort([m.frequency_rad_s for m in modes], kind="stable")
    modes = [modes[i] for i in order]
    vecs = np.column_stack([vectors[i] for i in order]) if vectors else np.zeros((A.shape[0], 0), complex)
    return modes, vecs


def response_dominance(z: np.ndarray, c_psi: np.ndarray, b_chi: np.ndarray, upper: np.ndarray,
                       D: np.ndarray | None = None) -> np.ndarray:
    """Share of the frequency response at each pole pair's own frequency that the pair makes up.

    The model's response ``H(w) = D + sum_j c_j b_j^T / (e^{iw} - z_j)`` (``c_j = C psi_j``,
    ``b_j^T = chi_j B``) at the pair's damped frequency ``w = arg z_i``, seen along the pair's unit
    output shape ``s`` and over the inputs: ``|s^H H_i(w)| / |s^H H(w)|``, ``H_i`` the two terms of
    the pair. A resonance dominates the response at its own frequency (about 1; the weaker mode of
    a pair 1.6 % apart measured 0.37-1.0, the tail of its neighbour adding to the response); a
    broad pole under stronger modes does not. The pair's own shape keeps a close mode of another
    shape out. (The output-only selection has its covariance-model counterpart,
    :func:`okid_ros.core.output_only_support.spectral_dominance`.)

    Parameters
    ----------
    z : (n,) eigenvalues; c_psi : (p, n) ``C psi``; b_chi : (n, m) ``chi B``; upper : indices of
    the pairs' upper-half-plane eigenvalues; D : optional (p, m) feedthrough.

    Returns
    -------
    (len(upper),) shares; NaN without inputs (m = 0).
    """
    shares = np.full(upper.size, np.nan)
    if b_chi.shape[1] == 0:
        return shares
    feedthrough = 0.0 if D is None else np.asarray(D, dtype=float)
    for idx, i in enumerate(upper):
        j = int(np.argmin(np.abs(z - np.conj(z[i]))))  # the conjugate partner
        weights = 1.0 / (np.exp(1j * np.angle(z[i])) - z)
        total = (c_psi * weights) @ b_chi + feedthrough  # (p, m)
        own = np.outer(c_psi[:, i], b_chi[i]) * weights[i] + np.outer(c_psi[:, j], b_chi[j]) * weights[j]
        shape = c_psi[:, i] / max(float(np.linalg.norm(c_psi[:, i])), np.finfo(float).tiny)
        seen = float(np.linalg.norm(shape.conj() @ total))
        shares[idx] = float(np.linalg.norm(shape.conj() @ own)) / seen if seen > 0 else 1.0
    return shares


def _relative_msv(z: np.ndarray, c_psi: np.ndarray, b_chi: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Modal singular values of the pairs ``upper``, relative to the largest of a stable pole."""
    msv = np.array([
        np.linalg.norm(c_psi[:, i]) * np.linalg.norm(b_chi[i]) / np.sqrt(max(1 - abs(z[i]) ** 2, 1e-12))
        for i in upper
    ])
    # Relative to the largest *stable* mode: an unstable pole's MSV is unbounded.
    stable_msv = msv[np.abs(z[upper]) < 1.0]
    scale = stable_msv.max() if stable_msv.size and stable_msv.max() > 0 else (msv.max() if msv.size else 1.0)
    return msv / scale if scale > 0 else msv


def _normalized_shape(psi_i: np.ndarray, shape: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The eigenvector rotated to a real reference output and scaled (module docstring), and its unit shape.

    ``shape`` is ``C psi_i`` as computed with the other eigenvectors (the same rounding).
    """
    rot = np.exp(-1j * np.angle(shape[phase_reference_row(shape)]))
    vec = psi_i * rot
    cn = np.linalg.norm(C @ np.column_stack([vec.real, vec.imag]))
    vec = vec / cn if cn > 0 else vec
    shape = C @ vec
    return vec, shape / np.linalg.norm(shape) if np.linalg.norm(shape) > 0 else shape


#: Two listed modes closer than this many of their summed half-power half-widths
#: (``|f1 - f2| < LISTED_TWICE_BAND (zeta1 f1 + zeta2 f2)``) and of one shape (MAC above
#: :data:`LISTED_TWICE_MAC`; always with one output) are one mode listed twice: a mode and a
#: noise pole beside it. Output-only (``bench/output_only.py --cases random``, records 0-359):
#: such twins are 0.27-0.75 apart at MAC >= 0.975 (4 of the 8 spurious modes); the closest true
#: pairs 0.35 apart at MAC 0.906 and, with one output, 1.00 apart; records 360-479, checked once
#: afterwards: 1 of 3 spurious modes removed, no mode lost. Input-output (``identify``'s
#: defaults, random structures 0-359 and the 105 named-case models): the three twins 0.04-0.16
#: apart at MAC >= 0.988; the closest true pairs 0.61 apart at MAC 0.930, the named close pair
#: 0.22-1.26 apart at MAC <= 0.71.
LISTED_TWICE_BAND = 0.85
LISTED_TWICE_MAC = 0.95


def modes_listed_once(modes: list, strengths: list[float], shapes: list[np.ndarray], *,
                      distinct: Callable[[int, int], bool] | None = None) -> list[int]:
    """Indices of the ``modes`` to keep, each mode listed once: of two twins the weaker goes.

    Parameters
    ----------
    modes : (M,) objects with ``frequency_hz`` and ``damping_ratio``; strengths : (M,) how
        strongly each stands out (the stronger twin stays); shapes : (M,) their (p,) complex
        output shapes.
    distinct : ``distinct(i, j)`` True where mode ``i`` and the stronger ``j`` are known to be
        two (never twins, whatever their band and shape); None: no pair is.

    Returns
    -------
    The kept indices, strongest first.
    """
    kept: list[int] = []
    for i in sorted(range(len(modes)), key=lambda j: -strengths[j]):
        a, twin = modes[i], False
        for j in kept:
            b = modes[j]
            band = a.damping_ratio * a.frequency_hz + b.damping_ratio * b.frequency_hz
            if abs(a.frequency_hz - b.frequency_hz) < LISTED_TWICE_BAND * band and not (distinct and distinct(i, j)):
                twin = twin or mac(shapes[i], shapes[j]) > LISTED_TWICE_MAC
        if not twin:
            kept.append(i)
    return kept


def modal_form(
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    K: np.ndarray,
    sample_time_s: float,
    reference_markov: np.ndarray | None = None,
    *,
    criteria: ModeCriteria | None = None,
    stability: Callable[[Mode], float] | None = None,
    steady: Callable[[Mode], bool] | None = None,
    noisy: Callable[[Mode], bool] | None = None,
    once: bool = False,
    D: np.ndarray | None = None,
) -> ModalForm:
    """Transform an innovation-form model to the normalized real modal form.

    ``criteria`` are passed to :func:`identify_modes`. ``stability(mode)`` gives the fraction
    of neighbouring model orders in which the mode is found (:mod:`okid_ros.core.stabilization`;
    NaN: not judged); a physical mode below ``criteria.min_stable_fraction`` is listed as
    non-physical unless ``steady(mode)`` (its pole known precisely from the data); so is one for
    which ``noisy(mode)`` (its pole not placed by the data: a noise pole). ``once``: of two
    physical modes that are one mode listed twice (:func:`modes_listed_once`), the one of smaller
    modal singular value is not physical. ``D`` (p, m),
    the feedthrough, is part of the response the dominance of each mode is judged against.
    """
    n = A.shape[0]
    criteria = ModeCriteria() if criteria is None else criteria
    modes, vecs = identify_modes(A, B, C, sample_time_s, reference_markov, criteria=criteria, D=D)
    if stability is not None:
        for mode in modes:
            if mode.physical:
                mode.stability = float(stability(mode))
                confirmed = not mode.stability < criteria.min_stable_fraction
                mode.physical = confirmed or bool(steady and steady(mode))
    if noisy is not None:
        for mode in modes:
            mode.physical = mode.physical and not noisy(mode)
    if once:
        listed = [m for m in modes if m.physical]
        kept = set(modes_listed_once(listed, [m.msv for m in listed], [m.shape for m in listed]))
        for k, mode in enumerate(listed):
            mode.physical = k in kept
    physical = [i for i, m in enumerate(modes) if m.physical]
    others = [i for i, m in enumerate(modes) if not m.physical]
    columns = []
    for i in physical + others:
        columns += [vecs[:, i].real, vecs[:, i].imag]
    # Real eigenvalues: one state each, scaled like the pairs (unit output norm).
    z, psi = linalg.eig(A)
    real_idx = np.flatnonzero(np.abs(z.imag) <= 1e-12 * max(1.0, np.abs(z).max()))
    for i in real_idx[np.argsort(-z[real_idx].real)]:
        vec = psi[:, i].real
        cn = np.linalg.norm(C @ vec)
        vec = vec / cn if cn > 1e-12 * np.linalg.norm(vec) else vec / np.linalg.norm(vec)
        # Deterministic sign: the largest component of the output (or state) shape positive.
        ref = C @ vec if cn > 0 else vec
        vec = vec * np.sign(ref[np.argmax(np.abs(ref))] or 1.0)
        columns.append(vec)
    T = np.column_stack(columns) if columns else np.zeros((n, 0))
    if T.shape != (n, n) or np.linalg.cond(T) > 1e12:
        # Defective or repeated eigenvalues: fall back to the identity (no modal coordinates).
        T = np.eye(n)
        physical = []
    T_inv = linalg.inv(T)
    A_m = T_inv @ A @ T
    # Clean the numerically zero couplings between blocks so the published A is block diagonal.
    blocks = np.zeros_like(A_m)
    pos = 0
    for i in physical + others:
        blocks[pos : pos + 2, pos : pos + 2] = A_m[pos : pos + 2, pos : pos + 2]
        pos += 2
    blocks[pos:, pos:] = np.diag(np.diag(A_m)[pos:]) if pos < n else blocks[pos:, pos:]
    if np.allclose(blocks, A_m, atol=1e-8 * max(1.0, np.abs(A_m).max())):
        A_m = blocks
    phys_modes = [modes[i] for i in physical]
    return ModalForm(
        A=A_m, B=T_inv @ B, C=C @ T, K=T_inv @ K, T=T, modes=phys_modes, n_physical_states=2 * len(phys_modes)
    )


def match_modes(
    previous: list[Mode],
    current: list[Mode],
    max_frequency_change: float = 0.05,
    min_mac: float = 0.7,
) -> list[int | None]:
    """Match each current mode to a previous one by frequency and MAC.

    A pair qualifies when the relative frequency change is below ``max_frequency_change`` and
    the MAC of the shapes is at least ``min_mac``; pairs are taken greedily by the score
    ``|df/f| / max_frequency_change + (1 - MAC)``, each previous mode used once.

    Returns
    -------
    For each current mode, the index in ``previous`` it continues, or None if it is new.
    """
    candidates = []
    for i, cur in enumerate(current):
        for j, prev in enumerate(previous):
            df = abs(cur.frequency_rad_s - prev.frequency_rad_s) / max(prev.frequency_rad_s, 1e-12)
            if df >= max_frequency_change:
                continue
            m = mac(cur.shape, prev.shape) if cur.shape.size == prev.shape.size else 0.0
            if m < min_mac:
                continue
            candidates.append((df / max_frequency_change + (1.0 - m), i, j, m))
    candidates.sort()
    result: list[int | None] = [None] * len(current)
    used: set[int] = set()
    for _, i, j, _m in candidates:
        if result[i] is None and j not in used:
            result[i] = j
            used.add(j)
    return result
