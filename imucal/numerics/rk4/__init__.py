"""Orientation from sampled body rates: classic RK4 on quaternions (method.md M5), vectorised.

For ``dq/dt = 1/2 q (x) W(t)`` (W the pure quaternion of the body rate) one RK4 step is linear
in ``q``: ``q_(n+1) = q_n (x) P_n``, with ``P_n`` a quaternion built from the rates at the step's
start, middle and end only. Renormalising after every step equals normalising the product once
at the end, because ``|q (x) P| = |q| |P|``. So a whole interval is the ordered product
``P_0 (x) P_1 (x) ... (x) P_(L-1)``, normalised: every ``P_n`` of every interval is built in one
vector operation, and the products are reduced pairwise, in ``log2(L)`` vector operations, for
all intervals at once (no per-sample Python loop; linear work in the number of samples).

One idea per module, from the bottom up:

- :mod:`.hamilton`: the Hamilton product of quaternions held as four component arrays;
- :mod:`.step`: one RK4 step in closed form (the four stages collapsed, with the thesis's
  half-step rate);
- :mod:`.product`: the ordered product of many steps, reduced pairwise;
- :mod:`.prefix_scan`: every prefix of that product (the orientation at every sample);
- :mod:`.rotation_matrix`: rotation matrices of component quaternions, in place;
- :mod:`.affine`: the rate model ``w = M (w_raw - b)`` (M4) for several models at once;
- :mod:`.buckets`: intervals grouped by length and laid out time-major, ``(L, K)``;
- :mod:`.lazy`: a bucket's samples and step times gathered a slab of rows at a time, on request;
- :mod:`.integrate`: every interval's rotation under several models, a slab of rows at a time;
- :mod:`.variational`: the rotation's sensitivity to the model (a fit's Jacobian);
- :mod:`.layout`: :class:`StepLayout`, the steps laid out once and integrated many times.

The names below are this package's public API (the gyroscope stage, the tests and bench/ import
them from here).
"""

from imucal.numerics.rk4.affine import calibrator
from imucal.numerics.rk4.hamilton import Quat, Vec, mul
from imucal.numerics.rk4.integrate import SLAB
from imucal.numerics.rk4.layout import StepLayout, integrate_transitions
from imucal.numerics.rk4.prefix_scan import prefix_rows
from imucal.numerics.rk4.product import ordered_product, ordered_product_soa, product_rows
from imucal.numerics.rk4.step import rk4_raw, rk4_step_quaternions, rk4_steps

__all__ = [
    "SLAB", "Quat", "StepLayout", "Vec", "calibrator", "integrate_transitions", "mul",
    "ordered_product", "ordered_product_soa", "prefix_rows", "product_rows", "rk4_raw",
    "rk4_step_quaternions", "rk4_steps",
]
