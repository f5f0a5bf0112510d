"""Joint-centre estimation (issue 7): the patent's synthetic experiment, real trials, speed.

(a) Synthetic (seed digest C, evaluation): continuous/discrete motion, ranges I and II,
    noise 0-5 % of the segment length, N trials each (default 100): mean joint-centre
    error per method with and without rigid preprocessing; the EDR table at 5 % next to
    the patent's figures; a per-cell check "patent <= every baseline".
(b) Real functional trials from ../shared/data/markers: every joint the marker set
    allows, ROM, residual and bone-length mean/std per method; overlay PNGs in bench/out/.
(c) Speed: a 1085-frame, 12-joint trial end to end (read, compute, write), median of runs.

    python -m bench joint_centres            # everything, defaults
    python bench/bench_joint_centres.py --trials 20 --skip-real
"""

from __future__ import annotations

import argparse
import logging
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mocap_rt.markers.joint_centres import METHODS
from mocap_rt.markers.rigid import fit_rigid_segment, select_markers
from mocap_rt.markers.synthetic import simulate_joint
from mocap_rt.shared_data import data_root

HERE = Path(__file__).resolve().parent
BASELINES = ("score", "sphere", "obrien")
# the patent's EDR (%) at 5 % noise: large continuous / small continuous / large discrete / small discrete
PATENT_EDR = {
    "Silaghi98": (28.62, 14.57, 35.53, 15.57),
    "O'Brien00": (7.44, 13.42, 6.48, 11.68),
    "UdLa02": (2.30, 13.57, 3.01, 11.70),
    "KOF05": (17.33, 14.23, 35.08, 13.26),
}
CONDITIONS = (("continuous", "II"), ("continuous", "I"), ("discrete", "II"), ("discrete", "I"))
CONDITION_LABEL = {("continuous", "II"): "large cont.", ("continuous", "I"): "small cont.",
                   ("discrete", "II"): "large disc.", ("discrete", "I"): "small disc."}
REAL_TRIALS = (
    ("biobuddy_qualisys_subjectECH/functional_right_hip.c3d", "biobuddy_qualisys"),
    ("biobuddy_qualisys_subjectECH/functional_right_knee.c3d", "biobuddy_qualisys"),
    ("biobuddy_vicon_P01_lightweight/Test_func_rhip.c3d", "biobuddy_vicon"),
    ("biobuddy_vicon_P01_lightweight/Test_func_rknee.c3d", "biobuddy_vicon"),
)
MIN_ROM_DEG = 20.0  # joints moving less than this are listed but left out of the method ranking


def run_synthetic(n_trials: int, n_frames: int, noise_levels: list[float], methods: list[str], seed: int):
    """errors[(motion, range, noise, rigid)][method] -> (n_trials,) mean error / segment length."""
    rng = np.random.default_rng(seed)
    errors: dict = {}
    for motion, rng_name in CONDITIONS:
        for noise in noise_levels:
            cell = {(rigid, m): np.empty(n_trials) for rigid in (False, True) for m in methods}
            for t in range(n_trials):
                trial = simulate_joint(rng, n_frames, motion == "continuous", rng_name, noise)
                fp, fc = fit_rigid_segment(trial.parent), fit_rigid_segment(trial.child)
                op, oc = select_markers(fp.template, fp.marker_error), select_markers(fc.template, fc.marker_error)
                inputs = {False: (trial.parent[:, op], trial.child[:, oc]),
                          True: (fp.corrected[:, op], fc.corrected[:, oc])}
                for rigid, (p, c) in inputs.items():
                    for m in methods:
                        centre = METHODS[m](p, c).centre
                        cell[(rigid, m)][t] = np.nanmean(np.linalg.norm(centre - trial.centre, axis=1))
            for (rigid, m), v in cell.items():
                errors.setdefault((motion, rng_name, noise, rigid), {})[m] = v
    return errors


def print_synthetic(errors, noise_levels, methods) -> dict:
    """Tables of mean error; per row, patent / best baseline.  Baselines are compared in
    their better configuration (raw or rigid), the patent method with its own step A."""
    print("\n(a) synthetic: mean joint-centre error, % of segment length (mean over trials)")
    head = "condition        noise " + " ".join(f"{m:>9}" for m in methods)
    wins = {}
    for rigid in (False, True):
        print(f"\n-- {'with' if rigid else 'without'} rigid preprocessing (step A) --")
        print(head + ("   patent/best baseline (any config)" if rigid else ""))
        for motion, rng_name in CONDITIONS:
            for noise in noise_levels:
                row = errors[(motion, rng_name, noise, rigid)]
                means = {m: 100 * float(np.mean(row[m])) for m in methods}
                line = f"{CONDITION_LABEL[(motion, rng_name)]:<16} {100 * noise:4.0f}% " + " ".join(
                    f"{means[m]:9.3f}" for m in methods)
                if rigid and "patent" in means and noise > 0:
                    best = {b: min((float(np.mean(errors[(motion, rng_name, noise, r)][b])), r) for r in (False, True))
                            for b in BASELINES if b in means}
                    ok = all(means["patent"] <= 100 * v + 1e-9 for v, _ in best.values())
                    wins[(motion, rng_name, noise)] = ok
                    ratio = means["patent"] / (100 * min(v for v, _ in best.values()))
                    verdict = []
                    for b, (v, r) in best.items():
                        if means["patent"] > 100 * v + 1e-9:
                            diff = row["patent"] - errors[(motion, rng_name, noise, r)][b]  # paired over trials
                            t = float(np.mean(diff) / (np.std(diff, ddof=1) / np.sqrt(len(diff)) + 1e-300))
                            verdict.append(f"{b} (paired t={t:.1f})")
                    line += f"   {ratio:5.3f} " + ("ok" if ok else "worse than " + ", ".join(verdict))
                print(line)
    return wins


def print_edr(errors, noise_levels, methods) -> None:
    top = max(noise_levels)
    print(f"\n(a) EDR (error-decrease ratio by rigid preprocessing, %) at {100 * top:.0f} % noise, patent layout:")
    cols = [CONDITION_LABEL[c] for c in CONDITIONS]
    order = [CONDITIONS.index(c) for c in (("continuous", "II"), ("continuous", "I"), ("discrete", "II"),
                                            ("discrete", "I"))]
    print(f"{'method':<14}" + "".join(f"{cols[i]:>13}" for i in order) + f"{'average':>10}")
    for m in methods:
        vals = []
        for i in order:
            motion, rng_name = CONDITIONS[i]
            raw = float(np.mean(errors[(motion, rng_name, top, False)][m]))
            cor = float(np.mean(errors[(motion, rng_name, top, True)][m]))
            vals.append(100.0 * (raw - cor) / raw if raw > 0 else float("nan"))
        print(f"{m:<14}" + "".join(f"{v:13.1f}" for v in vals) + f"{np.mean(vals):10.1f}")
    print("patent's figures (its own 4 methods, 5 % noise):")
    for name, vals in PATENT_EDR.items():
        print(f"{name:<14}" + "".join(f"{v:13.1f}" for v in vals) + f"{np.mean(vals):10.1f}")


def plot_synthetic(errors, noise_levels, methods, out_dir: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(16, 4), sharey=False)
    colours = plt.get_cmap("tab10")
    for ax, cond in zip(axes, CONDITIONS):
        for k, m in enumerate(methods):  # one colour per method; dashed = raw markers, solid = after step A
            for rigid, style in ((False, "--"), (True, "-")):
                y = [100 * np.mean(errors[(cond[0], cond[1], n, rigid)][m]) for n in noise_levels]
                ax.plot([100 * n for n in noise_levels], y, style, color=colours(k % 10),
                        label=f"{m}{' +rigid' if rigid else ''}")
        ax.set_title(CONDITION_LABEL[cond])
        ax.set_xlabel("noise, % of segment length")
    axes[0].set_ylabel("joint-centre error, % of segment length")
    axes[-1].legend(fontsize=6)
    fig.tight_layout()
    path = out_dir / "joint_centres_synthetic.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def run_real(methods: list[str], out_dir: Path) -> None:
    from mocap_rt.markers.io import read_markers
    from mocap_rt.markers.segments import load_segments, shipped_segments_path
    from mocap_rt.markers.trial import joint_centres_for_trial

    root = data_root() / "markers"
    print("\n(b) real functional trials: bone length mean ± std over the trial (mm; std lower is better) for bones\n"
          "    between chained joints (hip-knee, knee-ankle, ...) with at least one end moving >= "
          f"{MIN_ROM_DEG:.0f} deg; rigid preprocessing on")
    for rel, seg_name in REAL_TRIALS:
        path = root / rel
        if not path.is_file():
            print(f"{path}: missing, skipped")
            continue
        data = read_markers(path)
        segs = load_segments(shipped_segments_path(seg_name))
        results = {}
        logging.disable(logging.WARNING)  # low-ROM warnings: the table lists the ROM itself
        try:
            for m in methods:
                results[m] = joint_centres_for_trial(data, segs, m)
        finally:
            logging.disable(logging.NOTSET)
        rom = results[methods[0]].rom_deg
        moving = [j for j in segs.joint_names if rom.get(j, 0.0) >= MIN_ROM_DEG]
        print(f"\n{rel}: {data.n_frames} frames @ {data.rate_hz:g} Hz; joints with ROM >= {MIN_ROM_DEG:.0f} deg: "
              f"{moving or 'none'}")
        print("  ROM (deg): " + ", ".join(f"{j} {rom[j]:.0f}" for j in segs.joint_names if j in rom))
        print("  fit residual (mm) of the moving joints:")
        for j in moving:
            print(f"    {j:<10} " + " ".join(f"{m} {results[m].fits[j].residual_m * 1e3:6.2f}" for m in methods
                                         if j in results[m].fits))
        print(f"  {'bone':<22}" + "".join(f"{m:>16}" for m in methods) + "   best")
        for bone in results[methods[0]].bone_lengths(segs):
            a, b = bone.joint_a, bone.joint_b
            ja, jb = segs.joint(a), segs.joint(b)
            chained = ja.child == jb.parent or jb.child == ja.parent
            if not chained or (a not in moving and b not in moving):
                continue  # sibling joints (same parent) are trivially rigid for parent-fixed methods
            stats = {m: next(x for x in results[m].bone_lengths(segs) if (x.joint_a, x.joint_b) == (a, b))
                     for m in methods}
            best = min(methods, key=lambda m: stats[m].std_m)
            still = b if a in moving else a
            flag = "" if (a in moving and b in moving) else f"  ({still} moves < {MIN_ROM_DEG:.0f} deg)"
            print(f"  {a + '-' + b:<22}" + "".join(f"{stats[m].mean_m * 1e3:8.1f}±{stats[m].std_m * 1e3:5.2f}  "
                                                   for m in methods) + f" {best}{flag}")
        plot_real(data, segs, results, moving, out_dir / f"joint_centres_{path.stem}.png")
    print(f"\nplots in {out_dir}/joint_centres_*.png")


def plot_real(data, segs, results, moving, path: Path) -> None:
    """Per moving joint: child markers and each method's centre over time (x), the centre and
    child-marker trajectories in the parent's frame (3D), and the bone length over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mocap_rt.markers.rigid import fit_rigid_segment, to_local

    joints = moving or list(segs.joint_names[:1])
    fig = plt.figure(figsize=(18, 3.6 * len(joints)))
    colours = plt.get_cmap("tab10")
    t = data.times_s
    for row, j in enumerate(joints):
        joint = segs.joint(j)
        child = data.select(segs.segments[joint.child])
        ax = fig.add_subplot(len(joints), 3, 3 * row + 1)
        for k in range(child.shape[1]):
            ax.plot(t, child[:, k, 0] * 1e3, color="0.7", lw=0.6)
        for n, (m, res) in enumerate(results.items()):
            ax.plot(t, res.centres[:, res.names.index(j), 0] * 1e3, lw=1.0, color=colours(n % 10), label=m)
        ax.set_title(f"{j}: x of {joint.child} markers (grey) and centres")
        ax.set_xlabel("time, s")
        ax.set_ylabel("x, mm")
        ax.legend(fontsize=6)
        # 3D, parent frame: the child markers sweep spheres about the joint centre
        fit = fit_rigid_segment(data.select(segs.segments[joint.parent]))
        ax = fig.add_subplot(len(joints), 3, 3 * row + 2, projection="3d")
        local = to_local(fit.scale, fit.rotation, fit.translation, child) * 1e3  # (F, k, 3) mm
        for k in range(local.shape[1]):
            ax.plot(local[:, k, 0], local[:, k, 1], local[:, k, 2], color="0.6", lw=0.4)
        for n, (m, res) in enumerate(results.items()):
            c = to_local(fit.scale, fit.rotation, fit.translation, res.centres[:, [res.names.index(j)]])[:, 0] * 1e3
            ax.scatter(*np.nanmean(c, axis=0), color=colours(n % 10), s=30, label=m)
        ax.set_title(f"{j} in the {joint.parent} frame (mm)")
        ax.tick_params(labelsize=6)
        ax = fig.add_subplot(len(joints), 3, 3 * row + 3)
        chain = [nb for nb in segs.neighbours(j) if joint.child == segs.joint(nb).parent or
                 segs.joint(nb).child == joint.parent] or list(segs.neighbours(j))
        for nb in chain[:1]:
            for n, (m, res) in enumerate(results.items()):
                d = np.linalg.norm(res.centres[:, res.names.index(j)] - res.centres[:, res.names.index(nb)], axis=1)
                ax.plot(t, d * 1e3, lw=0.8, color=colours(n % 10), label=m)
            ax.set_title(f"bone {j}-{nb} over the trial")
        ax.set_xlabel("time, s")
        ax.set_ylabel("length, mm")
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _time_cli(argv: list[str], n_runs: int) -> tuple[list[float], list[float]]:
    """Wall and process-CPU seconds of ``mocap-rt`` runs in this process (stdout silenced)."""
    from mocap_rt.cli import main as cli_main

    wall, cpu = [], []
    for _ in range(n_runs):
        t0, c0 = time.perf_counter(), time.process_time()
        with open(os.devnull, "w") as sink:
            old, sys.stdout = sys.stdout, sink
            try:
                rc = cli_main(argv)
            finally:
                sys.stdout = old
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        if rc != 0:
            raise RuntimeError(f"mocap-rt {' '.join(argv)} exited {rc}")
    return wall, cpu


def run_speed(n_runs: int) -> None:
    from mocap_rt.markers.io import write_trc
    from mocap_rt.markers.segments import dumps_segments
    from mocap_rt.markers.synthetic import simulate_body

    data, segs, _ = simulate_body(n_frames=1085, noise_m=0.002, gap_frac=0.005, seed=1)
    print("\n(c) speed: 1085-frame trial, 12 joints, end to end (read TRC + rigid + centres + write TRC)")
    logging.disable(logging.WARNING)  # the CLI's low-ROM warnings would swamp the table
    with tempfile.TemporaryDirectory() as tmp:
        trial, seg_path, out = Path(tmp) / "rom.trc", Path(tmp) / "segs.toml", Path(tmp) / "out.trc"
        write_trc(trial, data)
        seg_path.write_text(dumps_segments(segs))
        for method in ("patent", "score"):
            times, cpu = _time_cli(["joint-centres", str(trial), "--segments", str(seg_path), "--out", str(out),
                                    "--method", method, "--overwrite"], n_runs)
            print(f"  synthetic 1085 frames, method {method:<7} wall median {statistics.median(times):.2f} s "
                  f"(min {min(times):.2f}), CPU median {statistics.median(cpu):.2f} s over {n_runs} runs   "
                  f"target <= 2 s: {'met' if statistics.median(times) <= 2.0 else 'MISSED'}")
    real = data_root() / "markers" / REAL_TRIALS[0][0]
    if real.is_file():
        from mocap_rt.markers.segments import shipped_segments_path

        with tempfile.TemporaryDirectory() as tmp:
            times, cpu = _time_cli(["joint-centres", str(real), "--segments",
                                    str(shipped_segments_path(REAL_TRIALS[0][1])), "--out", str(Path(tmp) / "o.trc"),
                                    "--overwrite"], n_runs)
        print(f"  real {real.name} (1690 frames, 12 joints), method patent: wall median {statistics.median(times):.2f} s"
              f" (min {min(times):.2f}), CPU median {statistics.median(cpu):.2f} s over {n_runs} runs")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench_joint_centres", description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=100, help="trials per cell (patent: 100)")
    ap.add_argument("--frames", type=int, default=100, help="frames per synthetic trial")
    ap.add_argument("--noise", default="0,1,2,3,4,5", help="noise levels, %% of segment length")
    ap.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods")
    ap.add_argument("--seed", type=int, default=2008)
    ap.add_argument("--runs", type=int, default=5, help="speed runs (median)")
    ap.add_argument("--out", type=Path, default=HERE / "out")
    ap.add_argument("--skip-synthetic", action="store_true")
    ap.add_argument("--skip-real", action="store_true")
    ap.add_argument("--skip-speed", action="store_true")
    args = ap.parse_args(argv)
    methods = [m for m in args.methods.split(",") if m]
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        ap.error(f"unknown methods {unknown}")
    noise = [float(x) / 100.0 for x in args.noise.split(",")]
    args.out.mkdir(parents=True, exist_ok=True)
    if not args.skip_synthetic:
        t0 = time.perf_counter()
        errors = run_synthetic(args.trials, args.frames, noise, methods, args.seed)
        print(f"synthetic: {args.trials} trials x {len(CONDITIONS)} conditions x {len(noise)} noise levels, "
              f"{args.frames} frames each, {time.perf_counter() - t0:.0f} s")
        wins = print_synthetic(errors, noise, methods)
        if max(noise) > 0:
            print_edr(errors, noise, methods)
        graded = {k: v for k, v in wins.items() if k[2] > 0}
        print(f"\npatent (with step A) <= every baseline (best of raw/rigid) in {sum(graded.values())}/{len(graded)}"
              " noisy cells")
        print(f"plot: {plot_synthetic(errors, noise, methods, args.out)}")
    if not args.skip_real:
        run_real(methods, args.out)
    if not args.skip_speed:
        try:
            run_speed(args.runs)
        finally:
            logging.disable(logging.NOTSET)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
