"""An independent, slow float64 NumPy GRT: a direct loop over frequencies with the exact
bistatic range and the exact 1/R_b² factor (or the bistatic radar equation's 1/(r_t r_r)).
Written from the paper's equations only."""

from __future__ import annotations

import numpy as np

C0 = 299_792_458.0


def antenna_positions(distance, spacing, n_tx, n_rx, azimuth, polar):
    a, p = float(azimuth), float(polar)
    centre = distance * np.array([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)])
    u_t = np.array([-np.cos(p) * np.cos(a), -np.cos(p) * np.sin(a), np.sin(p)])
    u_r = np.array([-np.sin(a), np.cos(a), 0.0])
    tx = np.array([centre + spacing * (m + 0.5) * u_t for m in range(n_tx)])
    rx = np.array([centre + spacing * (n + 0.5) * u_r for n in range(n_rx)])
    return tx, rx


def _amplitude(r_t, r_r, near_field, spreading):
    r_b = r_t[:, :, None] + r_r[:, None, :]  # (V, n_tx, n_rx)
    if not near_field:
        return r_b, np.ones_like(r_b)
    if spreading == "radar-equation":
        return r_b, 1.0 / (r_t[:, :, None] * r_r[:, None, :])
    return r_b, 1.0 / r_b**2


def forward(points, rho, tx, rx, frequencies, near_field=True, spreading="paper"):
    points = np.asarray(points, np.float64)
    rho = np.asarray(rho, np.complex128)
    r_t = np.linalg.norm(points[:, None, :] - np.asarray(tx, np.float64)[None], axis=-1)
    r_r = np.linalg.norm(points[:, None, :] - np.asarray(rx, np.float64)[None], axis=-1)
    r_b, amplitude = _amplitude(r_t, r_r, near_field, spreading)
    out = np.empty((len(frequencies), tx.shape[0], rx.shape[0]), np.complex128)
    for i, f in enumerate(np.asarray(frequencies, np.float64)):
        k = 2 * np.pi * f / C0
        out[i] = np.einsum("v,vmn->mn", rho, amplitude * np.exp(1j * k * r_b))
    return out


def adjoint(points, signal, tx, rx, frequencies, near_field=True, spreading="paper"):
    points = np.asarray(points, np.float64)
    r_t = np.linalg.norm(points[:, None, :] - np.asarray(tx, np.float64)[None], axis=-1)
    r_r = np.linalg.norm(points[:, None, :] - np.asarray(rx, np.float64)[None], axis=-1)
    r_b, amplitude = _amplitude(r_t, r_r, near_field, spreading)
    out = np.zeros(points.shape[0], np.complex128)
    for i, f in enumerate(np.asarray(frequencies, np.float64)):
        k = 2 * np.pi * f / C0
        out += np.einsum("vmn,mn->v", np.conj(amplitude * np.exp(1j * k * r_b)), signal[i])
    return out
