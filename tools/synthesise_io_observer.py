#!/usr/bin/env python3
"""Synthesises the IO observer's correction filter K(s) for the flexible-joint
population by DK-iteration (mu-synthesis), as Adams & Forbes do
(docs/control.md §12.2), and writes it for `observer.correction_file`; then
compares it on the population with Kalman filters.

    python3 -m venv target/synth-venv
    target/synth-venv/bin/pip install -r tools/synthesis-requirements.txt
    target/synth-venv/bin/python tools/synthesise_io_observer.py            # writes K, prints the table
    target/synth-venv/bin/python tools/synthesise_io_observer.py --quick    # reduced grid, 1 iteration, writes nothing

The generalised plant, continuous time. One K serves the population, each
device's observer running K with that device's own model (as flexloop's
`flexible-joint-k*` scenarios do: the observer's model is the scenario's
plant). A device of link stiffness k_i (1 + SPREAD δ_i), |δ_i| ≤ 1, has the
estimation-error loop

    e' = (A0 + B_Δ diag(δ) C_α) e + B w − B ν,   ρ = C e + v,   ν = K(s) ρ

(E = B: ν corrects the model's input, the paper's form). The uncertainty
channels are z_Δ = C_α e (the deflections α1, α2 of the error) and
w_Δ = δ z_Δ, two complex scalars (each link on its own, a superset of the
population), scaled by a constant D0 (μ does not change). The performance
channels: inputs w (σ_w per current) and v (σ_v per hub angle), outputs the
error of θ1 α1 θ2 α2 weighted by 1/E_SCALE and ν weighted by NU_WEIGHT
(which also makes D12 full rank). The rigid modes sit at s = 0; the
synthesis sees the model shifted right by SHIFT, so that K must move them to
a decay rate of at least SHIFT rather than leave them on the axis.

K is written continuous (no `ts`): flexloop discretises it by Tustin at the
loop's rate. The comparison runs the observers in discrete time at 200 Hz as
flexloop does (ZOH model, Tustin K, one-step predictors) on the four
configurations: (a) the robust K, each device's observer on its own model,
(a') the robust K on the nominal model, (b) the Kalman predictor of the
nominal joint, (c) the Kalman predictor of each configuration.
"""

import argparse
import pathlib
import sys

import numpy as np
import scipy.linalg as sla

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import flexible_joint_model as joint_model  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parent.parent
OUT = ROOT / "scenarios" / "flexible-joint" / "k-robust.npz"
TS = 1.0 / 200.0
ZETA = 0.02
SIGMA_W = 0.005  # A, process noise on each current (the scenarios' force_noise)
SIGMA_V = 1e-4  # rad, sensor noise on each hub angle (the scenarios' sensor_noise)
SPREAD = 0.2  # ±20 % link stiffness
E_SCALE = 1e-2  # rad of estimation error that weighs 1
NU_WEIGHT = 1.0
SHIFT = 0.5  # rad/s
D0 = 1e-3
# DK-iteration: D-K steps, order of the fitted D(s), frequency grid.
ITERATIONS = 2
FIT_ORDER = 0
FREQUENCIES = 41
POPULATION = (80, 93, 107, 120)


def first_order(percent: float):
    """Continuous (A, B, C) of the joint at `percent` stiffness, x = [q; q'],
    modal damping ζ on the flexible modes; and the mass-normalised modes."""
    arrays = joint_model.joint(percent / 100.0)
    m, k, b, c = arrays["M"], arrays["K"], arrays["B"], arrays["C"]
    w2, phi = sla.eigh(k, m)  # Φᵀ M Φ = I
    w = np.sqrt(np.clip(w2, 0.0, None))
    minv = np.linalg.inv(m)
    damping = m @ phi @ np.diag(2 * ZETA * w) @ phi.T @ m
    n = m.shape[0]
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-minv @ k, -minv @ damping]])
    bb = np.vstack([np.zeros((n, b.shape[1])), minv @ b])
    cc = np.hstack([c, np.zeros((c.shape[0], n))])
    return a, bb, cc, (m, k, b, phi, w)


def generalised_plant():
    """P with inputs [w_Δ (2); w (2); v (2); ν (2)] and outputs
    [z_Δ (2); z_e (4); z_ν (2); ρ (2)] (module doc)."""
    import control

    a0, b0, c0, (m, k, _, _, _) = first_order(100)
    n = m.shape[0]
    # Deflections α1, α2 of e and the force of δ_i on them: the error loop
    # of a device whose stiffness is k_i (1 + SPREAD δ_i), observed with its
    # own model, is A0 + B_Δ diag(δ) C_α.
    e_alpha = np.zeros((n, 2))
    e_alpha[1, 0] = e_alpha[3, 1] = 1.0
    f_delta = -SPREAD * e_alpha * np.array([k[1, 1], k[3, 3]])
    b_delta = np.vstack([np.zeros((n, 2)), np.linalg.inv(m) @ f_delta])
    c_alpha = np.hstack([e_alpha.T, np.zeros((2, n))])
    # The rigid modes shifted into the right half-plane: K must move them
    # left of −SHIFT (a decay-rate margin), not leave them at s = 0.
    ne = a0.shape[0]
    a = a0 + SHIFT * np.eye(ne)
    # A constant D-scale on the uncertainty channels (μ does not change):
    # the first H∞ step then weighs them against the performance.
    b_delta, c_alpha = b_delta * D0, c_alpha / D0
    b = np.hstack([b_delta, b0 * SIGMA_W, np.zeros((ne, 2)), -b0])
    c_pos = np.hstack([np.eye(n), np.zeros((n, n))])  # θ1 α1 θ2 α2 of e
    c = np.vstack([c_alpha, c_pos / E_SCALE, np.zeros((2, ne)), c0])
    z2, z4 = np.zeros((2, 2)), np.zeros((4, 2))
    d = np.block(
        [
            [z2, z2, z2, z2],
            [z4, z4, z4, z4],
            [z2, z2, z2, NU_WEIGHT * np.eye(2)],
            [z2, z2, SIGMA_V * np.eye(2), z2],
        ]
    )
    return control.ss(a, b, c, d)


def synthesise(quick: bool):
    import control
    import dkpy

    p = generalised_plant()
    # ν in units of σ_w and ρ in units of σ_v for the synthesis (the Riccati
    # solver is far better conditioned); K is scaled back below. These
    # channels are closed by K, so μ does not change.
    a, b, c, d = (np.asarray(m).copy() for m in (p.A, p.B, p.C, p.D))
    b[:, -2:] *= SIGMA_W
    d[:, -2:] *= SIGMA_W
    c[-2:, :] /= SIGMA_V
    d[-2:, :] /= SIGMA_V
    p = control.ss(a, b, c, d)
    omega = np.logspace(-1, 3, 25 if quick else FREQUENCIES)
    blocks = [
        dkpy.ComplexFullBlock(1, 1),
        dkpy.ComplexFullBlock(1, 1),
        dkpy.ComplexFullBlock(4, 6),
    ]
    dk = dkpy.DkIterFixedOrder(
        controller_synthesis=dkpy.HinfSynSlicot(),
        structured_singular_value=dkpy.SsvLmiBisection(n_jobs=1, initial_guess=1e4),
        d_scale_fit=dkpy.DScaleFitSlicot(),
        n_iterations=1 if quick else ITERATIONS,
        fit_order=FIT_ORDER,
    )
    k, n, mu, results, _ = dk.synthesize(p, 2, 2, omega, blocks)
    if k is None:
        raise SystemExit("DK-iteration found no controller")
    mu_before = float(np.max(results[0].mu_omega))
    mu_after = float(np.max(results[-1].mu_omega))
    a_k, b_k, c_k, d_k = (np.asarray(m) for m in (k.A, k.B, k.C, k.D))
    scaled = (a_k, b_k / SIGMA_V, c_k * SIGMA_W, d_k * SIGMA_W / SIGMA_V)
    return scaled, mu_before, mu_after, float(mu)


def tustin(a, b, c, d, ts):
    """s = (2/ts)(z − 1)/(z + 1), as flexloop-control's `tustin` (no prewarp)."""
    n = a.shape[0]
    alpha = ts / 2.0
    minv = np.linalg.inv(np.eye(n) - alpha * a)
    kk = np.sqrt(2 * alpha)
    return (
        minv @ (np.eye(n) + alpha * a),
        kk * minv @ b,
        kk * c @ minv,
        d + alpha * c @ minv @ b,
    )


def zoh(a, b, ts):
    n, m = a.shape[0], b.shape[1]
    big = sla.expm(np.block([[a, b], [np.zeros((m, n + m))]]) * ts)
    return big[:n, :n], big[:n, n:]


def kalman_predictor(ad, bd, cd):
    """Steady-state predictor gain L (x̂+ = A x̂ + B u + L ρ), G = B,
    Q = σ_w² per sample, R = σ_v² (flexloop's `kalman` weights)."""
    q = bd @ bd.T * SIGMA_W**2
    r = np.eye(cd.shape[0]) * SIGMA_V**2
    p = sla.solve_discrete_are(ad.T, cd.T, q, r)
    return ad @ p @ cd.T @ np.linalg.inv(cd @ p @ cd.T + r)


def simulate(plant_pct, observer, seconds, seed):
    """rms estimation error of [θ1, α1, θ2, α2] (rad) of `observer` on the
    joint at `plant_pct` under a known excitation and the scenarios' noise."""
    a, b, c, _ = first_order(plant_pct)
    ad, bd = zoh(a, b, TS)
    rng = np.random.default_rng(seed)
    steps = int(seconds / TS)
    t = np.arange(steps) * TS
    # The known input: two currents, a few sines across the modes' band.
    u = np.stack(
        [
            0.05 * np.sin(2 * np.pi * 0.3 * t) + 0.02 * np.sin(2 * np.pi * 4.0 * t),
            0.04 * np.cos(2 * np.pi * 0.5 * t) + 0.02 * np.sin(2 * np.pi * 5.5 * t),
        ],
        axis=1,
    )
    x = np.zeros(a.shape[0])
    state = observer["init"]()
    err = []
    for i in range(steps):
        y = c @ x + SIGMA_V * rng.standard_normal(2)
        x_hat = observer["estimate"](state)
        err.append(x[:4] - x_hat[:4])
        state = observer["step"](state, y, u[i])
        x = ad @ x + bd @ (u[i] + SIGMA_W * rng.standard_normal(2))
    err = np.array(err[int(2.0 / TS) :])  # after the start-up transient
    rms = np.sqrt(np.mean(err**2, axis=0))
    return rms


def kalman_observer(model_pct):
    a, b, c, _ = first_order(model_pct)
    ad, bd = zoh(a, b, TS)
    l = kalman_predictor(ad, bd, c)
    return {
        "init": lambda: np.zeros(ad.shape[0]),
        "estimate": lambda s: s,
        "step": lambda s, y, u: ad @ s + bd @ u + l @ (y - c @ s),
    }, ad, bd, c, l


def io_observer(kd, model_pct=100):
    a, b, c, _ = first_order(model_pct)
    ad, bd = zoh(a, b, TS)
    ak, bk, ck, dk = kd
    n = ad.shape[0]

    def step(s, y, u):
        x, w = s[:n], s[n:]
        rho = y - c @ x
        nu = ck @ w + dk @ rho
        return np.concatenate([ad @ x + bd @ u + bd @ nu, ak @ w + bk @ rho])

    return {
        "init": lambda: np.zeros(n + ak.shape[0]),
        "estimate": lambda s: s[:n],
        "step": step,
    }


def error_radius(model_pct, plant_pct, kd):
    """Spectral radius of the discrete error loop of the IO observer on the
    model at `model_pct` (flexloop's load-time check when they are equal)."""
    a, b, c, _ = first_order(model_pct)
    ad, bd = zoh(a, b, TS)
    ak, bk, ck, dk = kd
    top = np.hstack([ad - bd @ dk @ c, -bd @ ck])
    bottom = np.hstack([bk @ c, ak])
    return max(abs(np.linalg.eigvals(np.vstack([top, bottom]))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="reduced grid, writes nothing")
    parser.add_argument(
        "--table", action="store_true", help="the comparison with the committed K only"
    )
    args = parser.parse_args()
    if args.table:
        with np.load(OUT) as f:
            a_k, b_k, c_k, d_k = (f[n] for n in ("A_K", "B_K", "C_K", "D_K"))
        compare(tustin(a_k, b_k, c_k, d_k, TS))
        return
    (a_k, b_k, c_k, d_k), mu_before, mu_after, mu = synthesise(args.quick)
    kd = tustin(a_k, b_k, c_k, d_k, TS)
    print(f"K(s): {a_k.shape[0]} states; μ peak {mu_before:.3f} (first H∞ K) -> {mu_after:.3f}")
    k_radius = max(abs(np.linalg.eigvals(kd[0]))) if a_k.shape[0] else 0.0
    print(f"K(z) at {1 / TS:.0f} Hz: spectral radius {k_radius:.6f}")
    radii = {pct: error_radius(pct, pct, kd) for pct in (100,) + POPULATION}
    for pct, radius in radii.items():
        print(f"  error loop on the k{pct:03d} model: radius {radius:.6f}")
    # flexloop refuses an unstable K or error loop: such a K is not written.
    usable = k_radius < 1.0 and max(radii.values()) < 1.0
    if args.quick:
        return
    if not usable:
        print("K is not usable (unstable K or error loop at 200 Hz): nothing written")
        compare(None)
        raise SystemExit(1)
    np.savez(OUT, A_K=a_k, B_K=b_k, C_K=c_k, D_K=d_k)
    print(f"wrote {OUT.relative_to(ROOT)}")
    compare(kd)


def compare(kd) -> None:
    """The paper's comparison on the population (module doc), as a table;
    without a usable K (`kd` None) the Kalman rows only."""
    nominal, *_ = kalman_observer(100)
    print()
    print("| stiffness | observer | rms θ1 | rms α1 | rms θ2 | rms α2 (µrad) |")
    print("|---|---|---|---|---|---|")
    for pct in POPULATION:
        own, *_ = kalman_observer(pct)
        rows = [] if kd is None else [
            ("(a) robust K, own model", io_observer(kd, pct)),
            ("(a') robust K, nominal model", io_observer(kd, 100)),
        ]
        rows += [
            ("(b) Kalman, nominal", nominal),
            ("(c) Kalman, own configuration", own),
        ]
        for name, obs in rows:
            # The same noise for every observer of a configuration.
            rms = simulate(pct, obs, 30.0, seed=pct) * 1e6
            print(f"| {pct} % | {name} | " + " | ".join(f"{v:.1f}" for v in rms) + " |")


if __name__ == "__main__":
    main()
