#!/usr/bin/env python3
"""Writes the 2-DOF serial flexible joint of the IO-observer experiment
(Adams & Forbes; docs/control.md §12.2) as `second-order` plant files,
scenarios/flexible-joint/k<NNN>.npz: the nominal joint (k100) and the
population of four link-stiffness configurations spanning ±20 % (k080, k093,
k107, k120), NNN the stiffness in per cent of nominal.

Coordinates q = [θ1, α1, θ2, α2] (hub angles and link deflections, rad), the
paper's states. The paper gives the structure, not the numbers; these are
INVENTED, the same as flexloop-control's `models::flexible_joint` (which
writes them in absolute link angles): hub inertias 2e-3 and 1e-3 kg m², link
inertias 3.5e-3 and 1.5e-3 kg m², joint springs 1.2 and 0.8 N m/rad, motor
constants 0.12 and 0.08 N m/A. Linearised about the stationary collinear pose
with the inertial coupling between the links neglected; motor 2 sits on the
tip of link 1, so its torque turns hub 2 with the reaction on link 1. Inputs:
the two motor currents (A); outputs: the hub angles θ1, θ2 (rad). Both hubs
are free: two rigid-body modes, flexible modes near 4.9 and 5.8 Hz nominal.

    target/synth-venv/bin/python tools/flexible_joint_model.py
"""

import pathlib

import numpy as np

HUB = (2e-3, 1e-3)
LINK = (3.5e-3, 1.5e-3)
SPRING = (1.2, 0.8)
MOTOR = (0.12, 0.08)
# Link stiffness of each configuration, per cent of nominal.
CONFIGURATIONS = (80, 93, 100, 107, 120)
OUT = pathlib.Path(__file__).resolve().parent.parent / "scenarios" / "flexible-joint"


def joint(stiffness_factor: float) -> dict:
    """M, K, B, C of the joint with both springs scaled by the factor."""
    m = np.zeros((4, 4))
    k = np.zeros((4, 4))
    for i in range(2):
        j = 2 * i
        # Kinetic energy ½ J_h θ̇² + ½ J_l (θ̇ + α̇)².
        m[j : j + 2, j : j + 2] = [
            [HUB[i] + LINK[i], LINK[i]],
            [LINK[i], LINK[i]],
        ]
        k[j + 1, j + 1] = stiffness_factor * SPRING[i]
    # Virtual work of τ1 on θ1, of τ2 on θ2 and −τ2 on the link-1 angle θ1 + α1.
    b = np.array(
        [
            [MOTOR[0], -MOTOR[1]],
            [0.0, -MOTOR[1]],
            [0.0, MOTOR[1]],
            [0.0, 0.0],
        ]
    )
    c = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    return {"M": m, "K": k, "B": b, "C": c}


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for percent in CONFIGURATIONS:
        arrays = joint(percent / 100.0)
        np.savez(OUT / f"k{percent:03d}.npz", **arrays)
        w2 = np.linalg.eigvals(np.linalg.solve(arrays["M"], arrays["K"]))
        hz = np.sort(np.sqrt(np.abs(w2.real))) / (2 * np.pi)
        print(f"k{percent:03d}: modes {np.round(hz, 3)} Hz")


if __name__ == "__main__":
    main()
