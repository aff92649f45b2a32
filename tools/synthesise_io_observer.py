#!/usr/bin/env python3
"""Synthesises the IO observer's correction filter K(s) for the flexible-joint
population by DK-iteration (mu-synthesis), as Adams & Forbes do
(docs/control.md §12.2), and writes it for `observer.correction_file`; then
compares it on the population with Kalman filters.

    python3 -m venv target/synth-venv
    target/synth-venv/bin/pip install -r tools/synthesis-requirements.txt
    target/synth-venv/bin/python tools/synthesise_io_observer.py            # writes K, prints the table
    target/synth-venv/bin/python tools/synthesise_io_observer.py --quick    # reduced grid, 1 iteration, writes nothing
    target/synth-venv/bin/python tools/synthesise_io_observer.py --table    # the table with the committed K

The generalised plant, continuous time. One K serves the population, each
device's observer running K with that device's own model (as flexloop's
`flexible-joint-*` scenarios do: the observer's model is the scenario's
plant). A device of link stiffness k_i (1 + SPREAD δ_i), |δ_i| ≤ 1, has the
estimation-error loop

    e' = (A0 + B_Δ diag(δ) C_α) e + B d − B ν,   ρ = C e + n,   ν = K(s) ρ

(E = B: ν corrects the model's input, the paper's form). The uncertainty
channels are z_Δ = C_α e (the deflections α1, α2 of the error) and
w_Δ = δ z_Δ, two complex scalars (each link on its own, a superset of the
population), scaled by a constant D0 so that the first H∞ step weighs them
against the performance (μ does not depend on D0). The performance channels,
the paper's Fig. 8 with weights chosen here:

- inputs: the process noise d = SIGMA_W d̃ on each current and the sensor
  noise n = SIGMA_V ñ on each hub angle (W_d, W_n constant: both are white);
- outputs: the hub-angle errors through W_θ = (s + ω_b)/(s + ω_b/M_θ) ·
  ω_e/(s + ω_e) / E_SCALE (M_θ times heavier below ω_b: the rigid modes'
  random walk is what K must follow), the deflection errors through
  ω_e/(s + ω_e) / E_SCALE (a static deflection error is not in K's reach,
  docs/control.md §12.3, so it gets no low-frequency boost), and the
  correction through the high-pass W_ν = (s/ω_l + 1)/(s/(R ω_l) + 1) / NU_LOW,
  R times heavier above ω_l: K must roll off well below the 100 Hz Nyquist
  frequency of the 200 Hz loop, where flexloop discretises it by Tustin.

ν is synthesised in units of SIGMA_W and ρ in units of SIGMA_V (the Riccati
solvers are far better conditioned), K is scaled back before it is written.
Each H∞ step is a suboptimal central controller at H_INF_MARGIN times the
smallest γ found by bisection (SLICOT sb10fd, every γ verified by the
closed loop's poles and peak gain): the γ-optimal controller that
python-control's `hinfsyn` returns has poles near 10⁹ rad/s, which Tustin
at 200 Hz puts on the unit circle. The DK loop is dkpy's (its μ upper bound
by LMIs, its SLICOT fit of D(s) of order FIT_ORDER) with this H∞ step, and
keeps the iterate of least μ peak among those flexloop accepts.

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
# Performance weights (module doc). With these the nominal H∞ step reaches
# γ ≈ 1: the sensor noise through K at low frequency, SIGMA_V M_θ / E_SCALE,
# is what limits it.
E_SCALE = 3e-3  # rad of estimation error that weighs 1 between ω_b and ω_e
THETA_BOOST = 30.0  # M_θ
THETA_CORNER_HZ = 2.0  # ω_b / 2π
ERROR_BAND_HZ = 15.0  # ω_e / 2π
NU_LOW = 300.0  # ν (in units of SIGMA_W) that weighs 1 below ω_l
NU_CORNER_HZ = 20.0  # ω_l / 2π
NU_RISE = 100.0  # R
D0 = 1e-3
H_INF_MARGIN = 1.05
# DK-iteration: D-K steps, order of the fitted D(s), the paper's grid
# (61 points, 0.01 to 25 Hz).
ITERATIONS = 2
FIT_ORDER = 2
FREQUENCIES_HZ = (0.01, 25.0, 61)
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


def generalised_plant(spread: float = SPREAD):
    """P with inputs [w_Δ (2); d̃ (2); ñ (2); ν/SIGMA_W (2)] and outputs
    [z_Δ (2); W_θ e_θ1, W_α e_α1, W_θ e_θ2, W_α e_α2; W_ν ν (2); ρ/SIGMA_V (2)]
    (module doc)."""
    import control

    a0, b0, c0, (m, k, _, _, _) = first_order(100)
    n, ne = m.shape[0], a0.shape[0]
    # Deflections α1, α2 of e and the torque of δ_i on them: the error loop
    # of a device whose stiffness is k_i (1 + spread δ_i), observed with its
    # own model, is A0 + B_Δ diag(δ) C_α.
    e_alpha = np.zeros((n, 2))
    e_alpha[1, 0] = e_alpha[3, 1] = 1.0
    f_delta = -spread * e_alpha * np.array([k[1, 1], k[3, 3]])
    b_delta = np.vstack([np.zeros((n, 2)), np.linalg.inv(m) @ f_delta]) * D0
    c_alpha = np.hstack([e_alpha.T, np.zeros((2, n))]) / D0
    b = np.hstack([b_delta, b0 * SIGMA_W, np.zeros((ne, 2)), -b0 * SIGMA_W])
    c = np.vstack(
        [c_alpha, np.hstack([np.eye(n), np.zeros((n, n))]), np.zeros((2, ne)), c0 / SIGMA_V]
    )
    d = np.zeros((10, 8))
    d[6:8, 6:8] = np.eye(2)  # ν passed to its weight
    d[8:10, 4:6] = np.eye(2)  # ñ on ρ
    error_loop = control.ss(a0, b, c, d)
    s = control.tf("s")
    w_e, w_b = 2 * np.pi * ERROR_BAND_HZ, 2 * np.pi * THETA_CORNER_HZ
    low_pass = w_e / (s + w_e)
    w_theta = (s + w_b) / (s + w_b / THETA_BOOST) * low_pass / E_SCALE
    w_alpha = low_pass / E_SCALE
    w_l = 2 * np.pi * NU_CORNER_HZ
    w_nu = (s / w_l + 1) / (s / (NU_RISE * w_l) + 1) / NU_LOW
    one = control.tf([1], [1])
    weights = [one, one, w_theta, w_alpha, w_theta, w_alpha, w_nu, w_nu, one, one]
    return control.ss(control.append(*(control.ss(w) for w in weights))) * error_loop


def physical(k):
    """K of the scaled synthesis (ν/SIGMA_W from ρ/SIGMA_V) in A per rad."""
    a_k, b_k, c_k, d_k = (np.asarray(m) for m in (k.A, k.B, k.C, k.D))
    return a_k, b_k / SIGMA_V, c_k * SIGMA_W, d_k * SIGMA_W / SIGMA_V


def suboptimal_hinf(p, n_y, n_u):
    """Central H∞ controller at H_INF_MARGIN × the least γ (module doc).
    Returns (K, γ_min) or (None, None). sb10fd reports success for some γ
    whose controller does not reach γ (ill-conditioned Riccati equations),
    so each candidate is checked on the closed loop."""
    import control
    import slycot

    a, b, c, d = (np.asarray(m) for m in (p.A, p.B, p.C, p.D))
    omega = np.logspace(-2, 4.5, 300)

    def controller(gamma):
        try:
            a_k, b_k, c_k, d_k = slycot.sb10fd(
                a.shape[0], b.shape[1], c.shape[0], n_u, n_y, gamma, a, b, c, d
            )[:4]
        except (slycot.exceptions.SlycotError, ValueError):
            return None
        k = control.ss(a_k, b_k, c_k, d_k)
        loop = p.lft(k)
        if np.max(np.linalg.eigvals(loop.A).real) >= 0.0:
            return None
        response = loop(1j * omega)
        peak = max(
            np.linalg.svd(response[:, :, i], compute_uv=False)[0] for i in range(len(omega))
        )
        return k if peak <= gamma * 1.001 else None

    low, high = 1e-3, 1e7
    if controller(high) is None:
        return None, None
    for _ in range(80):  # bounded: stops at 1 % or after 80 halvings
        if high / low < 1.01:
            break
        mid = np.sqrt(low * high)
        if controller(mid) is None:
            low = mid
        else:
            high = mid
    gamma = H_INF_MARGIN * high
    for _ in range(40):  # bounded: γ grows by 5 % a step
        k = controller(gamma)
        if k is not None:
            return k, high
        gamma *= 1.05
    return None, None


def usable(kc):
    """What flexloop checks at load time, at 200 Hz (docs/control.md §12.3):
    the spectral radius of K(z) and of every member's error loop."""
    kd = tustin(*kc, TS)
    k_radius = max(abs(np.linalg.eigvals(kd[0]))) if kc[0].shape[0] else 0.0
    radii = {pct: error_radius(pct, pct, kd) for pct in (100,) + POPULATION}
    return k_radius, radii, k_radius < 1.0 and max(radii.values()) < 1.0


def mu_bound(n_omega, blocks):
    """dkpy's LMI upper bound on μ per frequency, with its D-scales. Clarabel
    (the default solver) panics on a few ill-conditioned grids (a Rust panic
    surfaces as a BaseException); SCS then solves the same LMIs."""
    import dkpy

    try:
        return dkpy.SsvLmiBisection(n_jobs=1).compute_ssv(n_omega, block_structure=blocks)
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException as error:  # noqa: B036 (pyo3's PanicException)
        print(f"  μ by Clarabel failed ({type(error).__name__}), SCS instead")
        scs = dkpy.SsvLmiBisection(n_jobs=1, solver_params={"solver": "SCS", "eps": 1e-7})
        return scs.compute_ssv(n_omega, block_structure=blocks)


def synthesise(quick: bool):
    """dkpy's DK-iteration with the suboptimal H∞ step (module doc).
    Returns the chosen K (physical units), the μ peak of the first H∞ K,
    of the chosen one, and the per-step (γ, μ peak, usable) log."""
    import control
    import dkpy

    p = generalised_plant()
    low, high, count = FREQUENCIES_HZ
    omega = 2 * np.pi * np.logspace(np.log10(low), np.log10(high), 21 if quick else count)
    blocks = [
        dkpy.ComplexFullBlock(1, 1),
        dkpy.ComplexFullBlock(1, 1),
        dkpy.ComplexFullBlock(4, 6),
    ]
    fit = dkpy.DScaleFitSlicot()
    scaled = p
    steps = []
    for step in range(1 + (1 if quick else ITERATIONS)):
        k, gamma = suboptimal_hinf(scaled, 2, 2)
        if k is None:
            print(f"step {step}: no H∞ controller")
            break
        n_omega = p.lft(k)(1j * omega)
        mu, d_left, d_right, _ = mu_bound(n_omega, blocks)
        kc = physical(k)
        k_radius, radii, ok = usable(kc)
        peak_hz = omega[np.argmax(mu)] / (2 * np.pi)
        print(
            f"step {step}: γ {gamma:.4f}, μ peak {np.max(mu):.4f} at {peak_hz:.3g} Hz, "
            f"K {kc[0].shape[0]} states, K(z) radius {k_radius:.5f}, error loops "
            + " ".join(f"{r:.5f}" for r in radii.values())
        )
        steps.append((float(np.max(mu)), kc, ok, n_omega))
        d_fit, d_fit_inv = fit.fit(omega, d_left, d_right, order=FIT_ORDER, block_structure=blocks)
        # D(s) on the uncertainty and performance channels, identity on ρ and ν.
        d_aug = control.ss(control.append(d_fit, control.ss([], [], [], np.eye(2))))
        d_aug_inv = control.ss(control.append(d_fit_inv, control.ss([], [], [], np.eye(2))))
        scaled = d_aug * p * d_aug_inv
    candidates = [s for s in steps if s[2]]
    if not candidates:
        return None, steps
    best = min(candidates, key=lambda s: s[0])
    # Robust stability alone: μ of the uncertainty channels, the two links'
    # stiffness perturbations; the loop stays stable for |δ_i| < 1/μ_RS.
    mu_rs, *_ = mu_bound(best[3][:2, :2, :], blocks[:2])
    print(
        f"robust stability of the chosen K: μ peak {np.max(mu_rs):.4f} "
        f"(stable for a stiffness spread up to ±{100 * SPREAD / np.max(mu_rs):.0f} %)"
    )
    return best, steps


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
    best, steps = synthesise(args.quick)
    if not steps:
        raise SystemExit("no H∞ controller for the generalised plant")
    if best is None:
        print("no DK step gave a K flexloop accepts (unstable K or error loop at 200 Hz)")
        if not args.quick:
            compare(None)
        raise SystemExit(1)
    mu_best, (a_k, b_k, c_k, d_k), *_ = best
    print(
        f"μ peak {steps[0][0]:.4f} (first H∞ K) -> {mu_best:.4f} "
        f"(step {steps.index(best)}, K of {a_k.shape[0]} states)"
    )
    if args.quick:
        return
    np.savez(OUT, A_K=a_k, B_K=b_k, C_K=c_k, D_K=d_k)
    print(f"wrote {OUT.relative_to(ROOT)}")
    compare(tustin(a_k, b_k, c_k, d_k, TS))


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
