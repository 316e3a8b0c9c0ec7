"""Where a short run's fixed cost goes (issue 22): the interpreter, every import, the compiled
kernels' load and first call, the first call of each scipy routine, and the calibration's own
work, each in CPU seconds (user + sys) of a fresh process.

    .venv/bin/python bench/startup.py SESSION [--gyro FILE] [--rate HZ] [--runs 5]
                                      [--baseline 'CMD ...'] [--pycache DIR]

1. The interpreter alone (``python -c pass``, with ``site``), median over ``--runs``.
2. ``python -X importtime`` of the whole ``imucal calibrate`` parsed: each import's own time
   summed by package, and the cumulative time of the imports that matter (importtime's figures
   are wall microseconds of the import, with its own overhead: read them as shares).
3. One fresh process walking the steps the command takes (import the CLI, load the session,
   import scipy.optimize, import numba, load each compiled kernel, ``calibrate`` with the
   first call of each kernel and scipy routine timed, ``calibrate`` again, save), the median
   over ``--runs`` processes.
4. The whole command, CPU and wall, median over ``--runs``; with ``--baseline`` (another
   ``imucal`` entry point, e.g. the main checkout's) both in turn, A B A B, and the ratio pair
   by pair, so a drifting machine's speed cancels.

The machine is shared: read the ratios and the medians, and say the load (printed first).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import statistics
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable

# The steps of section 3, run in a fresh process; prints one JSON object. Everything is CPU
# seconds of this process (resource.getrusage), so other processes' load does not count.
PROBE = r'''
import json, resource, sys, time
def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
steps, first = {}, {}
t = 0.0  # the first step counts the interpreter's start
def step(name):
    global t
    now = cpu(); steps[name] = steps.get(name, 0.0) + now - t; t = now
args = json.loads(sys.argv[1])
step("interpreter (to the probe's first line)")
import imucal.cli  # noqa: F401
step("import imucal.cli (typer, settings, options)")
import numpy  # noqa: F401
step("import numpy")
import imucal
session = imucal.load_session(args["path"], **args["load_kw"])
step("load_session (its imports, read, units, time base)")
import scipy.special  # noqa: F401
step("import scipy.special (the grouping's F test)")
import scipy.optimize  # noqa: F401
step("import scipy.optimize (the fits)")
from imucal import pipeline  # noqa: F401  (the stages)
step("import the stages")
import numba  # noqa: F401
step("import numba")
import imucal.numerics.rk4.jit as J
loaded = {}
real_jit = J.jit
def timed_jit(*sig, **kw):
    wrap = real_jit(*sig, **kw)
    def inner(f):
        t0 = cpu(); out = wrap(f); loaded[f.__name__] = cpu() - t0
        return out
    return inner
J.jit = timed_jit
t0 = cpu()
import imucal.numerics.rk4.kernels as K
J.jit = real_jit
step("load the rk4 kernels (numba's cache)")
def first_call(module, name, label):
    f = getattr(module, name)
    def wrapper(*a, **k):
        if label in first:
            return f(*a, **k)
        t0 = cpu(); out = f(*a, **k); first[label] = cpu() - t0
        return out
    setattr(module, name, wrapper)
import scipy.optimize as SO, scipy.special as SS  # the project imports them where they run
first_call(SO, "least_squares", "scipy least_squares (lm)")
first_call(SO, "minimize_scalar", "scipy minimize_scalar")
first_call(SO, "nnls", "scipy nnls")
first_call(SS, "fdtrc", "scipy.special fdtrc")
first_call(SS, "fdtri", "scipy.special fdtri")
for name in ("integrate", "integrate_each", "sensitivity", "max_step", "raw_turn"):
    first_call(K, name, f"kernel {name}")
result = imucal.calibrate(session)
step("calibrate, first (first calls included)")
result = imucal.calibrate(session)
step("calibrate, again (the work alone)")
imucal.save_calibration(result, args["out"])
step("save_calibration")
lazy = sorted(m for m in ("imucal.numerics.window_kernel", "imucal.numerics.allan_kernels")
              if m in sys.modules)
print(json.dumps({"steps": steps, "first": first, "loaded": loaded, "lazy": lazy}))
'''

CLI = ("import sys; from imucal.cli import main; sys.argv[0] = 'imucal'; "
       "sys.exit(main())")


def env(pycache: str | None, tree: Path | None = ROOT) -> dict[str, str]:
    """The children's environment: this tree first on the path; with ``--pycache DIR``
    bytecode cached under DIR (as an installed package has it) even where the environment
    says not to write it."""
    e = dict(os.environ)
    if pycache:
        e.pop("PYTHONDONTWRITEBYTECODE", None)
        e["PYTHONPYCACHEPREFIX"] = pycache
    if tree is None:
        return e
    e["PYTHONPATH"] = os.pathsep.join([str(tree), e.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return e


def child_cpu(cmd: list[str], **kw) -> tuple[float, float, str, str]:
    """(cpu, wall, stdout, stderr) of one process, CPU from its own rusage (os.wait4)."""
    import time

    kw.setdefault("cwd", tempfile.gettempdir())  # not a checkout: `-c` puts the cwd on the path
    with tempfile.TemporaryFile("w+") as fo, tempfile.TemporaryFile("w+") as fe:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=fo, stderr=fe, text=True, **kw)
        _, status, ru = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        fo.seek(0)
        fe.seek(0)
        out, err = fo.read(), fe.read()
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}): {err[-800:]}")
    return ru.ru_utime + ru.ru_stime, wall, out, err


def command_args(a: argparse.Namespace, out: str) -> list[str]:
    args = ["calibrate", a.session, "--out", out]
    if a.gyro:
        args += ["--gyro", a.gyro]
    if a.rate:
        args += ["--rate", str(a.rate)]
    return args


def parse_importtime(text: str) -> list[tuple[int, int, int, str]]:
    """(self us, cumulative us, depth, module) per line of ``-X importtime``."""
    rows = []
    for line in text.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)", line)
        if m:
            rows.append((int(m.group(1)), int(m.group(2)), len(m.group(3)) // 2, m.group(4)))
    return rows


def group_of(module: str) -> str:
    top = module.split(".")[0]
    if top in ("numba", "llvmlite"):
        return "numba + llvmlite"
    if top in ("typer", "click", "rich", "shellingham"):
        return "typer (the CLI framework)"
    if top == "scipy":
        sub = module.split(".")[1] if "." in module else ""
        return f"scipy.{sub}" if sub in ("optimize", "linalg", "special", "fft", "sparse",
                                          "spatial", "io") else "scipy (other)"
    if top == "numpy":
        sub = module.split(".")[1] if "." in module else ""
        return ("numpy (f2py, testing, ... pulled by scipy's array API layer)"
                if sub in ("f2py", "testing", "polynomial", "ctypeslib", "typing", "random",
                           "strings", "char", "rec", "ma") else "numpy")
    if top == "imucal":
        return "imucal." + module.split(".")[1] if "." in module else "imucal"
    if top == "yaml":
        return "yaml (numba's config)"
    return "stdlib and other"


WATCH = ("imucal.cli", "numpy", "scipy.special", "scipy.linalg", "scipy.fft",
         "numpy.f2py", "numpy.testing", "scipy.optimize", "numba",
         "imucal.numerics.rk4.kernels", "imucal.numerics.window_kernel",
         "imucal.numerics.allan_kernels")


def median(xs: list[float]) -> float:
    return statistics.median(xs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session")
    ap.add_argument("--gyro")
    ap.add_argument("--rate", type=float)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--baseline", help="another imucal entry point, e.g. main's, timed in turn")
    ap.add_argument("--tree", type=Path, default=ROOT,
                    help="the checkout whose imucal is measured (default: this one)")
    ap.add_argument("--pycache", metavar="DIR",
                    help="cache bytecode under DIR (PYTHONPYCACHEPREFIX) for every child, as an "
                         "installed package has it; the default is the environment as it is")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="imucal-startup-"))
    e = env(a.pycache, a.tree)
    if a.pycache:  # fill the bytecode cache: the figures are those of later runs
        child_cpu([PY, "-c", CLI, *command_args(a, str(tmp / "w.json"))], env=e)
    print(f"load average: {' '.join(f'{x:.2f}' for x in os.getloadavg())}, {os.cpu_count()} "
          f"cores; python {sys.version.split()[0]}; runs {a.runs}; tree {a.tree}; bytecode: "
          f"{a.pycache or ('not written' if 'PYTHONDONTWRITEBYTECODE' in e else 'as usual')}")

    # 1. the interpreter
    bare = [child_cpu([PY, "-c", "pass"], env=e)[0] for _ in range(a.runs)]
    print(f"\n1. interpreter alone (python -c pass): {median(bare):.3f} s CPU")

    # 2. importtime of the whole command
    _, _, _, err = child_cpu([PY, "-X", "importtime", "-c", CLI,
                              *command_args(a, str(tmp / "it.json"))], env=e)
    rows = parse_importtime(err)
    by_group: dict[str, int] = defaultdict(int)
    for self_us, _, _, mod in rows:
        by_group[group_of(mod)] += self_us
    total = sum(by_group.values())
    print(f"\n2. imports of `imucal calibrate` (-X importtime, {len(rows)} modules, "
          f"{total / 1e6:.3f} s wall with importtime's overhead), own time by package:")
    for g, us in sorted(by_group.items(), key=lambda kv: -kv[1]):
        print(f"   {g:62s} {us / 1e3:7.1f} ms  {us / total:5.1%}")
    print("   cumulative, where first imported (and by whom):")
    for i, (_, cum, depth, mod) in enumerate(rows):
        if mod in WATCH:
            parent = next((r[3] for r in rows[i + 1:] if r[2] < depth), "-")
            print(f"   {mod:40s} {cum / 1e3:7.1f} ms  <- {parent}")
    missing = [m for m in WATCH if m not in {r[3] for r in rows}]
    print(f"   not imported: {', '.join(missing) or '-'}")

    # 3. the steps in one process
    load_kw = {}
    if a.gyro:
        load_kw["gyro_path"] = a.gyro
    if a.rate:
        load_kw["rate"] = a.rate
    probe_args = json.dumps({"path": a.session, "load_kw": load_kw,
                             "out": str(tmp / "probe.json")})
    probes = [json.loads(child_cpu([PY, "-c", PROBE, probe_args], env=e)[2])
              for _ in range(a.runs)]
    steps = {k: median([p["steps"][k] for p in probes]) for k in probes[0]["steps"]}
    first = {k: median([p["first"].get(k, 0.0) for p in probes]) for k in probes[0]["first"]}
    loaded = {k: median([p["loaded"][k] for p in probes]) for k in probes[0]["loaded"]}
    print("\n3. the steps of one process (CPU s, median of the runs; each includes the imports "
          "it triggers):")
    for k, v in steps.items():
        print(f"   {k:58s} {v:6.3f}")
    print(f"   = {sum(steps.values()):.3f} s CPU in the process")
    print("   numba's load of each rk4 kernel (decorated with signatures: loaded at import):")
    for k, v in loaded.items():
        if v >= 0.0005:
            print(f"     {k:40s} {v * 1e3:6.1f} ms")
    print("   first calls within the first calibrate (ms; inclusive):")
    for k, v in first.items():
        print(f"     {k:40s} {v * 1e3:6.1f} ms")
    print(f"   lazy kernels loaded by this session: {', '.join(probes[0]['lazy']) or 'none'}")

    # 4. the whole command
    mine = [PY, "-c", CLI]
    pairs = []
    base = shlex.split(a.baseline) if a.baseline else None
    for i in range(a.runs + 1):  # the first pair is a warm-up
        c, w, _, _ = child_cpu([*mine, *command_args(a, str(tmp / "a.json"))], env=e)
        row = [c, w]
        if base:
            c, w, _, _ = child_cpu([*base, *command_args(a, str(tmp / "b.json"))],
                                   env=env(a.pycache, tree=None))
            row += [c, w]
        if i:
            pairs.append(row)
    cpu_a, wall_a = median([p[0] for p in pairs]), median([p[1] for p in pairs])
    print(f"\n4. whole command, this tree: {cpu_a:.3f} s CPU, {wall_a:.3f} s wall "
          f"(median of {len(pairs)})")
    if base:
        same = (tmp / "a.json").read_bytes() == (tmp / "b.json").read_bytes()
        cpu_b, wall_b = median([p[2] for p in pairs]), median([p[3] for p in pairs])
        r_cpu = median([p[0] / p[2] for p in pairs])
        r_wall = median([p[1] / p[3] for p in pairs])
        print(f"   baseline: {cpu_b:.3f} s CPU, {wall_b:.3f} s wall; this / baseline, pair by "
              f"pair: CPU {r_cpu:.2f}, wall {r_wall:.2f}; calib.json identical: {same}")

    # summary
    print("\nsummary (CPU s of the process, section 3):")
    rows_s = [("interpreter and the probe's start", steps[next(iter(steps))]),
              ("CLI framework and the project's imports, load",
               sum(v for k, v in steps.items() if k.startswith(("import imucal.cli",
                                                                "import numpy", "load_session",
                                                                "import the stages")))),
              ("scipy (special, optimize and what they pull)",
               sum(v for k, v in steps.items() if k.startswith("import scipy"))),
              ("numba (import, kernels' cache load)",
               sum(v for k, v in steps.items() if "numba" in k or "kernels" in k)),
              ("first calibrate beyond the second (first calls)",
               steps["calibrate, first (first calls included)"]
               - steps["calibrate, again (the work alone)"]),
              ("the work: calibrate (second call) and save",
               steps["calibrate, again (the work alone)"] + steps["save_calibration"])]
    whole = sum(v for _, v in rows_s)
    print(f"   {'part':52s} {'CPU s':>7s} {'share':>6s}")
    for k, v in rows_s:
        print(f"   {k:52s} {v:7.3f} {v / whole:6.1%}")
    print(f"   {'total (the first calibrate counted once)':52s} {whole:7.3f}")


if __name__ == "__main__":
    main()
