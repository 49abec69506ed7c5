"""A sparse matrix in compressed sparse row form on Taichi ndarrays: a linear
operator for the Krylov solvers (:mod:`taichi_hh.linalg.krylov`)."""
from functools import lru_cache
from types import SimpleNamespace
from typing import Optional

import numpy as np
import taichi as ti

from taichi_hh import runtime
from taichi_hh.errors import InputError
from taichi_hh.linalg import lanes
from taichi_hh.linalg.krylov_kernels import serial_below_threshold

__all__ = ["CSRMatrix"]


class CSRMatrix:
    """A sparse matrix in compressed sparse row form, stored in Taichi ndarrays.

    Implements the linear operator protocol (``apply``, ``apply_dot``,
    ``diagonal``, ``apply_transpose``, ``normal_diagonal``) with one gather loop
    per row, so there are no floating-point atomics and results are
    deterministic.  The transpose is built in CSR on first use of
    ``apply_transpose``.

    ``shape`` defaults to square ``(len(indptr) - 1,) * 2``.  Duplicate
    entries are summed, as in scipy.
    """

    def __init__(self, indptr, indices, data, shape: Optional[tuple[int, int]] = None):
        runtime.ensure_init()
        indptr = np.asarray(indptr)
        indices = np.asarray(indices)
        data = np.asarray(data)
        nrows = indptr.size - 1
        m, n = (nrows, nrows) if shape is None else (int(shape[0]), int(shape[1]))
        _validate_csr(indptr, indices, data, m, n)
        self.m, self.n = m, n
        self.nnz = int(indices.size)
        self._host = (indptr.astype(np.int32), indices.astype(np.int32),
                      data.astype(runtime.np_real()))
        self._generation = runtime.generation()
        self._row_kernels, self._col_kernels = _kernels(m), _kernels(n)
        self._rows = _upload_csr(*self._host)
        self._cols = None   # transpose, built on demand

    @classmethod
    def from_scipy(cls, matrix) -> "CSRMatrix":
        """From any scipy.sparse matrix or array (converted to CSR)."""
        csr = matrix.tocsr()
        return cls(csr.indptr, csr.indices, csr.data, shape=csr.shape)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.m, self.n)

    def apply(self, x, y) -> None:
        """y[:m] = A @ x[:n]."""
        self.apply_dot(x, y, y)

    def apply_dot(self, x, y, a) -> tuple[float, float]:
        """y[:m] = A @ x[:n]; returns (<a, y>, <y, y>) over the m rows."""
        runtime.check_generation(self._generation, "CSRMatrix")
        indptr, indices, data = self._rows
        return self._row_kernels.csr_matvec_dot(indptr, indices, data, x, y, a, self.m,
                                                lanes.partials(2))

    def apply_transpose(self, x, y) -> None:
        """y[:n] = A.T @ x[:m]."""
        indptr, indices, data = self._transpose()
        self._col_kernels.csr_matvec_dot(indptr, indices, data, x, y, y, self.n,
                                         lanes.partials(2))

    def diagonal(self, d) -> None:
        """d[:min(m, n)] = diag(A)."""
        runtime.check_generation(self._generation, "CSRMatrix")
        indptr, indices, data = self._rows
        rows = min(self.m, self.n)
        self._row_kernels.csr_diagonal(indptr, indices, data, d, rows)

    def normal_diagonal(self, d) -> None:
        """d[:n] = diag(A.T @ A), the squared column norms."""
        indptr, _, data = self._transpose()
        self._col_kernels.csr_row_sq_norms(indptr, data, d, self.n)

    def _transpose(self):
        runtime.check_generation(self._generation, "CSRMatrix")
        if self._cols is None:
            indptr, indices, data = self._host
            rows = np.repeat(np.arange(self.m, dtype=np.int32), np.diff(indptr))
            order = np.argsort(indices, kind="stable")
            t_indptr = np.zeros(self.n + 1, dtype=np.int32)
            np.cumsum(np.bincount(indices, minlength=self.n), out=t_indptr[1:])
            self._cols = _upload_csr(t_indptr, rows[order], data[order])
        return self._cols


def _validate_csr(indptr, indices, data, m, n) -> None:
    if indptr.ndim != 1 or indices.ndim != 1 or data.ndim != 1:
        raise InputError("CSR arrays indptr, indices, data must be 1-D")
    if m < 1 or n < 1:
        raise InputError(f"CSR matrix must have at least one row and column, got shape ({m}, {n})")
    if indptr.size != m + 1:
        raise InputError(f"CSR indptr has {indptr.size} entries, expected rows + 1 = {m + 1}")
    if indices.size != data.size:
        raise InputError(f"CSR indices ({indices.size}) and data ({data.size}) differ in length")
    if not (np.issubdtype(indptr.dtype, np.integer) and np.issubdtype(indices.dtype, np.integer)):
        raise InputError("CSR indptr and indices must be integer arrays")
    if data.dtype == bool or not np.issubdtype(data.dtype, np.number) or np.iscomplexobj(data):
        raise InputError(f"CSR data must be real, got dtype {data.dtype}")
    if max(indices.size, n) >= 2**31:
        raise InputError("CSR matrix too large for 32-bit indices")
    if indptr[0] != 0 or indptr[-1] != indices.size or np.any(np.diff(indptr) < 0):
        raise InputError("CSR indptr must start at 0, be non-decreasing and end at nnz")
    if indices.size and (indices.min() < 0 or indices.max() >= n):
        raise InputError(f"CSR column indices must lie in [0, {n})")
    if not np.all(np.isfinite(data)):
        bad = int(np.flatnonzero(~np.isfinite(data))[0])
        raise InputError(f"CSR data contains a non-finite value (entry {bad})")


def _upload_csr(indptr, indices, data):
    out = []
    for arr, dtype in ((indptr, ti.i32), (indices, ti.i32), (data, runtime.real_dtype())):
        nd = runtime.array(dtype, max(arr.size, 1))   # Taichi has no empty ndarrays
        if arr.size:
            nd.from_numpy(np.ascontiguousarray(arr))
        out.append(nd)
    return tuple(out)


def _kernels(rows: int) -> SimpleNamespace:
    """The CSR kernels for ``rows`` rows in the current precision, serial below the
    solvers' threshold (:data:`~taichi_hh.linalg.krylov_kernels.PARALLEL_MIN_SIZE`)."""
    runtime.ensure_init()
    return _build(runtime.state().precision, serial_below_threshold(rows), lanes.on())


@lru_cache(maxsize=None)
def _build(precision: str, serial: bool, in_lanes: bool) -> SimpleNamespace:
    real = ti.f64 if precision == "f64" else ti.f32
    vec = ti.types.ndarray(dtype=real, ndim=1)
    ivec = ti.types.ndarray(dtype=ti.i32, ndim=1)

    @ti.func
    def row_entry(i, indptr: ti.template(), indices: ti.template(), data: ti.template(),
                  x: ti.template(), y: ti.template(), a: ti.template()):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            acc += data[k] * x[indices[k]]
        y[i] = acc
        return ti.Vector([a[i] * acc, acc * acc])

    @ti.kernel
    def csr_matvec_dot(indptr: ivec, indices: ivec, data: vec, x: vec, y: vec, a: vec,
                       nrows: ti.i32, part: ti.types.ndarray()) -> (real, real):
        """y = A x; returns (<a, y>, <y, y>) (plain applies pass a = y and ignore
        them: two multiply-adds a row); the sums in lanes on a GPU."""
        dots = lanes.fold_entries(nrows, row_entry, (indptr, indices, data, x, y, a), 2, 1,
                                  lanes.ADD, in_lanes, serial, part)
        return dots[0], dots[1]

    @ti.kernel
    def csr_diagonal(indptr: ivec, indices: ivec, data: vec, d: vec, nrows: ti.i32):
        ti.loop_config(serialize=serial)
        for i in range(nrows):
            acc = 0.0
            for k in range(indptr[i], indptr[i + 1]):
                if indices[k] == i:
                    acc += data[k]
            d[i] = acc

    @ti.kernel
    def csr_row_sq_norms(indptr: ivec, data: vec, d: vec, nrows: ti.i32):
        ti.loop_config(serialize=serial)
        for i in range(nrows):
            acc = 0.0
            for k in range(indptr[i], indptr[i + 1]):
                acc += data[k] * data[k]
            d[i] = acc

    return SimpleNamespace(csr_matvec_dot=csr_matvec_dot, csr_diagonal=csr_diagonal,
                           csr_row_sq_norms=csr_row_sq_norms)
