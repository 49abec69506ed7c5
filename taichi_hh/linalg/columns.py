"""Several right-hand sides in one pass: vectors whose entries hold one value per column.

The decomposition solves two Poisson problems with the same matrix (phi and
psi, Petronetto Eq. 5).  At a million particles an iteration is bound by
memory traffic over the matrix's pair arrays, which does not grow with the
number of columns: kernels that read each pair once for both columns do two
solves' iterations in little more than one's time (docs/notes/scattered.md,
"Both potentials in one solve").  Such kernels take Taichi arrays of scalars (one column) or
of ``cols``-vectors (several), with ``cols`` a compile-time argument; their
accumulators start from :func:`zeros`.
"""
import taichi as ti

__all__ = ["zeros", "columns_of"]


@ti.func
def zeros(cols: ti.template()):
    """A zero accumulator for ``cols`` columns: the scalar 0 or a zero vector."""
    if ti.static(cols == 1):
        return 0.0
    else:
        return ti.Vector.zero(float, cols)


def columns_of(array) -> int:
    """How many columns a 1-D Taichi array holds: 1 for scalars, else its vector length."""
    return int(getattr(array, "n", 1)) if len(array.shape) == 1 else 1
