"""imucal synth's options for several triads and temperature (method.md §11, §12): a second
accelerometer (its range, its rotation to the first, its own errors), a gyroscope in its IMU,
the first one's range and a shake that drives it past it (M18), a temperature profile and
its coefficients. Kept apart from commands.py: its own small idea, light to import."""

from __future__ import annotations

from typing import Any

from imucal.cli.options import parse_triple, usage_error

# The second IMU's own drift with heat (g, rad/s per deg C^j about the ramp's middle): order 2
# as the first's default, other coefficients, so each triad's fit is its own (method.md §12).
ACC2_TEMP = ((-3e-4, 2e-4, 3e-4), (-1.2e-5, 8e-6, 1e-5))
GYRO2_TEMP = ((-7e-5, 9e-5, -5e-5), (2e-6, 3e-6, -3e-6))


def triad_kwargs(*, csv: bool, counts: bool, acc_range: float | None, shake: float,
                 acc2: float | None, acc2_rotation: float, gyro2: bool,
                 temperature: tuple[float, float] | None,
                 temp_steps: int, temp_acc_bias: str | None, temp_acc_scale: str | None,
                 temp_gyro_bias: str | None) -> dict[str, Any]:
    """The keyword arguments of :func:`imucal.synth.make_session` these options ask for
    (none when none is given: the session is then the one it always was)."""
    out: dict[str, Any] = {}
    given = {"--acc2": acc2 is not None, "--temperature": temperature is not None,
             "--acc-range": acc_range is not None, "--shake": bool(shake)}
    if any(given.values()) and not csv:
        first = next(k for k, v in given.items() if v)
        raise usage_error("other triads, a temperature and a clipped accelerometer are written "
                          "in a table's a2x…, g2x…, temp columns: name OUT.csv", f"'{first}'")
    if counts and (acc2 is not None or temperature is not None):
        raise usage_error("a second triad and a temperature are made in g or m/s^2 and rad/s "
                          "or deg/s, not counts", "'--acc2'" if acc2 is not None
                          else "'--temperature'")
    if gyro2 and acc2 is None:
        raise usage_error("--gyro2 is the gyroscope of the second IMU: give --acc2 too",
                          "'--gyro2'")
    coefs = {"--temp-steps": temp_steps > 0, "--temp-acc-bias": temp_acc_bias is not None,
             "--temp-acc-scale": temp_acc_scale is not None,
             "--temp-gyro-bias": temp_gyro_bias is not None}
    if temperature is None and any(coefs.values()):
        first = next(k for k, v in coefs.items() if v)
        raise usage_error(f"{first} shapes a temperature profile: give --temperature START END",
                          f"'{first}'")
    if acc_range is not None:
        out["acc_range"] = acc_range
    if shake:
        out["shake"] = shake
    if acc2 is not None:
        from imucal.synth import SecondTriad

        out["second_acc"] = SecondTriad(range_g=acc2, rotation_deg=acc2_rotation, gyro=gyro2,
                                        same_clock=True)
    if temperature is not None:
        import math

        from imucal.synth import TemperatureProfile

        start, end = temperature
        if not (math.isfinite(start) and math.isfinite(end) and -100 <= min(start, end)
                and max(start, end) <= 200):
            raise usage_error(f"expected two temperatures in deg C, got {start:g} {end:g}",
                              "'--temperature'")
        kw: dict[str, Any] = {"start": start, "end": end, "steps": temp_steps,
                              "ref": (start + end) / 2}
        if temp_acc_bias is not None:  # mg per deg C -> g per deg C, first order
            kw["acc"] = (tuple(v * 1e-3 for v in parse_triple(temp_acc_bias, "--temp-acc-bias")),)
        if temp_gyro_bias is not None:  # deg/s per deg C -> rad/s per deg C
            kw["gyro"] = (tuple(math.radians(v) for v in parse_triple(temp_gyro_bias,
                                                                      "--temp-gyro-bias")),)
        if acc2 is not None:  # the second IMU drifts too, by coefficients of its own
            kw["acc2"] = ACC2_TEMP
            kw["gyro2"] = GYRO2_TEMP if gyro2 else ()
        if temp_acc_scale is not None:  # ppm per deg C -> relative
            kw["acc_scale"] = tuple(v * 1e-6 for v in parse_triple(temp_acc_scale,
                                                                   "--temp-acc-scale"))
        out["temperature"] = TemperatureProfile(**kw)
    return out


def described(kwargs: dict[str, Any]) -> str:
    """What the options added, for synth's summary line ("" when nothing)."""
    parts = []
    if "acc_range" in kwargs:
        parts.append(f"accelerometer clipped at {kwargs['acc_range']:g} g")
    if "shake" in kwargs:
        parts.append(f"shaken to {kwargs['shake']:g} g in the turns")
    if "second_acc" in kwargs:
        t = kwargs["second_acc"]
        parts.append(f"second accelerometer a2 ({t.range_g:g} g, turned {t.rotation_deg:g} deg"
                     + (", with gyroscope g2)" if t.gyro else ")"))
    if "temperature" in kwargs:
        p = kwargs["temperature"]
        parts.append(f"temperature {p.start:g} to {p.end:g} deg C"
                     + (f" in {p.steps} steps" if p.steps else " (ramp)")
                    + (", a2" + (" and g2" if p.gyro2 else "") + " drifting by coefficients "
                       "of their own" if p.acc2 else ""))
    return "".join(f", {p}" for p in parts)
