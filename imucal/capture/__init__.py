"""Live capture (issue 25): read a device's stream, write every sample to a session file as it
arrives, follow the holds and turns with an incremental still detector, calibrate the data so
far after each new hold, and stop when the calibration is good enough (docs/method.md §13).

One module per idea: ``sources`` (where the bytes come from: standard input, TCP, UDP, a serial
port), ``lines`` (bytes to rows of numbers, garbled lines counted), ``writer`` (the session file,
flushed at least every 0.5 s), ``detector`` (M1 one batch at a time, the holds and poses),
``stop`` (the targets and the stop rule), ``run`` (the loop that ties them), ``send`` (a session
sent as a device would, for tests and for trying it without hardware). The core never imports
rerun: the live view maps the status this loop reports.
"""
