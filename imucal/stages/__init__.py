"""The method's stages in run order (method.md §1-§5).

``detect`` (§1, still samples and blocks, with ``saturation``) -> ``group`` (§2, segments) ->
``accel`` (§3, M2-M3 and the L-curve) -> ``gyro`` (§4, M4-M5) -> ``apply`` (the calibration
applied to the whole signal) -> ``quality`` (§5, the figures a user reads first).
"""
