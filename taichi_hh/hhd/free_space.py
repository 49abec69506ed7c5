"""The free-space Green's function of the plane on a regular grid of cells
(Hockney and Eastwood's particle-mesh convolution), the natural
decomposition's potential solver (:mod:`.natural`):

    u(x_a) = sum_b G(x_a - x_b) q_b,   G(x) = ln|x| / (2 pi),

over the cell centres of a :class:`Grid` covering the domain, by zero-padded
FFT in O(M log M) for M cells (:func:`convolve_fft`) or by direct summation
in a Taichi kernel (:func:`convolve_direct`, O(M^2), the exact reference of
the same sum), the cell's own integral of G on the diagonal; the potentials'
gradients by fourth-order differences on the grid (:func:`grid_gradient`; with
the values, padded, in one kernel: :func:`values_and_gradients`; the
spline's columns: the potentials continued beyond the grid,
:func:`edge_padded`, and their coefficients' differences,
:func:`with_differences`).
"""
import itertools
import math
import os

import numpy as np
import taichi as ti

from .. import runtime
from ..geometry.box import Box

#: cells beyond the domain's bounding box on each side: room for the
#: differences and the interpolation at points on the boundary
MARGIN = 3
#: a cell's charge is weighted by the exact integral of G over the cell (not
#: G at its centre times its area) at nodes within this many cells on each
#: axis: the midpoint rule's error there is what is left of a square's fourth
#: moments, small but not smooth across a boundary (a disk: the potential's
#: gradient 2-2.5x more accurate next to it)
EXACT_CELLS = 4
#: the cell average of G beyond EXACT_CELLS (:meth:`Grid.far_series`): its
#: expansion in the cell's moments M_n = mean of (x + i y)^n to this n (the
#: next term, n + 2 or n + 4 on square cells, is below 1e-9 of G's at 5 cells)
FAR_SERIES_ORDER = 8
#: ... within this many cells on each axis; beyond, G at the centre (the
#: series' first term is h^4 cos 4t / (240 r^4), below 1e-9 of G's there)
FAR_SERIES_CELLS = 64


class Grid:
    """Cell-centred grid covering ``domain``'s bounding box (whole cells of
    size ``hx`` x ``hy`` close to ``cell``) plus ``MARGIN`` cells on each side.
    ``cell_average``: the kernel beyond EXACT_CELLS is the cell's average of
    G (:meth:`far_series`), not G at its centre (:meth:`kernel`)."""

    #: the kernel beyond EXACT_CELLS: G at the offset (False) or the cell's
    #: average of G (True)
    cell_average = False

    def __init__(self, domain, cell: float, cell_average: bool = False):
        self.cell_average = bool(cell_average)
        (x0, y0), (x1, y1) = domain.bounds
        nx = max(int(math.ceil((x1 - x0) / cell - 1e-9)), 1)
        ny = max(int(math.ceil((y1 - y0) / cell - 1e-9)), 1)
        self.hx, self.hy = (x1 - x0) / nx, (y1 - y0) / ny
        self.nx, self.ny = nx + 2 * MARGIN, ny + 2 * MARGIN
        self.origin = np.array([x0 - (MARGIN - 0.5) * self.hx, y0 - (MARGIN - 0.5) * self.hy])

    @property
    def shape(self):
        return self.nx, self.ny

    def centres(self, cells=None) -> np.ndarray:
        """(nx * ny, 2) cell centres, x fastest within each row of constant ... index
        order ``[i * ny + j]`` for cell (i, j); ``cells`` (flat indices): those
        cells' only."""
        if cells is None:
            i, j = np.meshgrid(np.arange(self.nx), np.arange(self.ny), indexing="ij")
            i, j = i.ravel(), j.ravel()
        else:
            i = np.asarray(cells) // self.ny
            j = cells - i * self.ny
        out = np.empty((len(i), 2))
        out[:, 0] = self.origin[0] + i * self.hx
        out[:, 1] = self.origin[1] + j * self.hy
        return out

    def cell_index(self, points) -> np.ndarray:
        """(N,) flat index ``i * ny + j`` of the cell holding each point (points
        beyond the grid in its edge cells)."""
        lower = self.origin - 0.5 * np.array([self.hx, self.hy])
        ij = np.floor((points - lower) / [self.hx, self.hy]).astype(np.int64)
        np.clip(ij[:, 0], 0, self.nx - 1, out=ij[:, 0])
        np.clip(ij[:, 1], 0, self.ny - 1, out=ij[:, 1])
        return ij[:, 0] * self.ny + ij[:, 1]

    def coverage(self, domain, sub: int = 4, *, centroids: bool = False, inside: bool = False):
        """(nx, ny) fraction of each cell inside ``domain``, by ``sub`` x ``sub``
        subsamples for the cells the boundary may cross; with ``centroids``
        also (nx, ny, 2) the offset of the inside part's centroid from the
        cell centre (0 for whole and empty cells), from the same subsamples;
        with ``inside`` also (nx, ny) whether each cell centre is in the
        domain (``domain.contains``).

        An axis-aligned rectangle (a :class:`~taichi_hh.geometry.box.Box`)
        in closed form: its inside subsamples are a product of the inside
        columns and rows.  Other polygons: the cells the locator decides whole
        (inside or out) without a distance, the rest by the exact signed
        distance of the centre and, where the boundary may cross, the
        subsamples."""
        rect = axis_rectangle(domain)
        if rect is not None:
            frac, offset, centre_in = self._rectangle_coverage(rect, domain.boundary_tolerance,
                                                               sub, centroids)
        else:
            frac, offset, centre_in = self._polygon_coverage(domain, sub)
        out = (frac.reshape(self.shape),)
        if centroids:
            out += (offset.reshape(self.shape + (2,)),)
        if inside:
            out += (centre_in.reshape(self.shape),)
        return out[0] if len(out) == 1 else out

    def _subsample_offsets(self, sub: int):
        s = (np.arange(sub) + 0.5) / sub - 0.5
        return s * self.hx, s * self.hy

    def _rectangle_coverage(self, rect, eps: float, sub: int, centroids: bool = True):
        """Rectangle ``((x0, y0), (x1, y1))``: a subsample is inside when its x
        and its y are (within ``eps``, the domain's boundary tolerance), so a
        cell's inside subsamples are the product of its inside columns and rows:
        the fraction is the product of the two counts, the centroid the pair of
        the two means (None without ``centroids``: 30% of this at 1M cells)."""
        (x0, y0), (x1, y1) = rect
        sx, sy = self._subsample_offsets(sub)
        parts = []
        for n, o, h, lo, hi, s in ((self.nx, self.origin[0], self.hx, x0, x1, sx),
                                   (self.ny, self.origin[1], self.hy, y0, y1, sy)):
            c = o + np.arange(n) * h                           # as centres() makes them
            coords = c[:, None] + s[None, :]
            ins = (coords >= lo - eps) & (coords <= hi + eps)
            count = ins.sum(axis=1)
            mean = np.where(count > 0, (ins * s).sum(axis=1) / np.maximum(count, 1), 0.0)
            mean[count == sub] = 0.0                       # whole columns: the centre
            centre_in = (c >= lo - eps) & (c <= hi + eps)
            parts.append((count, mean, centre_in))
        (cx, mx, ix), (cy, my, iy) = parts
        frac = (cx[:, None] * cy[None, :]).astype(np.float64) / (sub * sub)
        inside = (ix[:, None] & iy[None, :]).ravel()
        if not centroids:
            return frac.ravel(), None, inside
        offset = np.zeros(self.shape + (2,))
        offset[..., 0] = np.where(frac > 0, mx[:, None], 0.0)
        offset[..., 1] = np.where(frac > 0, my[None, :], 0.0)
        offset[frac == 1.0] = 0.0
        return frac.ravel(), offset.reshape(-1, 2), inside

    def _polygon_coverage(self, domain, sub: int):
        c = self.centres()
        half_diag = 0.5 * math.hypot(self.hx, self.hy)
        # 1: the disc of the half diagonal inside (a whole cell), 0: outside
        # (an empty cell), 2: the boundary may cross it
        status = domain.classify_discs(c, half_diag, -np.inf, 0.0)
        frac = (status == 1).astype(np.float64)
        centre_in = status == 1
        offset = np.zeros((len(c), 2))
        cut = np.flatnonzero(status == 2)
        if cut.size:
            centre_in[cut] = domain.contains(c[cut])
            sx, sy = self._subsample_offsets(sub)
            ox, oy = np.meshgrid(sx, sy, indexing="ij")
            offs = np.c_[ox.ravel(), oy.ravel()]
            sp = (c[cut][:, None, :] + offs[None, :, :]).reshape(-1, 2)
            inside = domain.contains(sp).reshape(len(cut), -1)
            frac[cut] = inside.mean(axis=1)
            count = inside.sum(axis=1)
            offset[cut] = np.einsum("ks,sc->kc", inside.astype(np.float64), offs) \
                / np.maximum(count, 1)[:, None]
        return frac, offset, centre_in

    def self_integral(self) -> float:
        """int over one cell (centred at 0) of G = ln|s| / (2 pi): Gauss-Legendre
        in polar-free form, the log singularity handled by splitting the cell
        into four triangles from the centre (each integrable in closed form in r)."""
        # integral of ln r over the triangle (0,0), (a, -b), (a, b) is, in polar form,
        # int_{-atan(b/a)}^{atan(b/a)} (R^2 ln R / 2 - R^2 / 4) dt with R = a / cos t
        total = 0.0
        x, w = np.polynomial.legendre.leggauss(64)
        for a, b in ((self.hx / 2, self.hy / 2), (self.hy / 2, self.hx / 2)):
            t_max = math.atan2(b, a)
            t = x * t_max
            R = a / np.cos(t)
            total += 2.0 * float((w * t_max * (R * R * np.log(R) / 2 - R * R / 4)).sum())
        return total / (2.0 * math.pi)

    def near_kernel(self) -> np.ndarray:
        """(2 E + 1, 2 E + 1), E = :data:`EXACT_CELLS`: the integral of G over
        the cell at each offset (i, j) from a node, |i|, |j| <= E, at index
        (i + E, j + E) (:func:`cell_integral`)."""
        k = np.arange(-EXACT_CELLS, EXACT_CELLS + 1)
        return cell_integral(k[:, None] * self.hx, k[None, :] * self.hy, self.hx, self.hy)

    def far_series(self) -> tuple:
        """``(n, c_n)``: the cell average of G at an offset z = x + i y (a
        complex number) beyond the cell is G(z) - sum_n c_n Re(z^-n) / (2 pi),
        c_n = M_n / n, M_n the cell's moments (the mean of (x + i y)^n over
        it: real, zero for odd n), n even up to FAR_SERIES_ORDER.  From the
        Taylor series of G = Re log z / (2 pi): its n-th derivative is
        (-1)^(n-1) (n - 1)! z^-n / (2 pi).  Empty unless ``cell_average``."""
        if not self.cell_average:
            return ()
        def mean_power(h, k):                    # mean of t^k over [-h/2, h/2]
            return 0.0 if k % 2 else (h / 2) ** k / (k + 1)

        out = []
        for n in range(2, FAR_SERIES_ORDER + 1, 2):
            M = sum(math.comb(n, k) * mean_power(self.hx, n - k) * mean_power(self.hy, k)
                    * (-1) ** (k // 2) for k in range(0, n + 1, 2))
            out.append((n, M / n))
        return tuple(out)

    def _far(self, dx, dy):
        """The kernel beyond EXACT_CELLS at offsets ``dx``, ``dy`` (arrays that
        broadcast): the cell's area times G, less the cell average's series
        (:meth:`far_series`), Re(z^-n) = cos(n t) / r^n by the recurrence
        cos((k + 2) t) = 2 cos(2 t) cos(k t) - cos((k - 2) t) (real
        arithmetic: a 2000 x 2000 kernel in a fraction of a second)."""
        r2 = dx * dx + dy * dy
        K = np.log(r2) / (4.0 * math.pi)
        series = self.far_series()
        if series:
            inv = 1.0 / r2
            cos2 = (dx * dx - dy * dy) * inv
            prev, cur, power = np.ones_like(cos2), cos2, inv
            acc = np.zeros_like(cos2)
            for _, c in series:                      # n = 2, 4, ...
                acc += c * cur * power
                prev, cur = cur, 2.0 * cos2 * cur - prev
                power = power * inv
            K = K - acc / (2.0 * math.pi)
        return K * (self.hx * self.hy)

    def kernel_at(self, i: int, j: int) -> float:
        """:meth:`kernel`'s entry at the offset of (i, j) cells."""
        if abs(i) <= EXACT_CELLS and abs(j) <= EXACT_CELLS:
            return float(cell_integral(i * self.hx, j * self.hy, self.hx, self.hy))
        if not self.cell_average or max(abs(i), abs(j)) > FAR_SERIES_CELLS:
            return math.log((i * self.hx) ** 2 + (j * self.hy) ** 2) / (4.0 * math.pi) \
                * (self.hx * self.hy)
        return float(self._far(np.float64(i * self.hx), np.float64(j * self.hy)))

    def kernel(self, shape=None) -> np.ndarray:
        """(2 nx, 2 ny) the Green's function's weight of a cell's charge at every
        offset of the zero-padded grid (wrapped: offset -k at index 2n - k):
        G times the cell area (the midpoint rule; Hockney and Eastwood's
        free-space convolution; with ``cell_average``, within
        FAR_SERIES_CELLS, the cell's average of G times its area,
        :meth:`far_series`), and within :data:`EXACT_CELLS` of the offset 0
        the exact integral of G over the cell (:meth:`near_kernel`).  ``shape``: a larger padded grid
        (each side at least 2 n - 2; the offsets wrap at half of it)."""
        L1, L2 = (2 * self.nx, 2 * self.ny) if shape is None else shape
        ix = np.arange(L1)
        iy = np.arange(L2)
        ix = np.where(ix <= L1 // 2, ix, ix - L1) * self.hx
        iy = np.where(iy <= L2 // 2, iy, iy - L2) * self.hy
        r2 = ix[:, None] ** 2 + iy[None, :] ** 2
        r2[0, 0] = 1.0
        K = np.log(r2) / (4.0 * math.pi) * (self.hx * self.hy)
        if self.cell_average:
            F = min(FAR_SERIES_CELLS, L1 // 2, L2 // 2)
            k = np.arange(-F, F + 1)
            with np.errstate(divide="ignore", invalid="ignore"):
                # offset 0 is overwritten below
                K[np.ix_(k % L1, k % L2)] = self._far(k[:, None] * self.hx, k[None, :] * self.hy)
        E = EXACT_CELLS
        near = self.near_kernel()
        k = np.arange(-E, E + 1)
        K[np.ix_(k % L1, k % L2)] = near
        return K


def cell_integral(dx, dy, hx: float, hy: float):
    """The integral of G = ln|s| / (2 pi) over the hx x hy cell centred at
    (dx, dy) (arrays broadcast), in closed form: with F(x, y) = x y (ln(x^2 +
    y^2) - 3) + x^2 atan(y / x) + y^2 atan(x / y) the integral of
    ln(x^2 + y^2) over [0, x] x [0, y], the corners' alternating sum over 4 pi."""
    def F(x, y):
        r2 = x * x + y * y
        with np.errstate(divide="ignore", invalid="ignore"):
            t = x * y * (np.log(np.where(r2 > 0, r2, 1.0)) - 3.0)
            t = t + np.where(x != 0, x * x * np.arctan(y / np.where(x != 0, x, 1.0)), 0.0)
            t = t + np.where(y != 0, y * y * np.arctan(x / np.where(y != 0, y, 1.0)), 0.0)
        return t

    dx, dy = np.asarray(dx, dtype=np.float64), np.asarray(dy, dtype=np.float64)
    x1, x2, y1, y2 = dx - hx / 2, dx + hx / 2, dy - hy / 2, dy + hy / 2
    return (F(x2, y2) - F(x1, y2) - F(x2, y1) + F(x1, y1)) / (4.0 * math.pi)


def axis_rectangle(domain):
    """``((x0, y0), (x1, y1))`` when ``domain`` is an axis-aligned rectangle
    without holes (a Box, or a Polygon of those four corners), else None."""
    if isinstance(domain, Box):
        return domain.lo, domain.hi
    rings = getattr(domain, "rings", ())
    if len(rings) != 1 or len(rings[0]) != 4:
        return None
    (x0, y0), (x1, y1) = domain.bounds
    corners = {(x0, y0), (x1, y0), (x1, y1), (x0, y1)}
    if {(float(x), float(y)) for x, y in rings[0]} != corners:
        return None
    return (x0, y0), (x1, y1)


def fast_length(n: int) -> int:
    """The smallest 2^a 3^b 5^c >= n (a length the FFTs factor well)."""
    best = 1 << max(int(n) - 1, 0).bit_length()
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            q = p35
            while q < n:
                q *= 2
            best = min(best, q)
            p35 *= 3
        p5 *= 5
    return best


#: padded grids of at least this many cells are transformed by scipy.fft on
#: every core; smaller ones by numpy.fft: on 2 cores numpy's was 2-4x faster
#: up to 256 x 256 and scipy's 2x faster from 400 x 400, and importing
#: scipy.fft (scipy.special and the array API layer with it) took 0.4-1.4 s
#: of a fresh 4k-point command line (docs/notes/series.md)
THREADED_FFT_CELLS = 1 << 17


def _fft(cells: int):
    """``(module, keywords)`` for a padded grid of ``cells``: scipy.fft on
    every core where scipy is installed (a test and benchmark dependency, not
    a core one) and the grid is large, numpy.fft otherwise."""
    if cells < THREADED_FFT_CELLS:
        return np.fft, {}
    try:
        import scipy.fft as sfft
    except ImportError:
        return np.fft, {}
    return sfft, {"workers": os.cpu_count() or 1}


#: the last grid's kernel spectrum (a decomposition at one size repeated, or a
#: series of fields on the same points, reuses it)
_SPECTRA: dict = {}


def _kernel_spectrum(grid: Grid, shape, fft, kw) -> np.ndarray:
    """The transform of :meth:`Grid.kernel` on the padded ``shape``: real (the
    kernel is even in both offsets), (L1, L2 // 2 + 1)."""
    key = (grid.nx, grid.ny, grid.hx, grid.hy, grid.cell_average, tuple(shape), fft.__name__)
    K = _SPECTRA.get(key)
    if K is None:
        K = np.ascontiguousarray(fft.rfft2(grid.kernel(shape), **kw).real)
        _SPECTRA.clear()
        _SPECTRA[key] = K
    return K


#: densities per convolution from which numpy.fft's passes run on two threads
#: (pocketfft releases the GIL; Taichi's workers sit idle meanwhile): each
#: density's transforms are the same calls either way, so the same bits
FFT_THREAD_DENSITIES = 2
_FFT_POOL = []


def _fft_pool():
    """The one helper thread of :func:`convolve_fft` (made on first use, kept:
    a thread's start costs more than a density's transforms), or None where
    this process may use one core."""
    if not _FFT_POOL:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") \
            else (os.cpu_count() or 1)
        if cores < 2:
            _FFT_POOL.append(None)
        else:
            from concurrent.futures import ThreadPoolExecutor
            _FFT_POOL.append(ThreadPoolExecutor(1, thread_name_prefix="taichi_hh_fft"))
    return _FFT_POOL[0]


def padded_lengths(density: np.ndarray) -> tuple:
    """The zero-padded FFT's sides for the densities (k, nx, ny): on each
    axis the potentials at every node i and the charges at the nodes j
    with any nonzero density need the offsets |i - j| <= R (R the largest),
    which the padded length L keeps apart (the kernel's offsets wrap at
    L // 2: L - 1 - L // 2 >= R), the smallest :func:`fast_length` such.
    A window's grid has MARGIN empty cells a side: 240 instead of 243 at
    121 nodes, 8% faster transforms."""
    sides = []
    for axis, n in ((1, density.shape[1]), (2, density.shape[2])):
        other = tuple(a for a in (0, 1, 2) if a != axis)
        used = np.flatnonzero(density.any(axis=other))
        # (no charge at all: any length the nodes fit in, the answer zero)
        reach = max(int(used[-1]), n - 1 - int(used[0])) if used.size else n - 1
        sides.append(fast_length(2 * reach + 2))
    return tuple(sides)


def convolve_fft(grid: Grid, density: np.ndarray, threads: bool = True,
                 out=None) -> np.ndarray:
    """(nx, ny) sum over cells of G(x_a - x_b) density_b (times the cell area),
    by zero-padded FFT (the padding makes the circular convolution free-space);
    ``density`` (k, nx, ny) gives (k, nx, ny).  The padded sides are lengths
    the FFT factors well (:func:`padded_lengths`: at most 2 n, less where
    the densities leave the grid's sides empty), the
    transforms skip the padding's zero rows on the way in and the unused rows
    on the way out.  ``threads``: from :data:`FFT_THREAD_DENSITIES` densities
    on, half of them transformed on a helper thread (numpy.fft's sizes; the
    same answer bit for bit); ``out``: a (k, nx, ny) array to write (a
    series' batches reuse one)."""
    nx, ny = grid.shape
    d = np.asarray(density, dtype=np.float64)
    one = d.ndim == 2
    d = d[None] if one else d
    L1, L2 = padded_lengths(d)
    fft, kw = _fft(L1 * L2)
    K = _kernel_spectrum(grid, (L1, L2), fft, kw)
    # one density at a time: a padded spectrum (L1 x L2 / 2 complex, under a
    # megabyte at 120 x 120 cells) stays in cache through the four passes,
    # where a stack of eight ran 3.5x slower (docs/notes/series.md)
    if out is None or out.shape != d.shape or not out.flags.c_contiguous:
        out = np.empty(d.shape)

    def run(ks):
        for k in ks:
            A = fft.rfft(d[k], n=L2, axis=1, **kw)
            A = fft.fft(A, n=L1, axis=0, **kw)
            A *= K
            A = fft.ifft(A, axis=0, **kw)[:nx]
            out[k] = fft.irfft(A, n=L2, axis=1, **kw)[:, :ny]

    pool = _fft_pool() if threads and fft is np.fft and len(d) >= FFT_THREAD_DENSITIES \
        else None
    if pool is None:
        run(range(len(d)))
    else:
        # both threads take the next density from one counter (next() on it
        # holds the GIL): where the helper gets no core (a loaded machine)
        # this thread does the rest instead of waiting for a fixed half
        todo = itertools.count()

        def mine():
            return itertools.takewhile(lambda k: k < len(d), todo)
        helper = pool.submit(lambda: run(mine()))
        run(mine())
        helper.result()
    return out[0] if one else out


#: ln 2 split in two (fdlibm's): e ln 2 exact to double precision for any exponent e
_LN2_HI, _LN2_LO = 6.93147180369123816490e-01, 1.90821492927058770002e-10


@ti.func
def _log(x):
    """ln x of a positive normal f64, to 2 ulp, from its bits: SPIR-V
    (Vulkan) has no f64 log.  x = m 2^e with m in [sqrt(1/2), sqrt(2)), then
    ln m = 2 atanh(s), s = (m - 1) / (m + 1), |s| < 0.172, by its series to
    s^23 (the next term is below 1e-19)."""
    bits = ti.bit_cast(x, ti.i64)
    e = ti.cast((bits >> 52) & 0x7FF, ti.i32) - 1023
    m = ti.bit_cast((bits & ti.i64(0x000FFFFFFFFFFFFF)) | ti.i64(0x3FF0000000000000), ti.f64)
    if m > 1.4142135623730951:
        m *= 0.5
        e += 1
    s = (m - 1.0) / (m + 1.0)
    s2 = s * s
    series = 1.0 / 23.0
    for k in ti.static(range(21, 0, -2)):
        series = series * s2 + 1.0 / k
    fe = ti.cast(e, ti.f64)
    return (fe * _LN2_LO + 2.0 * s * series) + fe * _LN2_HI


@ti.kernel
def _direct_sum(n: ti.i32, pos: ti.types.ndarray(), q: ti.types.ndarray(),
                near: ti.types.ndarray(), hx: float, hy: float, far: ti.types.ndarray(),
                out: ti.types.ndarray(), bitwise_log: ti.template(), n_far: ti.template()):
    # one gather per target: no atomics; the cells within EXACT_CELLS
    # contribute their integrals (``near``, over the cell's area)
    E = EXACT_CELLS
    F = FAR_SERIES_CELLS
    for a in range(n):
        acc = 0.0
        for b in range(n):
            d = pos[a] - pos[b]
            i = ti.cast(ti.floor(d[0] / hx + 0.5), ti.i32)
            j = ti.cast(ti.floor(d[1] / hy + 0.5), ti.i32)
            if -E <= i <= E and -E <= j <= E:
                acc += q[b] * near[i + E, j + E]
            else:
                log_r2 = 0.0
                if ti.static(bitwise_log):
                    log_r2 = ti.cast(_log(ti.cast(d.dot(d), ti.f64)), float)
                else:
                    log_r2 = ti.log(d.dot(d))
                acc += q[b] * log_r2 * (0.25 / math.pi)
                if ti.static(n_far > 0):
                    if -F <= i <= F and -F <= j <= F:
                        # the cell average's series: far[k] Re(z^-(2k + 2)), z = d
                        r2 = d.dot(d)
                        w = ti.Vector([d[0] / r2, -d[1] / r2])      # 1 / z
                        w2 = ti.Vector([w[0] * w[0] - w[1] * w[1], 2.0 * w[0] * w[1]])
                        wn = w2
                        series = 0.0
                        for k in ti.static(range(n_far)):
                            series += far[k] * wn[0]
                            wn = ti.Vector([wn[0] * w2[0] - wn[1] * w2[1],
                                            wn[0] * w2[1] + wn[1] * w2[0]])
                        acc -= q[b] * series * (0.5 / math.pi)
        out[a] = acc


def convolve_direct(grid: Grid, density: np.ndarray, bitwise_log: bool | None = None) -> np.ndarray:
    """The same sum as :func:`convolve_fft` by direct summation over the cells
    with nonzero density (a Taichi kernel, O(M^2)): its exact reference.
    ``bitwise_log``: the logarithm from the float's bits (:func:`_log`), as the
    SPIR-V archs need (None: there only; the CPU's own is 1.1-1.5x faster)."""
    runtime.ensure_init()
    dens = np.asarray(density, dtype=np.float64).ravel()
    c = grid.centres()
    area = grid.hx * grid.hy
    # targets: every cell; sources: the cells with density (the others add zero)
    n = len(c)
    real = runtime.real_dtype()
    pos = runtime.array(real, n, vector=2)
    pos.from_numpy(c.astype(runtime.np_real()))
    q = runtime.array(real, n)
    q.from_numpy((dens * area).astype(runtime.np_real()))
    out = runtime.array(real, n)
    if bitwise_log is None:
        bitwise_log = runtime.state().arch in ("vulkan", "metal")
    near = np.ascontiguousarray(grid.near_kernel() / area, dtype=runtime.np_real())
    series = grid.far_series()
    far = np.array([c for _, c in series] or [0.0], dtype=runtime.np_real())
    _direct_sum(n, pos, q, near, grid.hx, grid.hy, far, out, bool(bitwise_log), len(series))
    return out.to_numpy().astype(np.float64).reshape(grid.shape)


@ti.func
def _difference(u: ti.template(), c, p, n, stride, h):
    """The derivative of the flat grid ``u`` at index ``c``, node ``p`` of
    ``n`` along an axis whose neighbours are ``stride`` apart, nodes spaced
    ``h``: fourth-order central differences, second order on the two
    outermost nodes (one-sided on the edge ones; numpy.gradient's
    edge_order=2 formulas)."""
    d = ti.cast(0.0, ti.f64)
    if p == 0:
        d = (-1.5 / h) * u[c] + (2.0 / h) * u[c + stride] + (-0.5 / h) * u[c + 2 * stride]
    elif p == n - 1:
        d = (0.5 / h) * u[c - 2 * stride] + (-2.0 / h) * u[c - stride] + (1.5 / h) * u[c]
    elif p >= 2 and p <= n - 3:
        d = (-u[c + 2 * stride] + 8.0 * u[c + stride] - 8.0 * u[c - stride]
             + u[c - 2 * stride]) / (12.0 * h)
    else:
        d = (u[c + stride] - u[c - stride]) / (2.0 * h)
    return d


@ti.kernel
def _values_and_gradients(u: ti.types.ndarray(), nx: ti.i32, ny: ti.i32, hx: ti.f64,
                          hy: ti.f64, pad: ti.i32, out: ti.types.ndarray(), m: ti.template(),
                          last: ti.template()):
    """out[I, J, k, :] = u[k] and its grid gradient (:func:`_difference`) at
    the node (I - pad, J - pad) clamped into the grid (the edge nodes'
    values repeated ``pad`` nodes beyond it); ``u`` (m, nx, ny), or (nx, ny,
    m) with ``last``, and ``out`` (nx + 2 pad, ny + 2 pad, m, 3) flat, the
    ``m`` potentials' strides known at compile time (2-d and 4-d ndarrays'
    runtime strides took 1.4x as long)."""
    NX, NY = nx + 2 * pad, ny + 2 * pad
    for I, J in ti.ndrange(NX, NY):
        i = ti.math.clamp(I - pad, 0, nx - 1)
        j = ti.math.clamp(J - pad, 0, ny - 1)
        o = (I * NY + J) * (3 * m)
        for k in ti.static(range(m)):
            c = (k * nx + i) * ny + j
            sx, sy = ny, 1
            if ti.static(last):
                c = (i * ny + j) * m + k
                sx, sy = ny * m, m
            out[o + 3 * k] = u[c]
            out[o + 3 * k + 1] = _difference(u, c, i, nx, sx, hx)
            out[o + 3 * k + 2] = _difference(u, c, j, ny, sy, hy)


@ti.kernel
def _edge_padded(u: ti.types.ndarray(), nx: ti.i32, ny: ti.i32, pad: ti.i32,
                 out: ti.types.ndarray(), m: ti.template()):
    """out[I, J, k] = u[k] continued linearly beyond the grid along each
    axis (the edge's slope) to the node (I - pad, J - pad); ``u`` (m, nx,
    ny), ``out`` (nx + 2 pad, ny + 2 pad, m), flat."""
    NX, NY = nx + 2 * pad, ny + 2 * pad
    for I, J in ti.ndrange(NX, NY):
        i = ti.math.clamp(I - pad, 0, nx - 1)
        j = ti.math.clamp(J - pad, 0, ny - 1)
        di = ti.cast(I - pad - i, ti.f64)
        dj = ti.cast(J - pad - j, ti.f64)
        si = 1 if I - pad > i else -1        # towards the inside: i - si
        sj = 1 if J - pad > j else -1
        o = (I * NY + J) * m
        for k in ti.static(range(m)):
            b = k * nx * ny
            a = u[b + i * ny + j]
            if di != 0.0:
                a += ti.abs(di) * (u[b + i * ny + j] - u[b + (i - si) * ny + j])
            if dj != 0.0:
                a2 = u[b + i * ny + j - sj]
                if di != 0.0:
                    a2 += ti.abs(di) * (u[b + i * ny + j - sj] - u[b + (i - si) * ny + j - sj])
                a += ti.abs(dj) * (a - a2)
            out[o + k] = a


def _potentials(grid: Grid, u: np.ndarray) -> np.ndarray:
    u = np.ascontiguousarray(u, dtype=np.float64)
    nx, ny = grid.shape
    if u.ndim != 3 or u.shape[1:] != (nx, ny):
        raise ValueError(f"potentials of shape (m, {nx}, {ny}) expected, got {u.shape}")
    if min(nx, ny) < 3:
        raise ValueError(f"the grid's differences need 3 nodes a side, got {nx} x {ny}")
    return u


def values_and_gradients(grid: Grid, u: np.ndarray, pad: int = 0, out=None) -> np.ndarray:
    """(nx + 2 pad, ny + 2 pad, m, 3) the potentials ``u`` (m, nx, ny) and their
    gradients (:func:`grid_gradient`) side by side at each node, the edge
    nodes' repeated ``pad`` nodes beyond the grid (numpy.pad's ``edge``): the
    columns the spline through them all takes.  A Taichi kernel, one pass;
    ``out``: the array to write (a series' batches reuse one)."""
    runtime.ensure_init()
    u = _potentials(grid, u)
    nx, ny = grid.shape
    shape = (nx + 2 * pad, ny + 2 * pad, len(u), 3)
    if not runtime.writable(out, shape):
        out = np.empty(shape)
    if len(u):
        _values_and_gradients(u.reshape(-1), nx, ny, grid.hx, grid.hy, int(pad),
                              runtime.flat(out), len(u), False)
    return out


def edge_padded(grid: Grid, u: np.ndarray, pad: int, out=None) -> np.ndarray:
    """(nx + 2 pad, ny + 2 pad, m) the potentials ``u`` (m, nx, ny) with the
    edge nodes' values repeated ``pad`` nodes beyond the grid, the
    potentials last (a spline's columns); ``out``: the array to write."""
    runtime.ensure_init()
    u = _potentials(grid, u)
    nx, ny = grid.shape
    shape = (nx + 2 * pad, ny + 2 * pad, len(u))
    if not runtime.writable(out, shape):
        out = np.empty(shape)
    if len(u):
        _edge_padded(u.reshape(-1), nx, ny, int(pad), runtime.flat(out), len(u))
    return out



def with_differences(grid: Grid, c: np.ndarray, out=None) -> np.ndarray:
    """(NX, NY, m, 3) the columns ``c`` (NX, NY, m: values on a grid of
    ``grid``'s spacing, e.g. a spline's coefficients) and their grid
    gradients (:func:`_difference`, that grid's edges its own) side by
    side; ``out``: the array to write."""
    runtime.ensure_init()
    NX, NY, m = c.shape
    if min(NX, NY) < 3:
        raise ValueError(f"the grid's differences need 3 nodes a side, got {NX} x {NY}")
    shape = (NX, NY, m, 3)
    if not runtime.writable(out, shape):
        out = runtime.work(shape) if isinstance(c, runtime.Device) else np.empty(shape)
    if m:
        _values_and_gradients(runtime.flat(c), NX, NY, grid.hx, grid.hy, 0, runtime.flat(out),
                              m, True)
    return out


def grid_gradient(grid: Grid, u: np.ndarray) -> np.ndarray:
    """(nx, ny, 2) fourth-order central differences (second order on the two
    outermost cells; :func:`values_and_gradients`)."""
    return values_and_gradients(grid, np.asarray(u)[None])[:, :, 0, 1:].copy()
