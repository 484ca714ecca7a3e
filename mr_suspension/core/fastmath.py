"""Branch-free elementary functions that vectorise in numba loops."""

from numba import njit

TANH_CLAMP = 7.90531110763549805


@njit(fastmath=True, error_model='numpy', cache=True)
def fast_tanh(x):
    """``tanh(x)`` by a clamped 13/6 rational approximation (the Eigen library's kernel).

    Maximum absolute and relative error 2.6e-7 over the real line (checked in the tests), far
    below any damper model's accuracy; unlike ``math.tanh`` it is plain arithmetic, so loops
    over many corners compile to SIMD instructions.
    """
    if x > TANH_CLAMP:
        x = TANH_CLAMP
    elif x < -TANH_CLAMP:
        x = -TANH_CLAMP
    x2 = x * x
    p = x2 * -2.76076847742355e-16 + 2.00018790482477e-13
    p = x2 * p + -8.60467152213735e-11
    p = x2 * p + 5.12229709037114e-08
    p = x2 * p + 1.48572235717979e-05
    p = x2 * p + 6.37261928875436e-04
    p = x2 * p + 4.89352455891786e-03
    q = x2 * 1.19825839466702e-06 + 1.18534705686654e-04
    q = x2 * q + 2.26843463243900e-03
    q = x2 * q + 4.89352518554385e-03
    return x * p / q
