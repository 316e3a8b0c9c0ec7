"""The limits a calibration in use is held to (method.md §10), declared once; free of numpy so
that the command line shows them without importing it."""

ACC_LIMIT_MG = 2.0  # the verdict's caveat level for the held-out still-norm error
GYRO_LIMIT_DEG_S = 0.1  # 6 deg of heading a minute
