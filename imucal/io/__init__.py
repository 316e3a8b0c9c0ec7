"""Files in and out: readers (MATLAB, text, Parquet) -> ``load`` (a Session), the calibration
file, the calibrated signals, atomic writes."""
