"""Benchmark of ``imucal calibrate``: whole process and each stage, on synthetic sessions of
growing length and on the real imu_tk Xsens recording.

    .venv/bin/python bench/run.py            # every size (a few minutes)
    .venv/bin/python bench/run.py --quick    # 2 and 20 minutes and the Xsens file

For every size it

* generates a session with the project's own generator (``imucal.synth.make_session``, about
  5 s per pose: 3 s still, 2 s turning) and writes it as .mat
  (``imucal.io.export.write_session_mat``)
  into a temporary directory;
* times each stage in a fresh worker process (load, detect, accelerometer incl. the L-curve,
  group, gyroscope, apply + quality figures, JSON, .rrd), by wrapping the functions
  ``imucal.pipeline.calibrate`` calls, so the stages are the pipeline's own; the minimum over
  repeats is reported, with the worker's RSS high-water mark after each stage and the peak
  memory each stage allocates (tracemalloc, in an extra untimed pass);
* times the whole command line, ``imucal calibrate SESSION --out calib.json`` and again with
  ``--rrd run.rrd``, as child processes: wall time, CPU time (user + sys) and max RSS of the
  child from ``os.wait4`` (the per-child form of ``getrusage(RUSAGE_CHILDREN)``).

Side by side in the same run, on a short session, it times naive versions of the two stages
that matter most (a Python loop over windows for the detector statistic, a Python loop over
samples for one RK4 evaluation of the gyroscope cost) against the product's, and the gyroscope
Jacobian by the methods on offer. Bytecode is compiled first, as after any first run.
Targets are printed as measured, never asserted.

Results go to stdout and to ``bench/results.md`` (``--out``).
"""

from __future__ import annotations

import argparse
import compileall
import contextlib
import datetime as _dt
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent
XSENS = ROOT.parent / "shared" / "data" / "imu_tk_xsens"
STAGES = ("load", "detect", "accel", "group", "gyro", "apply", "quality", "other", "json",
          "rrd")
STAGE_TITLES = {
    "load": "load", "detect": "detect", "accel": "accel + L-curve", "group": "group",
    "gyro": "gyro", "apply": "apply", "quality": "quality figures", "other": "rest of calibrate",
    "json": "write JSON", "rrd": "write .rrd",
}


@dataclass(frozen=True)
class Size:
    key: str
    title: str
    minutes: float | None = None  # None: the real Xsens recording
    acc_rate: float = 100.0
    gyro_rate: float = 100.0
    seed: int = 1

    @property
    def synthetic(self) -> bool:
        return self.minutes is not None

    @property
    def poses(self) -> int:
        return max(int(round(self.minutes * 60.0 / 5.0)), 2)


SIZES = [
    Size("2min", "2 min @ 100 Hz", 2, 100, 100),
    Size("20min", "20 min @ 100 Hz", 20, 100, 100),
    Size("60min", "60 min @ 100 Hz", 60, 100, 100),
    Size("90min", "90 min @ 100 Hz", 90, 100, 100),
    Size("60min_1k", "60 min @ 1000/140 Hz", 60, 1000, 140),
    Size("90min_1k", "90 min @ 1000/140 Hz", 90, 1000, 140),
    Size("xsens", "imu_tk_xsens (real)"),
]
QUICK = ("2min", "20min", "xsens")
# Pairs whose time per sample shows whether a stage is linear in the signal length.
LINEARITY_PAIRS = [("20min", "60min"), ("20min", "90min"), ("60min_1k", "90min_1k")]


# --- the worker: stages of one session in-process ------------------------------------------------


def _maxrss_mb(who: int = resource.RUSAGE_SELF) -> float:
    return resource.getrusage(who).ru_maxrss / 1024.0  # Linux: kilobytes


class StageClock:
    """Wraps the functions ``imucal.pipeline.calibrate`` calls and adds up time per stage.

    A wrapper called inside another wrapped call is not counted twice (only the outermost
    stage gets the time), so the stages partition the call.
    """

    def __init__(self, trace_memory: bool = False):
        self.times: dict[str, float] = {}
        self.rss: dict[str, float] = {}
        self.mem: dict[str, float] = {}
        self.trace_memory = trace_memory
        self._depth = 0

    @contextlib.contextmanager
    def stage(self, name: str):
        if self._depth:
            yield
            return
        self._depth += 1
        if self.trace_memory:
            import tracemalloc

            base = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.times[name] = self.times.get(name, 0.0) + time.perf_counter() - t0
            self.rss[name] = _maxrss_mb()
            if self.trace_memory:
                peak = (tracemalloc.get_traced_memory()[1] - base) / 2**20
                self.mem[name] = max(self.mem.get(name, 0.0), peak)
            self._depth -= 1

    def wrap(self, name: str, fn):
        def wrapped(*args, **kwargs):
            with self.stage(name):
                return fn(*args, **kwargs)

        wrapped.__wrapped__ = fn
        return wrapped


def _patch_pipeline(clock: StageClock) -> list[str]:
    """Point the names pipeline.calibrate uses at timing wrappers; return what was missing."""
    import imucal.pipeline as pl
    import imucal.stages.apply

    stages = {"tune_detector": "detect", "calibrate_accelerometer": "accel",
              "group_blocks": "group", "block_mean_cov": "gyro", "calibrate_gyroscope": "gyro",
              "quality_figures": "quality", "distinct_orientations": "quality"}
    missing = []
    for attr, stage in stages.items():
        fn = getattr(pl, attr, None)
        if fn is None:
            missing.append(attr)
            continue
        fn = getattr(fn, "__wrapped__", fn)
        setattr(pl, attr, clock.wrap(stage, fn))
    cls = imucal.stages.apply.Calibration
    apply = getattr(cls.apply, "__wrapped__", cls.apply)
    cls.apply = clock.wrap("apply", apply)
    return missing


def worker(args: argparse.Namespace) -> None:
    """Time the stages of one session in this process; print one JSON object."""
    import imucal

    out_dir = Path(args.tmp)
    load_kw = {"gyro_path": args.gyro} if args.gyro else {}
    save_recording = None
    if args.rrd:
        try:
            from viewer.recording import save_recording
        except Exception as e:  # the viewer is optional for the benchmark
            print(f"bench: no .rrd stage ({e.__class__.__name__}: {e})", file=sys.stderr)
    runs = []
    info: dict = {}
    n_passes = args.repeat + (1 if args.trace_memory else 0)
    for i in range(n_passes):
        tracing = args.trace_memory and i == n_passes - 1
        if tracing:
            import tracemalloc

            tracemalloc.start()
        clock = StageClock(trace_memory=tracing)
        missing = _patch_pipeline(clock)
        with clock.stage("load"):
            session = imucal.load_session(args.session, **load_kw)
        t0 = time.perf_counter()
        result = imucal.calibrate(session)
        total = time.perf_counter() - t0
        inner = sum(clock.times.get(s, 0.0)
                    for s in ("detect", "accel", "group", "gyro", "apply", "quality"))
        clock.times["other"] = total - inner
        clock.rss["other"] = _maxrss_mb()
        clock.times["calibrate"] = total
        with clock.stage("json"):
            imucal.save_calibration(result, out_dir / "calib.json")
        if save_recording is not None:
            rrd = out_dir / "run.rrd"
            with clock.stage("rrd"):
                save_recording(result, rrd)
            info["rrd_mb"] = rrd.stat().st_size / 1e6
            rrd.unlink()
        if tracing:
            tracemalloc.stop()
            info["mem_mb"] = clock.mem
        else:
            runs.append(clock.times)
            info.setdefault("rss_mb", clock.rss)
        info.update(missing=missing, acc_samples=len(session.acc),
                    gyro_samples=len(session.gyro) if session.has_gyro else 0,
                    blocks=len(result.detection.blocks), segments=len(result.segments),
                    acc_nfev=sum(s.acc.report.nfev for s in result.segments),
                    gyro_nfev=sum(s.gyro.report.nfev for s in result.segments if s.gyro),
                    group_tests=len(result.grouping.tests))
        del result, session
    stages = {k: min(r[k] for r in runs) for k in runs[0]}
    print(json.dumps({"stages": stages, "all": runs, "maxrss_mb": _maxrss_mb(), **info}))


# --- whole-process runs --------------------------------------------------------------------------


def run_child(cmd: list[str], cwd: Path | None = None) -> dict:
    """Run a command to its end; wall time, CPU time and max RSS of that child alone."""
    with tempfile.TemporaryFile() as fo, tempfile.TemporaryFile() as fe:
        t0 = time.perf_counter()
        p = subprocess.Popen(cmd, cwd=cwd, stdout=fo, stderr=fe)
        _, status, ru = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t0
        p.returncode = os.waitstatus_to_exitcode(status)
        fo.seek(0)
        fe.seek(0)
        out, err = fo.read(), fe.read()
    return {"wall": wall, "cpu": ru.ru_utime + ru.ru_stime, "user": ru.ru_utime,
            "sys": ru.ru_stime, "maxrss_mb": ru.ru_maxrss / 1024.0, "rc": p.returncode,
            "stdout": out.decode(errors="replace"), "stderr": err.decode(errors="replace")}


def best_of(cmd: list[str], repeat: int, cwd: Path | None = None) -> dict:
    runs = [run_child(cmd, cwd) for _ in range(repeat)]
    bad = [r for r in runs if r["rc"] != 0]
    if bad:
        return {"error": f"exit {bad[0]['rc']}: {bad[0]['stderr'].strip()[-300:]}"}
    return {"wall": min(r["wall"] for r in runs), "cpu": min(r["cpu"] for r in runs),
            "user": min(r["user"] for r in runs), "sys": min(r["sys"] for r in runs),
            "maxrss_mb": max(r["maxrss_mb"] for r in runs),
            "walls": [r["wall"] for r in runs], "cpus": [r["cpu"] for r in runs]}


def cli_available() -> str | None:
    """Why the command line cannot be timed, or None when it can."""
    exe = VENV_BIN / "imucal"
    if not exe.exists():
        return f"{exe} not installed"
    r = run_child([str(exe), "calibrate", "--help"])
    if r["rc"] != 0:
        return f"`imucal calibrate --help` failed: {r['stderr'].strip()[-200:]}"
    return None


# --- sessions ------------------------------------------------------------------------------------


def make_session_file(size: Size, directory: Path) -> tuple[list[str], float]:
    """Write the session; return the CLI arguments naming it and the time it took."""
    if not size.synthetic:
        return [str(XSENS / "xsens_acc.mat"), "--gyro", str(XSENS / "xsens_gyro.mat")], 0.0
    path = directory / (f"{size.key}_s{size.seed}_p{size.poses}_{size.acc_rate:g}_"
                        f"{size.gyro_rate:g}.mat")
    if path.exists():
        return [str(path)], 0.0
    # In a child process: this one must stay small, or every child forked from it later
    # starts with (and reports) its resident memory.
    code = ("import sys; from imucal.io.export import write_session_mat; "
            "from imucal.synth import make_session; "
            f"s, _ = make_session(poses={size.poses}, seed={size.seed}, still=3.0, move=2.0, "
            f"acc_rate={size.acc_rate!r}, gyro_rate={size.gyro_rate!r}); "
            "write_session_mat(sys.argv[1], s)")
    tmp = path.with_suffix(".partial.mat")
    r = run_child([sys.executable, "-c", code, str(tmp)], cwd=ROOT)
    if r["rc"] != 0:
        raise RuntimeError(f"generating {size.title} failed: {r['stderr'][-500:]}")
    tmp.rename(path)
    return [str(path)], r["wall"]


def stage_run(size: Size, files: list[str], tmp: Path, repeat: int, rrd: bool,
              trace_memory: bool) -> dict:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", files[0],
           "--tmp", str(tmp), "--repeat", str(repeat)]
    if len(files) == 3:
        cmd += ["--gyro", files[2]]
    if rrd:
        cmd.append("--rrd")
    if trace_memory:
        cmd.append("--trace-memory")
    r = run_child(cmd, cwd=ROOT)
    if r["rc"] != 0:
        return {"error": r["stderr"].strip()[-500:]}
    d = json.loads(r["stdout"].strip().splitlines()[-1])
    d["worker_wall"] = r["wall"]
    return d


# --- naive baselines and the Jacobian ------------------------------------------------------------


def naive_statistic(acc, window: int):
    """M1 the straightforward way: the variance of every centred window, one at a time
    (O(N w), as the thesis's code), mirrored at the ends like the product's."""
    import numpy as np

    n = len(acc)
    h = window // 2
    x = np.asarray(acc, dtype=np.float64)
    padded = np.concatenate([x[h:0:-1], x, x[-2:-h - 2:-1]])  # mirror, edge not repeated
    out = np.empty(n)
    for i in range(n):
        v = np.var(padded[i:i + window], axis=0, ddof=1)
        out[i] = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    return out


def naive_gyro_cost(w_raw, t, starts, ends, M, b, u_prev, u_meas):
    """One evaluation of the M5 residuals the straightforward way: for every transition, a
    Python loop over its samples taking classic RK4 steps of dq/dt = 1/2 q (x) (0, w) with the
    rate at the half step the mean of the two samples, renormalising each step."""
    import math

    import numpy as np

    def qmul(p, q):
        return (p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3],
                p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2],
                p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1],
                p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0])

    def deriv(q, w):
        d = qmul(q, (0.0, w[0], w[1], w[2]))
        return (0.5 * d[0], 0.5 * d[1], 0.5 * d[2], 0.5 * d[3])

    def axpy(q, h, k):
        return (q[0] + h * k[0], q[1] + h * k[1], q[2] + h * k[2], q[3] + h * k[3])

    Ml = M.tolist()
    bl = b.tolist()
    wl = w_raw.tolist()
    tl = t.tolist()

    def cal(i):
        r = wl[i]
        d = (r[0] - bl[0], r[1] - bl[1], r[2] - bl[2])
        return tuple(Ml[k][0] * d[0] + Ml[k][1] * d[1] + Ml[k][2] * d[2] for k in range(3))

    res = []
    for k in range(len(starts)):
        q = (1.0, 0.0, 0.0, 0.0)
        for i in range(int(starts[k]), int(ends[k])):
            h = tl[i + 1] - tl[i]
            w0, w1 = cal(i), cal(i + 1)
            wm = tuple(0.5 * (w0[j] + w1[j]) for j in range(3))
            k1 = deriv(q, w0)
            k2 = deriv(axpy(q, h / 2, k1), wm)
            k3 = deriv(axpy(q, h / 2, k2), wm)
            k4 = deriv(axpy(q, h, k3), w1)
            q = tuple(q[j] + h / 6 * (k1[j] + 2 * k2[j] + 2 * k3[j] + k4[j]) for j in range(4))
            n = math.sqrt(sum(c * c for c in q))
            q = tuple(c / n for c in q)
        # R^T u: rotate u_prev by the conjugate of q
        qc = (q[0], -q[1], -q[2], -q[3])
        u = u_prev[k]
        v = qmul(qmul(qc, (0.0, u[0], u[1], u[2])), q)
        res.extend([u_meas[k][0] - v[1], u_meas[k][1] - v[2], u_meas[k][2] - v[3]])
    return np.array(res)


def _best_time(fn, repeat: int, min_time: float = 0.2) -> float:
    """Minimum over ``repeat`` rounds of the mean time of enough calls to fill ``min_time``."""
    fn()
    t0 = time.perf_counter()
    fn()
    one = time.perf_counter() - t0
    n = max(1, int(min_time / max(one, 1e-9)))
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n)
    return best


def gyro_problem(minutes: float, acc_rate: float = 100.0, gyro_rate: float = 100.0):
    """A calibrated synthetic session and the pieces of its gyroscope cost."""
    import numpy as np

    import imucal
    from imucal.models import GYRO_THETA0, SensorModel, gyro_T
    from imucal.stages.gyro_transitions import Transitions
    from imucal.synth import make_session

    session, _ = make_session(poses=max(int(round(minutes * 12)), 2), seed=1, still=3.0,
                              move=2.0, acc_rate=acc_rate, gyro_rate=gyro_rate)
    r = imucal.calibrate(session, single_segment=True)
    g = r.segments[0].gyro
    tr = Transitions(session.gyro, session.t_gyro, r.block_times)
    bias = g.model.b

    def model_of(theta):
        return SensorModel(T=gyro_T(theta), K=theta[6:9], b=bias)

    def res(theta):
        return (g.u_meas - tr.predict(model_of(theta), g.u_prev)).ravel()

    theta = np.asarray(g.report.theta, float)
    return dict(session=session, result=r, tr=tr, res=res, theta=theta, model_of=model_of,
                u_prev=g.u_prev, u_meas=g.u_meas, theta0=GYRO_THETA0)


def baselines(repeat: int) -> dict:
    """Naive vs product, side by side on the same short session (2 min at 100 Hz)."""
    import numpy as np

    from imucal.numerics.windows import rolling_variance
    from imucal.stages.detect import combine_variances

    out = {}
    p = gyro_problem(2.0)
    session, tr = p["session"], p["tr"]
    window = p["result"].detection.window
    acc = session.acc

    def product_stat():
        return combine_variances(rolling_variance(acc, window), "thesis")

    ref = product_stat()
    naive = naive_statistic(acc, window)
    out["detector"] = {
        "samples": len(acc), "window": window,
        "naive": _best_time(lambda: naive_statistic(acc, window), max(repeat, 2), 0.0),
        "product": _best_time(product_stat, repeat),
        "max_rel_diff": float(np.max(np.abs(naive - ref) / np.maximum(np.abs(ref), 1e-300))),
    }
    theta = p["theta"]
    model = p["model_of"](theta)

    def naive_cost():
        return naive_gyro_cost(session.gyro, session.t_gyro, tr.starts, tr.ends, model.matrix,
                               model.b, p["u_prev"], p["u_meas"])

    r_naive = naive_cost()
    r_prod = p["res"](theta)
    out["gyro_cost"] = {
        "transitions": len(tr), "steps": int(np.sum(tr.ends - tr.starts)),
        "naive": _best_time(naive_cost, max(repeat, 2), 0.0),
        "product": _best_time(lambda: p["res"](theta), repeat),
        "max_abs_diff": float(np.max(np.abs(r_naive - r_prod))),
    }
    return out


def complex_step_jacobian(p: dict, theta, h: float = 1e-20):
    """Jacobian of the gyroscope residuals by complex steps: every operation of the cost (RK4
    steps, quaternion products, normalisation as q / sqrt(sum q^2)) is analytic, so
    ``Im r(theta + i h e_j) / h`` is the derivative to rounding, with no step-size error.
    One complex evaluation per parameter, each about four real ones."""
    import numba
    import numpy as np

    from imucal.numerics.rk4 import kernels

    tr, u_prev, model_of = p["tr"], p["u_prev"], p["model_of"]
    turns = tr.turns
    integrate = numba.njit(kernels.integrate.py_func)  # the product's loop, for complex models
    cols = []
    for j in range(len(theta)):
        th = np.asarray(theta, complex).copy()
        th[j] += 1j * h
        model = model_of(th)
        M = np.asarray(model.T, complex) * np.asarray(model.K, complex)[None, :]
        b = np.asarray(model.b, complex)
        q = np.empty((1, len(tr), 4), complex)
        integrate(turns.x, turns.t, turns.starts, turns.ends, M[None], b[None], q)
        q = q[0]
        q = q / np.sqrt(np.sum(q * q, axis=-1, keepdims=True))
        w_, x_, y_, z_ = q.T
        R = np.stack([
            np.stack([1 - 2 * (y_ * y_ + z_ * z_), 2 * (x_ * y_ - w_ * z_),
                      2 * (x_ * z_ + w_ * y_)], -1),
            np.stack([2 * (x_ * y_ + w_ * z_), 1 - 2 * (x_ * x_ + z_ * z_),
                      2 * (y_ * z_ - w_ * x_)], -1),
            np.stack([2 * (x_ * z_ - w_ * y_), 2 * (y_ * z_ + w_ * x_),
                      1 - 2 * (x_ * x_ + y_ * y_)], -1),
        ], axis=-2)
        pred = np.einsum("kji,kj->ki", R, u_prev)
        cols.append(-pred.imag.ravel() / h)  # r = u_meas - pred
    return np.column_stack(cols)


def jacobian_methods(repeat: int, minutes: float) -> dict:
    """The gyroscope Jacobian (data part, 3K x 9) by each method: cost of one Jacobian, its
    error against the complex-step one (exact to rounding), and a whole gyroscope fit with it
    (time, residual evaluations, and how far its solution lands from the product's, in
    standard errors)."""
    import numpy as np
    from scipy.optimize._numdiff import approx_derivative

    from imucal.numerics.least_squares import fit_tikhonov

    p = gyro_problem(minutes)
    res, theta = p["res"], p["theta"]
    theta0 = p["theta0"]
    lam = p["result"].settings.gyro_lambda

    def _fd2(th):  # forward differences, scipy's "2-point" rule (fit_tikhonov's with jac=None)
        return approx_derivative(res, np.asarray(th, float), method="2-point")

    def _variational(th):  # the product's own (Transitions.jacobian)
        return p["tr"].jacobian(p["model_of"], np.asarray(th, float), p["u_prev"])

    methods = {
        "variational equation, one compiled pass (in use)": (_variational, _variational),
        "2-point FD (used before)": (_fd2, None),
        "3-point FD": (lambda th: approx_derivative(res, th, method="3-point"),
                       lambda th: approx_derivative(res, th, method="3-point")),
        "complex step (exact)": (lambda th: complex_step_jacobian(p, th),
                                 lambda th: complex_step_jacobian(p, th)),
    }
    ref = complex_step_jacobian(p, theta)
    out = {"transitions": len(p["tr"]), "minutes": minutes,
           "one_residual": _best_time(lambda: res(theta), repeat)}
    base = None
    for name, (jac_fn, fit_jac) in methods.items():
        J = jac_fn(theta)
        t_jac = _best_time(lambda jac_fn=jac_fn: jac_fn(theta), repeat)
        calls = [0]

        def counted(th, calls=calls):
            calls[0] += 1
            return res(th)

        t_fit = float("inf")
        for _ in range(max(repeat, 1)):
            calls[0] = 0
            t0 = time.perf_counter()
            rep = fit_tikhonov(counted, fit_jac, theta0, theta0, lam)
            t_fit = min(t_fit, time.perf_counter() - t0)
        if base is None:
            base = rep
        shift = float(np.max(np.abs(rep.theta - base.theta) / np.maximum(base.std, 1e-300)))
        out[name] = {"time": t_jac,
                     "rel_err": float(np.linalg.norm(J - ref) / np.linalg.norm(ref)),
                     "fit_time": t_fit, "fit_residual_evals": calls[0],
                     "fit_shift_std": shift}
    return out


STARTUP_STEPS = [
    ("python -c pass", "pass"),
    ("+ numpy", "import numpy"),
    ("+ imucal.cli (all `imucal --help` loads)", "import numpy, imucal.cli"),
    ("+ imucal.io.load", "import numpy, imucal.cli, imucal.io.load"),
    ("+ imucal.pipeline, imucal.io.calibration_file",
     "import numpy, imucal.cli, imucal.io.load, imucal.pipeline, imucal.io.calibration_file"),
    ("(for comparison) + polars", "import numpy, imucal.cli, imucal.io.load, imucal.pipeline, "
     "imucal.io.calibration_file, polars"),
    ("(for comparison) + scipy.optimize",
     "import numpy, imucal.cli, imucal.io.load, imucal.pipeline, imucal.io.calibration_file, "
     "scipy.optimize"),
]


def startup(repeat: int) -> list[dict]:
    """CPU time of the imports a command-line run pays before any work, cumulatively."""
    out = []
    for label, code in STARTUP_STEPS:
        r = best_of([sys.executable, "-c", code], max(repeat, 3))
        out.append({"label": label, "cpu": r.get("cpu"), "wall": r.get("wall")})
    return out


# --- report --------------------------------------------------------------------------------------


def machine_info() -> dict:
    cpu = platform.processor() or "unknown"
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    ram = "unknown"
    with contextlib.suppress(OSError, ValueError, IndexError):
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                ram = f"{int(line.split()[1]) / 2**20:.1f} GiB"
                break
    from importlib import metadata

    versions = {"python": platform.python_version()}
    for pkg in ("numpy", "scipy", "polars", "rerun-sdk"):
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = "not installed"
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    return {"cpu": cpu, "cores": os.cpu_count(), "usable_cores": affinity, "ram": ram,
            "os": f"{platform.system()} {platform.release()}",
            "date": _dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z"),
            "versions": versions}


def _f(x, spec=".2f", none="–") -> str:
    return none if x is None else format(x, spec)


def render(info: dict, rows: list[dict], extra: dict, args: argparse.Namespace) -> str:
    L = []
    v = info["versions"]
    L.append("# imucal benchmark\n")
    L.append(f"- date: {info['date']}")
    L.append(f"- machine: {info['cpu']}, {info['cores']} cores "
             f"({info['usable_cores']} usable), {info['ram']} RAM, {info['os']}")
    L.append("- versions: " + ", ".join(f"{k} {val}" for k, val in v.items()))
    L.append(f"- command: `{' '.join(['bench/run.py'] + sys.argv[1:])}`; every time is the "
             f"minimum of {args.repeat} runs (other processes share the machine)")
    L.append("- sessions: `imucal.synth.make_session(poses=minutes*12, seed=1, still=3.0, "
             "move=2.0, acc_rate, gyro_rate)` written with `write_session_mat` (compressed .mat "
             "v5); 90 min @ 100 Hz is extra, so that 20 -> 90 min is measured at one rate\n")

    L.append("## Whole process (`imucal calibrate SESSION --out calib.json [--rrd run.rrd]`)\n")
    L.append("| session | acc / gyro samples | blocks | wall s | CPU s | max RSS MB "
             "| wall s with --rrd | max RSS MB with --rrd | .rrd MB |")
    L.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        w = r.get("stage", {})
        c, cr = r.get("cli") or {}, r.get("cli_rrd") or {}
        L.append(f"| {r['title']} | {w.get('acc_samples', '–'):,} / {w.get('gyro_samples', 0):,} "
                 f"| {w.get('blocks', '–')} | {_f(c.get('wall'))} | {_f(c.get('cpu'))} "
                 f"| {_f(c.get('maxrss_mb'), '.0f')} | {_f(cr.get('wall'))} "
                 f"| {_f(cr.get('maxrss_mb'), '.0f')} | {_f(cr.get('rrd_mb'), '.1f')} |")
    for r in rows:
        for k in ("cli", "cli_rrd"):
            if (r.get(k) or {}).get("error"):
                L.append(f"\n{r['title']} {k}: {r[k]['error']}")
    if extra.get("cli_note"):
        L.append(f"\nCommand line not timed: {extra['cli_note']}")
    h = extra.get("help")
    if h:
        L.append(f"\nStart-up: `imucal --help` {h['wall']:.3f} s wall, {h['cpu']:.3f} s CPU; "
                 f"`python -c 'import imucal'` {extra['import']['wall']:.3f} s wall.")

    L.append("\n## Stages, in-process (seconds)\n")
    L.append("| session | " + " | ".join(STAGE_TITLES[s] for s in STAGES)
             + " | calibrate() | acc nfev | gyro nfev |")
    L.append("|---|" + "---:|" * (len(STAGES) + 3))
    for r in rows:
        w = r.get("stage", {})
        if "stages" not in w:
            L.append(f"| {r['title']} | error: {w.get('error', '?')[-200:]} |")
            continue
        s = w["stages"]
        L.append(f"| {r['title']} | " + " | ".join(_f(s.get(k), ".3f") for k in STAGES)
                 + f" | {_f(s.get('calibrate'), '.3f')} | {w.get('acc_nfev')} "
                 f"| {w.get('gyro_nfev')} |")

    L.append("\n## Memory per stage (MB): peak allocated during the stage (tracemalloc) / "
             "worker RSS high-water mark after it\n")
    L.append("| session | " + " | ".join(STAGE_TITLES[s] for s in STAGES) + " |")
    L.append("|---|" + "---:|" * len(STAGES))
    for r in rows:
        w = r.get("stage", {})
        if "stages" not in w:
            continue
        mem, rss = w.get("mem_mb", {}), w.get("rss_mb", {})
        L.append(f"| {r['title']} | " + " | ".join(
            f"{_f(mem.get(k), '.0f')} / {_f(rss.get(k), '.0f')}" for k in STAGES) + " |")

    lin = linearity(rows)
    if lin:
        L.append("\n## Linearity: time per sample (µs), and its ratio big / small "
                 "(target: within 1.3x)\n")
        L.append("| stage (per sample of) | " + " | ".join(
            f"{a} -> {b}" for a, b in [(p[0], p[1]) for p in lin["pairs"]]) + " |")
        L.append("|---|" + "---:|" * len(lin["pairs"]))
        for stage, cells in lin["table"].items():
            L.append(f"| {stage} | " + " | ".join(cells) + " |")

    b = extra.get("baselines")
    if b:
        d, g = b["detector"], b["gyro_cost"]
        L.append("\n## Naive baselines, same run, same 2-minute session\n")
        L.append("| stage | naive | product | speed-up | agreement |")
        L.append("|---|---:|---:|---:|---|")
        L.append(f"| detector statistic M1 ({d['samples']:,} samples, window {d['window']}): "
                 f"Python loop over windows vs rolling sums | {d['naive'] * 1e3:.1f} ms "
                 f"| {d['product'] * 1e3:.3f} ms | {d['naive'] / d['product']:.0f}x "
                 f"| max rel. diff {d['max_rel_diff']:.1e} |")
        L.append(f"| one gyroscope cost evaluation ({g['transitions']} transitions, "
                 f"{g['steps']:,} RK4 steps): Python loop over samples vs vectorised "
                 f"| {g['naive'] * 1e3:.1f} ms | {g['product'] * 1e3:.3f} ms "
                 f"| {g['naive'] / g['product']:.0f}x | max abs diff {g['max_abs_diff']:.1e} |")
    j = extra.get("jacobian")
    if j:
        L.append(f"\n## Gyroscope Jacobian ({j['minutes']:g} min session, {j['transitions']} "
                 f"transitions; one residual evaluation {j['one_residual'] * 1e3:.2f} ms)\n")
        L.append("| method | one Jacobian | in residual evaluations | error vs complex step "
                 "| whole gyroscope fit | real residual evaluations in it | solution shift "
                 "(std errors) |")
        L.append("|---|---:|---:|---:|---:|---:|---:|")
        for name, m in j.items():
            if isinstance(m, dict):
                L.append(f"| {name} | {m['time'] * 1e3:.1f} ms "
                         f"| {m['time'] / j['one_residual']:.1f} | {m['rel_err']:.1e} "
                         f"| {m['fit_time']:.2f} s | {m['fit_residual_evals']} "
                         f"| {m['fit_shift_std']:.1e} |")
    st = extra.get("startup")
    if st:
        L.append("\n## Start-up: CPU time of the imports a command-line run pays (cumulative)\n")
        L.append("| imports | CPU s | wall s |")
        L.append("|---|---:|---:|")
        for row in st:
            L.append(f"| {row['label']} | {_f(row['cpu'], '.3f')} | {_f(row['wall'], '.3f')} |")

    if extra.get("compare"):
        L += render_compare(rows, extra["compare"])

    L.append("\n## Targets (measured, not asserted)\n")
    for line in targets(rows, extra, lin):
        L.append(f"- {line}")
    return "\n".join(L) + "\n"


def render_compare(rows: list[dict], old: dict) -> list[str]:
    """Before -> after (speed-up) against an earlier run's ``--json`` file."""
    by_old = {r["key"]: r for r in old.get("rows", [])}
    L = [f"\n## Against an earlier run: {old.get('label', 'baseline')}\n",
         "Each cell: before -> after (ratio before / after).\n"]
    stages = ("detect", "accel", "group", "gyro", "apply", "calibrate")
    titles = {**STAGE_TITLES, "apply": "apply + quality", "calibrate": "calibrate()"}
    L.append("| session | process wall s | process CPU s | max RSS MB | "
             + " | ".join(titles[s] for s in stages) + " |")
    L.append("|---|" + "---:|" * (3 + len(stages)))

    def cell(a, b, spec=".2f"):
        if a is None or b is None:
            return "–"
        return f"{a:{spec}} -> {b:{spec}} ({a / b:.1f}x)" if b else f"{a:{spec}} -> {b:{spec}}"

    for r in rows:
        o = by_old.get(r["key"])
        if not o:
            continue
        c, oc = r.get("cli") or {}, o.get("cli") or {}
        st, ost = r.get("stage", {}).get("stages", {}), o.get("stage", {}).get("stages", {})
        if "quality" in st and "quality" not in ost:  # the earlier run timed them together
            st = {**st, "apply": st.get("apply", 0.0) + st["quality"]}
        L.append(f"| {r['title']} | {cell(oc.get('wall'), c.get('wall'))} "
                 f"| {cell(oc.get('cpu'), c.get('cpu'))} "
                 f"| {cell(oc.get('maxrss_mb'), c.get('maxrss_mb'), '.0f')} | "
                 + " | ".join(cell(ost.get(s), st.get(s), ".3f") for s in stages) + " |")
    return L


def linearity(rows: list[dict]) -> dict | None:
    by = {r["key"]: r.get("stage", {}) for r in rows}
    pairs = [(a, b) for a, b in LINEARITY_PAIRS
             if "stages" in by.get(a, {}) and "stages" in by.get(b, {})]
    if not pairs:
        return None
    table: dict[str, list[str]] = {}
    worst = {}
    for stage in (*STAGES, "calibrate"):
        per = "gyro" if stage == "gyro" else "acc"
        cells = []
        for a, b in pairs:
            sa, sb = by[a]["stages"].get(stage), by[b]["stages"].get(stage)
            if not sa or not sb:
                cells.append("–")
                continue
            na, nb = by[a][f"{per}_samples"], by[b][f"{per}_samples"]
            ua, ub = sa / na * 1e6, sb / nb * 1e6
            ratio = ub / ua
            worst[stage] = max(worst.get(stage, 0.0), ratio)
            cells.append(f"{ua:.3f} -> {ub:.3f} ({ratio:.2f}x)")
        table[f"{STAGE_TITLES.get(stage, 'calibrate() total')} ({per})"] = cells
    return {"pairs": pairs, "table": table, "worst": worst}


def targets(rows: list[dict], extra: dict, lin: dict | None) -> list[str]:
    out = []
    by = {r["key"]: r for r in rows}

    def mark(ok: bool) -> str:
        return "met" if ok else "NOT met"

    r = by.get("60min_1k")
    if r and (r.get("cli") or {}).get("wall") is not None:
        c = r["cli"]
        out.append(f"60 min @ 1000/140 Hz, .mat to calib.json: {c['wall']:.2f} s wall "
                   f"(< 10 s: {mark(c['wall'] < 10)}), {c['maxrss_mb']:.0f} MB peak "
                   f"(< 1.5 GB: {mark(c['maxrss_mb'] < 1536)})")
        cr = r.get("cli_rrd") or {}
        if cr.get("wall") is not None:
            out.append(f"the same with the .rrd: {cr['wall']:.2f} s wall (< 25 s: "
                       f"{mark(cr['wall'] < 25)}), file {cr['rrd_mb']:.1f} MB (< 150 MB: "
                       f"{mark(cr['rrd_mb'] < 150)})")
    r = by.get("xsens")
    if r and (r.get("cli") or {}).get("cpu") is not None:
        c = r["cli"]
        out.append(f"imu_tk_xsens, whole process to calib.json: {c['cpu']:.3f} s CPU "
                   f"(user {c['user']:.3f} + sys {c['sys']:.3f}; < 0.6 s: {mark(c['cpu'] < 0.6)})"
                   f", {c['wall']:.3f} s wall")
    h = extra.get("help")
    if h:
        out.append(f"`imucal --help`: {h['wall']:.3f} s wall (< 0.5 s: {mark(h['wall'] < 0.5)})")
    if lin:
        bad = {k: v for k, v in lin["worst"].items() if v > 1.3}
        worst = max(lin["worst"].items(), key=lambda kv: kv[1])
        out.append("every stage linear (time per sample within 1.3x over the pairs above): "
                   f"{mark(not bad)}; worst {STAGE_TITLES.get(worst[0], worst[0])} "
                   f"{worst[1]:.2f}x" + (f"; over: {', '.join(sorted(bad))}" if bad else ""))
    return out


# --- main ----------------------------------------------------------------------------------------


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="2 and 20 minutes and the Xsens file")
    ap.add_argument("--sizes", nargs="+", choices=[s.key for s in SIZES],
                    help="only these sizes")
    ap.add_argument("--repeat", type=int, default=None,
                    help="runs per measurement, the minimum is reported (default 3, quick 2)")
    ap.add_argument("--no-rrd", action="store_true", help="skip the .rrd runs")
    ap.add_argument("--no-cli", action="store_true", help="skip the whole-process runs")
    ap.add_argument("--no-baselines", action="store_true")
    ap.add_argument("--workdir", type=Path, default=None,
                    help="keep the generated sessions here and reuse them (default: a temporary "
                         "directory, removed at the end)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results.md")
    ap.add_argument("--json", type=Path, default=None, help="also write the raw numbers")
    ap.add_argument("--compare", type=Path, default=None,
                    help="an earlier run's --json file: add a before -> after table")
    ap.add_argument("--compare-label", default=None, help="what the earlier run measured")
    # worker mode (internal)
    ap.add_argument("--worker", dest="session", help=argparse.SUPPRESS)
    ap.add_argument("--gyro", help=argparse.SUPPRESS)
    ap.add_argument("--tmp", help=argparse.SUPPRESS)
    ap.add_argument("--rrd", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--trace-memory", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.repeat is None:
        args.repeat = 2 if args.quick else 3
    if args.session:
        worker(args)
        return 0

    sizes = [s for s in SIZES if (args.sizes and s.key in args.sizes)
             or (not args.sizes and (not args.quick or s.key in QUICK))]
    if not XSENS.is_dir():
        sizes = [s for s in sizes if s.synthetic]
    info = machine_info()
    # Every machine caches bytecode after a package's first run; with PYTHONDONTWRITEBYTECODE
    # set (as in some sandboxes) each timed process would compile imucal anew (~50 ms).
    for pkg in ("imucal", "viewer"):
        compileall.compile_dir(ROOT / pkg, quiet=1)
    print(f"{info['cpu']}, {info['cores']} cores, {info['ram']}; "
          + ", ".join(f"{k} {v}" for k, v in info["versions"].items()), flush=True)
    extra: dict = {}
    if args.compare:
        extra["compare"] = json.loads(args.compare.read_text())
        extra["compare"]["label"] = (args.compare_label or extra["compare"].get("label")
                                     or str(args.compare))
    cli_note = None if args.no_cli else cli_available()
    extra["cli_note"] = cli_note
    have_viewer = not args.no_rrd
    if have_viewer:
        try:
            import viewer.recording  # noqa: F401
        except Exception as e:
            have_viewer = False
            print(f"no .rrd runs: {e}", flush=True)

    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="imucal-bench-"))
    workdir.mkdir(parents=True, exist_ok=True)
    rows = []
    try:
        if not args.no_cli and cli_note is None:
            exe = str(VENV_BIN / "imucal")
            extra["help"] = best_of([exe, "--help"], max(args.repeat, 3))
            extra["import"] = best_of([sys.executable, "-c", "import imucal"],
                                      max(args.repeat, 3))
            print(f"imucal --help: {extra['help']['wall']:.3f} s wall", flush=True)
        for size in sizes:
            files, t_make = make_session_file(size, workdir)
            if t_make:
                print(f"{size.title}: session written in {t_make:.1f} s", flush=True)
            row = {"key": size.key, "title": size.title}
            run_dir = workdir / f"run_{size.key}"
            run_dir.mkdir(exist_ok=True)
            row["stage"] = stage_run(size, files, run_dir, args.repeat, have_viewer, True)
            st = row["stage"].get("stages", {})
            print(f"{size.title}: stages " + ", ".join(f"{k} {v:.3f}" for k, v in st.items()),
                  flush=True)
            if "error" in row["stage"]:
                print(f"  worker error: {row['stage']['error']}", flush=True)
            if not args.no_cli and cli_note is None:
                exe = str(VENV_BIN / "imucal")
                cmd = [exe, "calibrate", *files, "--out", str(run_dir / "calib.json")]
                row["cli"] = best_of(cmd, args.repeat, cwd=run_dir)
                if have_viewer:
                    rrd = run_dir / "run.rrd"
                    row["cli_rrd"] = best_of(cmd + ["--rrd", str(rrd)], args.repeat, cwd=run_dir)
                    if rrd.exists():
                        row["cli_rrd"]["rrd_mb"] = rrd.stat().st_size / 1e6
                        rrd.unlink()
                c, cr = row["cli"], row.get("cli_rrd", {})
                print(f"  process: {_f(c.get('wall'))} s wall, {_f(c.get('cpu'))} s CPU, "
                      f"{_f(c.get('maxrss_mb'), '.0f')} MB; with .rrd {_f(cr.get('wall'))} s, "
                      f"{_f(cr.get('maxrss_mb'), '.0f')} MB, {_f(cr.get('rrd_mb'), '.1f')} MB file"
                      + (f"  {c.get('error', '')} {cr.get('error', '')}" if 'error' in c
                         or 'error' in cr else ""), flush=True)
            rows.append(row)
        if not args.no_baselines:
            extra["baselines"] = baselines(args.repeat)
            b = extra["baselines"]
            print(f"baselines: detector {b['detector']['naive'] / b['detector']['product']:.0f}x,"
                  f" gyro cost {b['gyro_cost']['naive'] / b['gyro_cost']['product']:.0f}x",
                  flush=True)
            extra["jacobian"] = jacobian_methods(args.repeat, 2.0 if args.quick else 20.0)
        if not args.no_cli:
            extra["startup"] = startup(args.repeat)
    finally:
        if args.workdir is None:
            shutil.rmtree(workdir, ignore_errors=True)
    text = render(info, rows, extra, args)
    print()
    print(text)
    args.out.write_text(text)
    if args.json:
        saved = {k: v for k, v in extra.items() if k != "compare"}
        args.json.write_text(json.dumps({"machine": info, "rows": rows, "extra": saved},
                                        indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
