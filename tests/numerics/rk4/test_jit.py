"""imucal.numerics.rk4.jit: a kernel compiled into an empty cache, then loaded from it in a fresh
process without numba's start-up (its implementations are not imported: ~0.1 s CPU a process,
issue 22), gives the same numbers; signatures given still refuse other types."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[3]

KERNEL = textwrap.dedent('''
    import numpy as np
    from imucal.numerics.rk4.jit import jit

    @jit("float64(float64[:], float64[:])")
    def fixed(x, y):
        acc = np.empty(2)  # numba's runtime allocates it: must be initialised by the load
        acc[0] = 0.0
        acc[1] = 0.0
        for i in range(x.shape[0]):
            acc[0] += x[i] * y[i]
            acc[1] += np.sqrt(abs(x[i]))
        return acc[0] / acc[1]

    @jit()
    def lazy(x):
        s = 0.0
        for v in x:
            s = s * 0.5 + v
        return s

    @jit("float64(float64)")
    def checked(x):
        if x < 0.0:
            raise ValueError("negative")
        return 1.0 / x
''')

RUN = textwrap.dedent('''
    import json, sys
    import numpy as np
    import kern
    x = np.linspace(-1.0, 2.0, 101)
    out = {"fixed": kern.fixed(x, np.cos(x)).hex(), "lazy": kern.lazy(x[::3]).hex(),
           "refreshed": "numba.np.arraymath" in sys.modules}
    try:
        kern.fixed(x.astype(np.float32), x.astype(np.float32))
        out["other_type"] = "compiled"
    except TypeError:
        out["other_type"] = "refused"
    raised = []
    for v in (-1.0, 0.0):
        try:
            kern.checked(v)
        except (ValueError, ZeroDivisionError) as e:
            raised.append(f"{type(e).__name__}: {e}")
    out["raised"] = raised
    print(json.dumps(out))
''')


def _run(tmp_path: Path) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=os.pathsep.join([str(tmp_path), str(ROOT)]))
    proc = subprocess.run([sys.executable, "-c", RUN], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_compiled_then_loaded_lean_gives_the_same_numbers(tmp_path: Path) -> None:
    (tmp_path / "kern.py").write_text(KERNEL)
    cold = _run(tmp_path)  # compiles (numba's full start-up) and writes the cache
    assert cold["refreshed"]
    assert list((tmp_path / "cache").rglob("*.nbi"))
    warm = _run(tmp_path)  # loads both kernels from the cache
    assert not warm["refreshed"], "numba's implementations were imported to load a cached kernel"
    assert warm["fixed"] == cold["fixed"] and warm["lazy"] == cold["lazy"]
    x = np.linspace(-1.0, 2.0, 101)
    expected = float(np.dot(x, np.cos(x)) / np.sum(np.sqrt(np.abs(x))))
    assert float.fromhex(warm["fixed"]) == pytest.approx(expected, rel=1e-12)
    assert cold["other_type"] == warm["other_type"] == "refused"
    # a kernel's exceptions reach Python from the cached code as from the compiled
    assert warm["raised"] == cold["raised"] == ["ValueError: negative",
                                                "ZeroDivisionError: division by zero"]
