"""Numerics that know nothing of IMUs: window sums and runs, least squares and covariance,
quaternions and RK4 scans, the L-curve corner, distinct directions."""
