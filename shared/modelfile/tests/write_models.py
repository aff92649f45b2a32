"""Writes model files with the official writers, for tests/official_writers.rs.

Usage: python write_models.py OUT_DIR

NumPy's np.savez (and np.savez_compressed) and SciPy's scipy.io.savemat write
the files; the arrays are the ones official_writers.rs expects, entry for
entry. A MATLAB `save plant.mat A B C D` writes a level-5 file with
zlib-compressed elements, which is what savemat(do_compression=True) writes.
"""

import sys
from pathlib import Path

import numpy as np
import scipy.io
import scipy.sparse


def second_order():
    """A 3-mass chain: M, K, D (2-D), B a column, C a row, as a user writes them."""
    m = np.diag([1.5, 0.25, 2.0])
    k = np.array([[3.0e4, -3.0e4, 0.0], [-3.0e4, 5.0e4, -2.0e4], [0.0, -2.0e4, 2.0e4]])
    d = 1e-3 * k + np.diag([0.1, 0.2, 0.3])
    b = np.array([[1.0], [0.0], [-1.0 / 3.0]])
    c = np.array([[0.0, 0.1, 1.0 / 7.0]])
    return {"M": m, "K": k, "D": d, "B": b, "C": c}


def state_space():
    """First order A, B, C, D with a sample time `ts`; B and C saved as 1-D vectors."""
    a = np.array([[0.0, 1.0], [-4.0e3, -0.7]])
    b = np.array([0.0, 2.5])
    c = np.array([1.0, 1e-300])
    d = np.array([[0.0]])
    return {"A": a, "B": b, "C": c, "D": d, "ts": 1e-4}


def main():
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)

    second = second_order()
    ss = state_space()

    np.savez(out / "second_order.npz", **second)
    np.savez_compressed(out / "second_order_compressed.npz", **second)
    np.savez(out / "state_space.npz", **ss)
    # A MAT-file's variables handed on through scipy.io.loadmat, which adds
    # __header__, __version__ and __globals__: not arrays of the model.
    scipy.io.savemat(out / "via_loadmat.mat", second)
    np.savez(out / "via_loadmat.npz", **scipy.io.loadmat(out / "via_loadmat.mat"))
    (out / "via_loadmat.mat").unlink()
    # A Fortran-ordered array (fortran_order: True in the .npy header), an
    # integer array and a boolean array: read as numbers.
    np.savez(
        out / "layouts.npz",
        F=np.asfortranarray(np.arange(12.0).reshape(3, 4) + 0.5),
        I=np.array([[1, -2, 3], [4, 5, -6]], dtype=np.int32),
        U=np.array([7, 8], dtype=np.uint8),
        L=np.array([True, False, True]),
        S=np.float32(0.25),
    )
    # Refused: complex and text arrays, each naming the array.
    np.savez(out / "complex.npz", Z=np.array([[1.0 + 2.0j]]))
    np.savez(out / "text.npz", T=np.array(["M", "K"]))

    for fmt_name, compress in (("plain", False), ("compressed", True)):
        scipy.io.savemat(out / f"second_order_{fmt_name}.mat", second, format="5",
                         do_compression=compress)
        scipy.io.savemat(out / f"state_space_{fmt_name}.mat", ss, format="5",
                         do_compression=compress)
    scipy.io.savemat(
        out / "layouts.mat",
        {
            "I": np.array([[1, -2, 3], [4, 5, -6]], dtype=np.int32),
            "U": np.array([7, 8], dtype=np.uint8),
            "L": np.array([[True, False, True]]),
            "S": np.float32(0.25),
        },
        do_compression=True,
    )
    # Refused, each naming the array.
    scipy.io.savemat(out / "complex.mat", {"Z": np.array([[1.0 + 2.0j]])})
    scipy.io.savemat(out / "sparse.mat", {"K": scipy.sparse.csc_matrix(np.eye(2))})
    scipy.io.savemat(out / "text.mat", {"T": "M K"})
    scipy.io.savemat(out / "cell.mat", {"X": np.array([np.eye(2), np.ones(3)], dtype=object)})
    scipy.io.savemat(out / "struct.mat", {"P": {"M": np.eye(2)}})
    # Level 4 (save -v4): refused with the instruction to save with -v7.
    scipy.io.savemat(out / "level4.mat", {"A": np.eye(2)}, format="4")


if __name__ == "__main__":
    main()
