"""Dropped Taichi ndarrays given back to the device.

Taichi 1.7 frees an ndarray's memory in ``ScalarNdarray.__del__`` only, and
there not always:

* ``VectorNdarray`` and ``MatrixNdarray`` have no ``__del__``: every vector
  ndarray made and dropped stays allocated (taichi-dev/taichi issue #8763;
  the fix, PR #8764, moves ``__del__`` to the base class).
* On the SPIR-V archs (Vulkan, Metal, OpenGL) ``Program.delete_ndarray``
  does nothing while a launch since the last synchronisation used the array
  (``GfxRuntime::used_in_kernel``: the launch may still be running), and
  nothing asks again.  An array a kernel used and Python dropped before the
  next ``ti.sync()`` stays allocated for the life of the process: on
  lavapipe 60 such 8 MB arrays kept 455 MB, the same with ``ti.sync()``
  after each drop, and 20 MB with it before (docs/arch.md).

:func:`install` gives every ndarray class one ``__del__``: where Taichi
frees at once (the CPU and CUDA) it does so; on a SPIR-V arch it keeps the
array's handle on a list, and once the list holds :data:`DEFER_BYTES` or
:data:`DEFER_COUNT` arrays (or at :func:`release_deferred`) synchronises
and frees them all, when no launch can still use them.  The synchronisation
waits for the launches queued so far, as every download of a result does.
"""
from __future__ import annotations

import threading

#: a SPIR-V arch's dropped arrays are freed once they hold this many bytes...
DEFER_BYTES = 256 << 20
#: ...or are this many
DEFER_COUNT = 512

_lock = threading.Lock()
_deferred: list = []            # (the Program they belong to, C++ Ndarray handle)
_deferred_bytes = 0
_installed = False


def _impl():
    from taichi.lang import impl
    return impl


_arch_of: list = [None, False]   # (the Program last asked about, whether it is SPIR-V)


def _spirv_arch(impl, prog) -> bool:
    """Whether ``prog`` runs a SPIR-V arch (asked once a Program: a drop
    costs Taichi's own deletion and little more)."""
    if _arch_of[0] is not prog:
        import taichi as ti
        arch = impl.current_cfg().arch
        _arch_of[:] = [prog, any(arch == getattr(ti, name, None)
                                 for name in ("vulkan", "metal", "opengl", "gles", "dx11"))]
    return _arch_of[1]


def _release(self) -> None:
    """``__del__`` of every Taichi ndarray class (:func:`install`)."""
    global _deferred_bytes
    try:
        impl = _impl()
        runtime = impl.get_runtime()
        prog = runtime.prog if runtime is not None else None
        arr = getattr(self, "arr", None)
        if prog is None or arr is None:
            return
        if not _spirv_arch(impl, prog):
            prog.delete_ndarray(arr)
            return
        with _lock:
            _deferred.append((prog, arr))
            _deferred_bytes += arr.nelement() * arr.element_size()
            full = _deferred_bytes >= DEFER_BYTES or len(_deferred) >= DEFER_COUNT
        if full:
            release_deferred()
    except Exception:       # a destructor must not raise (interpreter exit, a reset)
        pass


def release_deferred() -> int:
    """Free the dropped ndarrays a SPIR-V arch still holds (after a
    synchronisation: Taichi frees none a queued launch may use); returns how
    many.  Arrays of a Taichi program since reset are forgotten, not freed
    (their memory went with it)."""
    global _deferred_bytes
    with _lock:
        todo = list(_deferred)
        _deferred.clear()
        _deferred_bytes = 0
    if not todo:
        return 0
    impl = _impl()
    runtime = impl.get_runtime()
    prog = runtime.prog if runtime is not None else None
    mine = [arr for owner, arr in todo if owner is prog]
    if not mine:
        return 0
    prog.synchronize()      # clears the arch's record of arrays in use
    for arr in mine:
        prog.delete_ndarray(arr)
    return len(mine)


def deferred() -> int:
    """How many dropped ndarrays wait for :func:`release_deferred`."""
    return len(_deferred)


def install() -> None:
    """Give Taichi's ndarray classes :func:`_release` as ``__del__`` (once:
    a later removal, as ``benchmarks/flow_memory.py --without-vector-free``
    does, sticks).  Where Taichi's layout differs (it is pinned below 1.8),
    its classes are left alone."""
    global _installed
    if _installed:
        return
    _installed = True
    try:
        from taichi.lang import _ndarray, matrix
    except ImportError:
        return
    if getattr(_ndarray.ScalarNdarray, "__del__", None) is None:
        return
    for cls in (_ndarray.ScalarNdarray, getattr(matrix, "VectorNdarray", None),
                getattr(matrix, "MatrixNdarray", None)):
        if cls is not None:
            cls.__del__ = _release
