"""Writes the thesis chain (docs/control.md §1.3, Table 3.2: ma = 2.5 kg,
m1..m7 = 10/7 kg, ka = 1e8 N/m, k = 9.6e7 N/m, ζ = 0.005 on every flexible
mode, the force on ma, the sensor on m5) as a user would bring it, with the
official packages: NumPy's np.savez and SciPy's scipy.io.savemat (MAT level 5,
compressed as MATLAB's default `save` writes it).

- chain_mkd.npz / chain_mkd.mat: the second-order model M, K, D, B, C in
  nodal coordinates (M q'' + D q' + K q = B u, y = C q), D the modal
  damping brought back to nodal coordinates, D = M Φ diag(2 ζ ω) Φᵀ M.
- chain_abcd.npz / chain_abcd.mat: the first-order model in physical
  coordinates x = (q, q'), A = [[0, I], [-M⁻¹K, -M⁻¹D]], B = [0; M⁻¹B],
  C = [C, 0], D = 0, as python-control or MATLAB's ss() would hold it.

usage: write_chain_models.py OUTDIR
"""
import os
import sys

import numpy as np
import scipy.io
import scipy.linalg

ZETA = 0.005


def chain():
    masses = np.array([2.5] + [10.0 / 7.0] * 7)
    springs = np.array([1e8] + [9.6e7] * 6)
    n = len(masses)
    m = np.diag(masses)
    k = np.zeros((n, n))
    for i, s in enumerate(springs):
        k[i, i] += s
        k[i + 1, i + 1] += s
        k[i, i + 1] -= s
        k[i + 1, i] -= s
    b = np.zeros((n, 1))
    b[0, 0] = 1.0
    c = np.zeros((1, n))
    c[0, 5] = 1.0
    # Mass-normalised modes: K Φ = M Φ Ω², Φᵀ M Φ = I.
    w2, phi = scipy.linalg.eigh(k, m)
    omega = np.sqrt(np.clip(w2, 0.0, None))
    modal = np.where(omega > 1e-6 * omega.max(), 2.0 * ZETA * omega, 0.0)
    d = m @ phi @ np.diag(modal) @ phi.T @ m
    d = 0.5 * (d + d.T)
    return m, k, d, b, c


def main(out):
    os.makedirs(out, exist_ok=True)
    m, k, d, b, c = chain()
    second = {"M": m, "K": k, "D": d, "B": b, "C": c}
    np.savez(os.path.join(out, "chain_mkd.npz"), **second)
    scipy.io.savemat(os.path.join(out, "chain_mkd.mat"), second, do_compression=True)
    n = m.shape[0]
    minv = np.linalg.inv(m)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-minv @ k, -minv @ d]])
    first = {
        "A": a,
        "B": np.vstack([np.zeros((n, 1)), minv @ b]),
        "C": np.hstack([c, np.zeros((1, n))]),
        "D": np.zeros((1, 1)),
    }
    np.savez(os.path.join(out, "chain_abcd.npz"), **first)
    scipy.io.savemat(os.path.join(out, "chain_abcd.mat"), first, do_compression=True)


if __name__ == "__main__":
    main(sys.argv[1])
