"""A calibration in use (method.md §10): still moments of ordinary use, the check of a stored
calibration against them, its refresh, and synthetic everyday use to test both on."""
