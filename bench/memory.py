"""Where a session's memory goes: tracemalloc (numpy reports its buffers to it) around each step
of loading and each stage of the pipeline, the bytes held before and after it and the peak
while it ran.

    .venv/bin/imucal synth /tmp/s60.mat --minutes 60 --acc-rate 1000
    .venv/bin/python bench/memory.py /tmp/s60.mat

The process's own peak (RSS, with the interpreter and the libraries) is
``/usr/bin/time -v .venv/bin/imucal calibrate /tmp/s60.mat -o /tmp/c.json``.
"""

from __future__ import annotations

import argparse
import functools
import tracemalloc
from collections.abc import Callable
from typing import Any

MB = 1e6
_PEAKS: list[int] = []  # each step resets tracemalloc's peak: the whole run's is the largest


def _probed(name: str, f: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(f)
    def g(*args: Any, **kwargs: Any) -> Any:
        before, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        out = f(*args, **kwargs)
        after, peak = tracemalloc.get_traced_memory()
        _PEAKS.append(peak)
        print(f"| {name} | {before / MB:.0f} | {after / MB:.0f} | {peak / MB:.0f} | "
              f"+{(peak - before) / MB:.0f} |")
        return out

    return g


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session")
    args = ap.parse_args()

    import imucal.io.load as load
    import imucal.pipeline as pipeline
    from imucal.stages import apply

    for name in ("read_file", "own_rows", "settle_time", "resolve_acc_unit",
                 "resolve_gyro_unit"):
        setattr(load, name, _probed(f"load: {name}", getattr(load, name)))
    for name in ("tune_detector", "_drop_saturated", "calibrate_accelerometer",
                 "block_mean_variance", "group_blocks", "block_mean_cov", "calibrate_gyroscope",
                 "leave_one_block_out", "quality_figures", "recording_guide"):
        setattr(pipeline, name, _probed(name, getattr(pipeline, name)))
    apply.Calibration.apply = _probed("apply", apply.Calibration.apply)
    import imucal.result as result_module
    import imucal.session as session_module

    # The noise calib.json asks for, and the rates (the guide reads them; the rate properties
    # are probed through the median they compute, where this tree has it).
    result_module.still_noise = _probed("still_noise", result_module.still_noise)
    if hasattr(session_module, "_median_rate"):
        session_module._median_rate = _probed("Session rate (median step)",
                                              session_module._median_rate)

    print("| step | MB held before | after | peak | peak above before |")
    print("|---|---|---|---|---|")
    tracemalloc.start()
    session = load.load_session(args.session)
    held, peak = tracemalloc.get_traced_memory()
    peak = max([peak, *_PEAKS])
    print(f"| **load_session** | 0 | {held / MB:.0f} | {peak / MB:.0f} | +{peak / MB:.0f} |")
    tracemalloc.reset_peak()
    _PEAKS.clear()
    result = pipeline.calibrate(session)
    after, peak = tracemalloc.get_traced_memory()
    peak = max([peak, *_PEAKS])
    print(f"| **calibrate** | {held / MB:.0f} | {after / MB:.0f} | {peak / MB:.0f} | "
          f"+{(peak - held) / MB:.0f} |")
    # What calib.json adds: the noise figures (on the calibrated still samples) and the dict.
    from imucal.io.calibration_file import result_to_dict

    held = after
    tracemalloc.reset_peak()
    result_to_dict(result)
    after, peak = tracemalloc.get_traced_memory()
    print(f"| **calib.json (noise, dict)** | {held / MB:.0f} | {after / MB:.0f} | "
          f"{peak / MB:.0f} | +{(peak - held) / MB:.0f} |")
    del result


if __name__ == "__main__":
    main()
