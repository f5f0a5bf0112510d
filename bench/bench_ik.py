"""The thesis' IK experiment (seed digest B.9) on the 38-DOF body model.

A simulated pose (every angle drawn inside its range of motion), noise on the joint
angles (uniform +-``--noise-deg`` per angle, clipped to the limits) that moves the end
effectors (head, hands, feet) by up to ~60 cm and ~55 deg, then each solver brings
them back to the simulated effector positions and orientations. The pelvis is fixed.
Prints, per solver: per end-effector position / orientation error (mean and max),
iterations (CCD sweeps + DLS iterations for the polished rows), time per solve
(median, p95, and the median over the yardstick, ``bench.yardstick``) and the share of
solves meeting the target (every effector within 1 mm and 0.5 deg). The default CCD is
the hybrid (``CcdConfig.polish``); the ablation rows ("without ...", thesis, plain) are
pure CCD (``polish=False``).

    python -m bench ik            # or: python -m bench.bench_ik --trials 100
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from bench.yardstick import header, yardstick_ms
from mocap_rt.body.ccd import CcdConfig, solve_ccd
from mocap_rt.body.jacobian import JacobianConfig, solve_jacobian
from mocap_rt.body.kinematics import forward_kinematics
from mocap_rt.body.skeleton import END_EFFECTORS, J, body_model

TARGET_MM, TARGET_DEG, TARGET_MS = 1.0, 0.5, 1.0


def make_trials(model, n: int, noise_deg: float, seed: int):
    """[(truth angles, start angles)] with the pelvis fixed at the origin."""
    rng = np.random.default_rng(seed)
    lo, hi = model.limits[..., 0], model.limits[..., 1]
    out = []
    for _ in range(n):
        truth = np.where(model.dof, lo + (hi - lo) * rng.uniform(0.2, 0.8, lo.shape), 0.0)
        truth[0] = 0.0
        start = truth + np.where(model.dof, rng.uniform(-1, 1, lo.shape) * np.radians(noise_deg), 0.0)
        start[0] = 0.0
        out.append((truth, np.clip(start, lo, hi)))
    return out


def solvers():
    hybrid = CcdConfig()                     # default: improved CCD + DLS polish
    ccd = replace(hybrid, polish=False)      # the ablation rows are pure CCD
    thesis = replace(ccd, relaxation=1.0, redundant_chain_weight=1.0)
    return [
        ("CCD improved + DLS polish (default)", "ccd", hybrid),
        ("CCD improved, no polish", "ccd", ccd),
        ("CCD thesis (3 improvements)", "ccd", thesis),
        ("CCD without limits", "ccd", replace(ccd, use_limits=False)),
        ("CCD without angle tolerance", "ccd", replace(ccd, angle_tolerance_deg=0.0)),
        ("CCD without adaptive weights", "ccd", replace(ccd, adaptive_weights=False)),
        ("CCD without over-relaxation", "ccd", replace(ccd, relaxation=1.0)),
        ("CCD without chain weights", "ccd", replace(ccd, redundant_chain_weight=1.0)),
        ("CCD plain (no improvements)", "ccd", replace(thesis, use_limits=False, angle_tolerance_deg=0.0,
                                                       adaptive_weights=False)),
        ("CCD thesis + DLS polish", "ccd", replace(hybrid, relaxation=1.0, redundant_chain_weight=1.0)),
        ("Jacobian transpose", "jac", JacobianConfig(method="transpose")),
        ("Damped pseudo-inverse + null space", "jac", JacobianConfig(method="dls")),
    ]


def run(trials, model, name, kind, cfg, effectors):
    perr, oerr, its, ms = [], [], [], []
    for truth, start in trials:
        P, R = forward_kinematics(model, np.zeros(3), truth)
        t0 = time.perf_counter()
        fn = solve_ccd if kind == "ccd" else solve_jacobian
        res = fn(model, np.zeros(3), start, effectors, P[effectors], R[effectors], reference=start, config=cfg)
        ms.append((time.perf_counter() - t0) * 1e3)
        perr.append(res.position_error_m * 1e3)
        oerr.append(res.orientation_error_deg)
        its.append(res.iterations)
    return np.array(perr), np.array(oerr), np.array(its), np.array(ms)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=60)
    ap.add_argument("--noise-deg", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    model = body_model(preset="full")
    effectors = np.array([J[n] for n in END_EFFECTORS])
    trials = make_trials(model, args.trials, args.noise_deg, args.seed)
    # start errors
    d0, a0 = [], []
    for truth, start in trials:
        P, R = forward_kinematics(model, np.zeros(3), truth)
        P0, R0 = forward_kinematics(model, np.zeros(3), start)
        d0.append(np.linalg.norm(P0[effectors] - P[effectors], axis=1))
        a0.append([np.degrees(np.arccos(np.clip((np.trace(R[e].T @ R0[e]) - 1) / 2, -1, 1))) for e in effectors])
    d0, a0 = np.array(d0) * 100, np.array(a0)
    print(f"{len(trials)} simulated poses, 38-DOF model, noise +-{args.noise_deg:.0f} deg per angle; "
          f"start errors: position max {d0.max():.0f} cm (median {np.median(d0):.0f}), "
          f"orientation max {a0.max():.0f} deg (median {np.median(a0):.0f})")
    # warm up the compiled kernels
    for _, kind, cfg in solvers()[:1] + solvers()[-1:]:
        run(trials[:1], model, "", kind, cfg, effectors)
    print(f"target: every effector < {TARGET_MM} mm and < {TARGET_DEG} deg, < {TARGET_MS} ms per solve")
    ys = yardstick_ms()
    print(header(ys))
    head = f"{'solver':36s} {'ok%':>5s} {'iter':>5s} {'ms med':>7s} {'x yd':>6s} {'ms p95':>7s}  " + "  ".join(
        f"{n:>15s}" for n in END_EFFECTORS)
    print(head)
    print(f"{'':36s} {'':>5s} {'med':>5s} {'':>7s} {'':>6s} {'':>7s}  " + "  ".join(f"{'mm mean/max deg':>15s}" for _ in END_EFFECTORS))
    for name, kind, cfg in solvers():
        perr, oerr, its, ms = run(trials, model, name, kind, cfg, effectors)
        ok = ((perr < TARGET_MM) & (oerr < TARGET_DEG)).all(axis=1)
        cells = [f"{perr[:, e].mean():5.2f}/{perr[:, e].max():5.1f} {oerr[:, e].max():4.1f}" for e in range(len(effectors))]
        print(f"{name:36s} {100 * ok.mean():5.0f} {np.median(its):5.0f} {np.median(ms):7.3f} "
              f"{np.median(ms) / ys:6.2f} {np.percentile(ms, 95):7.3f}  " + "  ".join(f"{c:>15s}" for c in cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
