"""Smoothing kernels in 2D, as one mechanism with the kernel as a parameter.

Every kernel is written in terms of its *support radius* ``H`` (the distance
beyond which it vanishes; the neighbour grid's cell size).  The smoothing
length ``h`` of the literature is ``H / support_factor``:

============  =========================================  ===============  =====
name          formula (q = r / h)                        reference        H/h
============  =========================================  ===============  =====
``quartic``   15/(7 pi h^2) (2/3 - 9/8 q^2 + 19/24 q^3    Petronetto Sec.3  2
              - 5/32 q^4)
``poly6``     4/(pi h^8) (h^2 - r^2)^3                    Colin Eq. 7       1
``wendland``  7/(4 pi h^2) (1 - q/2)^4 (2 q + 1)          Wendland C2       2
``cubic``     10/(7 pi h^2) {1 - 3/2 q^2 + 3/4 q^3;       Monaghan 1992     2
              1/4 (2 - q)^3}
============  =========================================  ===============  =====

The quartic is kept exactly as published: it is slightly negative (down to
-0.3% of W(0)) for 0.848 H < r < H, where its gradient also changes sign.

Colin et al. call the support radius itself ``h``; Petronetto et al. use the
quartic's ``h`` (support ``2h``).

Each Taichi function returns, for a distance ``r`` and support ``H``:
``W`` (value), ``F = W'(r) / r`` (so that grad_i W_ij = F * x_ij, finite at
r = 0) and ``L = W'' + W'/r`` (the 2D Laplacian of W, Colin Eq. 9).
"""

import math
from enum import IntEnum

import numpy as np
import taichi as ti


class KernelId(IntEnum):
    """The kernels (the value selects the branch of :func:`kernel_terms` at compile time)."""
    QUARTIC = 0
    POLY6 = 1
    WENDLAND = 2
    CUBIC = 3


KERNELS = tuple(k.name.lower() for k in KernelId)
KERNEL_ID = {name: KernelId[name.upper()] for name in KERNELS}
SUPPORT_FACTOR = {"quartic": 2.0, "poly6": 1.0, "wendland": 2.0, "cubic": 2.0}


def kernel_id(name: str) -> KernelId:
    try:
        return KERNEL_ID[name]
    except KeyError:
        raise ValueError(f"unknown kernel {name!r}; choose one of {KERNELS}") from None


@ti.func
def kernel_terms(kernel_id: ti.template(), r, H):
    """(W, W'/r, laplacian W) of kernel ``kernel_id`` (a static id) at distance r."""
    W = 0.0
    F = 0.0
    L = 0.0
    if ti.static(kernel_id == KernelId.QUARTIC):      # quartic, h = H/2
        h = 0.5 * H
        q = r / h
        if q < 2.0:
            s = 15.0 / (7.0 * math.pi * h * h)
            W = s * (2.0 / 3.0 - 9.0 / 8.0 * q * q + 19.0 / 24.0 * q * q * q - 5.0 / 32.0 * q * q * q * q)
            # w'(q)/q and w''(q)
            dwq = -9.0 / 4.0 + 19.0 / 8.0 * q - 5.0 / 8.0 * q * q
            d2w = -9.0 / 4.0 + 19.0 / 4.0 * q - 15.0 / 8.0 * q * q
            F = s * dwq / (h * h)
            L = s * (d2w + dwq) / (h * h)
    elif ti.static(kernel_id == KernelId.POLY6):    # poly6, support H (Colin's h)
        if r < H:
            s = 4.0 / (math.pi * H ** 8)
            d = H * H - r * r
            W = s * d * d * d
            F = -6.0 * s * d * d
            # W'' = -6 s (d^2 - 4 r^2 d); L = W'' + W'/r
            L = -6.0 * s * (d * d - 4.0 * r * r * d) + F
    elif ti.static(kernel_id == KernelId.WENDLAND):    # Wendland C2, h = H/2
        h = 0.5 * H
        q = r / h
        if q < 2.0:
            s = 7.0 / (4.0 * math.pi * h * h)
            t = 1.0 - 0.5 * q
            W = s * t * t * t * t * (2.0 * q + 1.0)
            # w' = -5 q t^3, w'' = -5 t^3 + 7.5 q t^2
            F = s * (-5.0 * t * t * t) / (h * h)
            L = s * (-10.0 * t * t * t + 7.5 * q * t * t) / (h * h)
    else:                        # cubic spline, h = H/2
        h = 0.5 * H
        q = r / h
        s = 10.0 / (7.0 * math.pi * h * h)
        if q < 1.0:
            W = s * (1.0 - 1.5 * q * q + 0.75 * q * q * q)
            F = s * (-3.0 + 2.25 * q) / (h * h)
            L = s * ((-3.0 + 4.5 * q) + (-3.0 + 2.25 * q)) / (h * h)
        elif q < 2.0:
            t = 2.0 - q
            W = s * 0.25 * t * t * t
            F = s * (-0.75 * t * t / q) / (h * h)
            L = s * (1.5 * t + (-0.75 * t * t / q)) / (h * h)
    return W, F, L


# ---- numpy twins: for tests, plots and host-side set-up (not hot paths) ----

def kernel_numpy(name: str, r, H):
    """(W, W'/r, laplacian W) evaluated with numpy; mirrors :func:`kernel_terms`."""
    r = np.asarray(r, dtype=np.float64)
    which = kernel_id(name)
    W = np.zeros_like(r)
    F = np.zeros_like(r)
    L = np.zeros_like(r)
    if which == KernelId.QUARTIC:
        h = 0.5 * H
        q = r / h
        m = q < 2
        s = 15.0 / (7.0 * np.pi * h * h)
        qm = q[m]
        W[m] = s * (2 / 3 - 9 / 8 * qm**2 + 19 / 24 * qm**3 - 5 / 32 * qm**4)
        dwq = -9 / 4 + 19 / 8 * qm - 5 / 8 * qm**2
        F[m] = s * dwq / h**2
        L[m] = s * (-9 / 4 + 19 / 4 * qm - 15 / 8 * qm**2 + dwq) / h**2
    elif which == KernelId.POLY6:
        m = r < H
        s = 4.0 / (np.pi * H**8)
        d = H * H - r[m] ** 2
        W[m] = s * d**3
        F[m] = -6 * s * d**2
        L[m] = -6 * s * (d**2 - 4 * r[m] ** 2 * d) + F[m]
    elif which == KernelId.WENDLAND:
        h = 0.5 * H
        q = r / h
        m = q < 2
        s = 7.0 / (4.0 * np.pi * h * h)
        t = 1 - 0.5 * q[m]
        W[m] = s * t**4 * (2 * q[m] + 1)
        F[m] = s * (-5 * t**3) / h**2
        L[m] = s * (-10 * t**3 + 7.5 * q[m] * t**2) / h**2
    else:
        h = 0.5 * H
        q = r / h
        s = 10.0 / (7.0 * np.pi * h * h)
        a = q < 1
        b = (q >= 1) & (q < 2)
        W[a] = s * (1 - 1.5 * q[a] ** 2 + 0.75 * q[a] ** 3)
        F[a] = s * (-3 + 2.25 * q[a]) / h**2
        L[a] = s * ((-3 + 4.5 * q[a]) + (-3 + 2.25 * q[a])) / h**2
        t = 2 - q[b]
        W[b] = s * 0.25 * t**3
        F[b] = s * (-0.75 * t**2 / q[b]) / h**2
        L[b] = s * (1.5 * t - 0.75 * t**2 / q[b]) / h**2
    return W, F, L
