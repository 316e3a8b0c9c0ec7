"""viewer: an imucal run as a Rerun recording, and the ``imucal-view`` command.

- :mod:`viewer.recording` — ``log_result(result, rec)``, ``save_recording(result, path)``; the
  table of entity paths (a contract: :mod:`viewer.paths` names them without importing Rerun).
- :mod:`viewer.blueprint` — the layout stored in every ``.rrd``.
- :mod:`viewer.app` — ``view(target, save=..., web=..., port=...)`` and ``main()``.
- :mod:`viewer.readback` — the numbers back out of an ``.rrd`` (scripts, tests).
- :mod:`viewer.decimate` — how many rows a signal gets: a screen's worth, min/max envelopes.
- one module per tab maps the core's arrays onto entities: :mod:`viewer.signals`,
  :mod:`viewer.gravity`, :mod:`viewer.lcurve`, :mod:`viewer.optimiser`, :mod:`viewer.summary`
  (the markdown summary is :mod:`imucal.report`, the CLI's summary too); helpers in
  :mod:`viewer.columns`. The viewer computes nothing the core should.

The core (``imucal``) never imports this package; importing it costs nothing until a
recording is written (``import rerun`` happens there).
"""
