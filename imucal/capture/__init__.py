"""Live capture (issue 25): read a device's stream, write every sample to a session file as it
arrives, follow the holds and turns with an incremental still detector, calibrate what it keeps
after each new hold, and stop when the calibration is good enough or a spec can no longer be
met (docs/method.md §13); then calibrate the whole session file once with the full method.

One module per idea: ``byte_source`` (what a source is: bytes read with a timeout), ``sources``
(where the bytes come from: standard input, TCP, UDP, a serial port; ``mavlink``), ``lines``
(bytes to rows of numbers, garbled lines counted), ``writer`` (the session file, flushed at least
every 0.5 s), ``detector`` (M1 one batch at a time, the holds and poses, what the running fits
keep), ``turns`` (a turn's gyroscope samples in bounded rows), ``running`` (the method's fits on
what is kept), ``stop`` (the targets, the stop rule, a spec lost), ``run`` (the loop that ties
them), ``send`` (a session sent as a device would, for tests and for trying it without
hardware). The core never imports rerun: the live view maps the status this loop
reports.
"""
