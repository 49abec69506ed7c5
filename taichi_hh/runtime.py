"""Taichi runtime ownership: the only module that calls ``ti.init``.

Nothing in :mod:`taichi_hh` initialises Taichi at import time.  The first call
that needs Taichi runs :func:`ensure_init`, which initialises the CPU arch (or
the one ``$TAICHI_HH_ARCH`` names) in double precision unless :func:`init` was
called before with other settings.

Precision is a runtime-wide choice (Taichi's ``default_fp``): every ``float``
inside a kernel and every real-valued array this package allocates follows it.
Re-initialising with other settings invalidates every Taichi array made before
(Taichi frees them); objects of this package remember the runtime generation
they were made in and refuse to run on a later one instead of crashing.
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass

import numpy as np

from .errors import InputError

#: the arch choices of :func:`init`: a backend by name, any GPU backend, or
#: whatever is present
ARCHES = ("cpu", "cuda", "vulkan", "gpu", "auto")
#: the environment variable that names the default arch (of :func:`init`, the
#: lazy start, the command line and the scenes; CI's Vulkan run sets it)
ARCH_VARIABLE = "TAICHI_HH_ARCH"
#: set to 1: Taichi's kernel profiler on (each kernel's device time, CUDA and
#: CPU; benchmarks print it), at the cost of a synchronisation per launch
PROFILER_VARIABLE = "TAICHI_HH_KERNEL_PROFILER"
#: set to 1 or 0: the GPU's loop schedule on or off whatever the device (:func:`on_gpu`)
GPU_SCHEDULE_VARIABLE = "TAICHI_HH_GPU_SCHEDULE"
#: set to 1 or 0: work arrays on the device (Taichi ndarrays) or in numpy,
#: whatever the arch (:func:`resident`)
RESIDENT_VARIABLE = "TAICHI_HH_RESIDENT"
#: the GPU backends ``"gpu"`` and ``"auto"`` try, in order (Metal first on macOS)
GPU_BACKENDS = ("cuda", "vulkan")
_PRECISIONS = {"f32": np.float32, "f64": np.float64}


@dataclass
class RuntimeState:
    initialized: bool = False
    arch: str = ""           # the backend Taichi actually runs on: cpu, cuda, vulkan, metal
    requested_arch: str = ""
    precision: str = ""
    generation: int = 0      # bumped on every (re)initialisation
    pinned: tuple = ()       # CPUs Taichi's worker threads were bound to, in order
    device: str = ""         # the Vulkan device's name where known ("" otherwise)
    software: bool = False   # a CPU behind the Vulkan API (Mesa's lavapipe)
    refused: bool = False    # a GPU request found no device: Taichi started and was reset


_state = RuntimeState()


class FloatingPointEnvironment:
    """The calling thread's floating-point environment (C's ``fenv_t``: the
    rounding mode and, on x86-64, the MXCSR's flush-to-zero and
    denormals-are-zero bits), saved and put back around ``ti.init``.

    Taichi's CPU runtime switches the thread that initialises it to
    flush-to-zero; numpy runs on that thread, so without this every subnormal
    in the process became 0 (a field of 1e-300 lost its components below
    2.2e-308 once mapped back to its units).  Kernels keep Taichi's own mode.
    Where the C library has no ``fegetenv`` (Windows) nothing is done.
    """

    def __init__(self):
        self._lib = None
        try:
            import ctypes
            import ctypes.util
            name = ctypes.util.find_library("m") or ctypes.util.find_library("c")
            lib = ctypes.CDLL(name) if name else None
            if lib is not None and hasattr(lib, "fegetenv") and hasattr(lib, "fesetenv"):
                self._lib = lib
                self._saved = ctypes.create_string_buffer(1024)   # > any fenv_t
        except OSError:
            self._lib = None

    def save(self) -> None:
        if self._lib is not None and self._lib.fegetenv(self._saved) != 0:
            self._lib = None

    def restore(self) -> None:
        if self._lib is not None:
            self._lib.fesetenv(self._saved)


def subnormals_kept() -> bool:
    """Whether numpy on this thread keeps subnormal numbers (not flushed to 0)."""
    tiny = np.array([np.finfo(np.float64).tiny])
    return bool((tiny / 4.0)[0] != 0.0)


def _taichi():
    import taichi as ti  # imported lazily: importing taichi prints a banner
    from . import ndarray_release
    ndarray_release.install()   # dropped ndarrays freed (vector ones, and on Vulkan)
    from .kernel_transform import install
    install()                # kernels' Python->IR transforms memoised (kernel_transform.py)
    return ti


def default_arch() -> str:
    """The arch :func:`init` takes when given none: ``$TAICHI_HH_ARCH`` where
    set, else ``"cpu"``."""
    arch = os.environ.get(ARCH_VARIABLE, "").strip() or "cpu"
    if arch not in ARCHES:
        raise InputError(f"${ARCH_VARIABLE} must be one of {ARCHES}, got {arch!r}")
    return arch


#: the offline cache's size past which Taichi drops the least recently used
#: quarter of its kernels (Taichi's default, 100 MB, is about one version of
#: this package's kernels: a cache shared by a few versions or processes,
#: full, then dropped kernels that the next call compiled again, seconds each)
OFFLINE_CACHE_BYTES = 1 << 30


def init(arch: str | None = None, precision: str = "f64", *, offline_cache_dir: str | None = None,
         threads: int | None = None, debug: bool = False, verbose: bool = True,
         pin_threads: bool | None = None) -> RuntimeState:
    """Initialise Taichi for this package.

    arch: ``"cpu"``; ``"cuda"`` or ``"vulkan"`` (that backend); ``"gpu"``
    (the first GPU backend that starts: CUDA, then Vulkan; Metal first on
    macOS; a Vulkan whose only device is a CPU driver, lavapipe, does not
    count) or ``"auto"`` (a GPU backend when one starts, the CPU otherwise);
    None: :func:`default_arch` (``$TAICHI_HH_ARCH``, else ``"cpu"``).  A GPU
    request that no device can serve (``cuda``, ``vulkan``, ``gpu``) raises
    :class:`~taichi_hh.errors.InputError` naming the backends tried: Taichi
    itself falls back to the CPU silently, so the arch Taichi reports after
    starting is checked.  The arch in use is :attr:`RuntimeState.arch`.
    precision: ``"f32"`` or ``"f64"``; the default floating type of every kernel.
    verbose: kept for callers of the time a missing GPU printed a message;
    nothing is printed now (a missing GPU is an error).
    offline_cache_dir: where Taichi keeps compiled kernels between runs
    (default: Taichi's own, or ``$TAICHI_HH_CACHE`` when set).
    threads: CPU worker threads (default: all cores).
    pin_threads: bind each of Taichi's CPU worker threads to its own core
    (default: on where the process may use two or more cores; off with
    ``$TAICHI_HH_PIN_THREADS=0``).  Unbound, Linux wakes both workers on the
    core that launched the loop and moves one away only after a few
    milliseconds, so loops shorter than that ran on one core
    (docs/notes/flow.md, "Worker threads").
    """
    if arch is None:
        arch = default_arch()
    if arch not in ARCHES:
        raise InputError(f"arch must be one of {ARCHES}, got {arch!r}")
    if precision not in _PRECISIONS:
        raise ValueError(f"precision must be one of {tuple(_PRECISIONS)}, got {precision!r}")
    ti = _taichi()
    if _state.initialized:
        if (_state.requested_arch, _state.precision) == (arch, precision):
            return _state
        ti.reset()
    environment = FloatingPointEnvironment()
    environment.save()
    try:
        _start(ti, arch, precision, offline_cache_dir, threads, debug, pin_threads)
    finally:
        environment.restore()
    return _state


def _start(ti, arch, precision, offline_cache_dir, threads, debug, pin_threads) -> None:
    """:func:`init`'s work once the arguments are checked."""
    kwargs = dict(default_fp=ti.f64 if precision == "f64" else ti.f32, default_ip=ti.i32,
                  offline_cache=True, offline_cache_max_size_of_files=OFFLINE_CACHE_BYTES,
                  debug=debug, log_level=ti.WARN)
    if os.environ.get(PROFILER_VARIABLE, "0") not in ("", "0"):
        kwargs["kernel_profiler"] = True     # ti.profiler.print_kernel_profiler_info()
    cache = offline_cache_dir or os.environ.get("TAICHI_HH_CACHE")
    if cache:
        os.makedirs(cache, exist_ok=True)
        kwargs["offline_cache_file_path"] = cache
    if threads:
        kwargs["cpu_max_num_threads"] = int(threads)
    actual = "cpu"
    tried = []
    if arch != "cpu":
        # Backends one by one rather than ti.gpu: its OpenGL probe segfaults on
        # machines without a display (seen on the CPU-only CI boxes), while CUDA
        # and Vulkan fall back to the CPU cleanly when absent.
        names = (arch,) if arch in GPU_BACKENDS else _gpu_backends()
        for name in names:
            tried.append(name)
            if name == "vulkan" and arch != "vulkan" and _software_vulkan_only():
                continue     # Mesa's lavapipe: a CPU behind the Vulkan API, far slower
            ti.init(arch=getattr(ti, name), **kwargs)
            if ti.lang.impl.current_cfg().arch == getattr(ti, name):
                actual = name
                break
            ti.reset()
    if actual == "cpu" and arch not in ("cpu", "auto"):
        software = arch == "gpu" and _software_vulkan_only()
        _state.initialized = False          # Taichi was reset: nothing is running
        _state.generation += 1              # and every array made before is gone
        _state.refused = True
        raise InputError(
            f"arch={arch!r} asks for a GPU backend, but Taichi found no usable "
            f"{' or '.join(tried)} device on this machine (no driver, or no device "
            "it can start"
            + ("; the only Vulkan device is a CPU driver (Mesa's lavapipe), which "
               "arch='vulkan' still takes" if software else "")
            + "); use arch='cpu', or 'auto' to take a GPU only where one exists")
    if actual == "cpu":
        ti.init(arch=ti.cpu, **kwargs)
    _state.pinned = ()
    if actual == "cpu":
        if pin_threads is None:
            pin_threads = os.environ.get("TAICHI_HH_PIN_THREADS", "1") != "0"
        if pin_threads:
            _state.pinned = _pin_workers(ti)
    _state.initialized = True
    _state.arch = actual
    _state.device = _device_name(actual)
    _state.software = actual == "vulkan" and _software_vulkan_only()
    if _state.software:
        check_mapping_limit()
    _state.requested_arch = arch
    _state.precision = precision
    _state.generation += 1


def _thread_runtimes() -> dict:
    """Nanoseconds each thread of this process has run (Linux schedstat)."""
    out = {}
    for name in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{name}/schedstat") as f:
                out[int(name)] = int(f.read().split()[0])
        except (OSError, ValueError, IndexError):
            pass
    return out


def busy_threads(ran: dict, workers: int) -> list:
    """The threads (sorted ids) that ran more than a tenth of a worker's fair
    share, ``sum(ran) / workers``, of ``ran`` (thread id -> nanoseconds run
    during the probe loops): Taichi's workers where their count is
    ``workers`` (:func:`_pin_workers` binds nothing otherwise)."""
    total = sum(ran.values())
    return sorted(t for t, dt in ran.items() if total and dt > 0.1 * total / workers)


def _pin_workers(ti) -> tuple:
    """Bind Taichi's CPU worker threads one to a core; return the cores used.

    Taichi starts its thread pool in ``ti.init`` and does not expose it, so the
    workers are found by what they do: the threads other than this one that
    ran a parallel loop launched for the purpose.  Nothing is bound unless the
    count found equals Taichi's worker count (a foreign thread busy at the same
    time, an unknown Taichi layout), nor where the process may use one core.
    """
    if not (hasattr(os, "sched_setaffinity") and os.path.isdir("/proc/self/task")):
        return ()
    cpus = sorted(os.sched_getaffinity(0))
    workers = int(ti.lang.impl.current_cfg().cpu_max_num_threads)
    if len(cpus) < 2 or workers < 2:
        return ()
    import threading

    def spin(out):
        for i in range(4096):
            a = ti.cast(i, ti.f32) * 1e-6
            for _ in range(400):
                a = a * 0.999 + 0.001 * ti.sin(a)
            out[i] = a

    # set by hand: this module's postponed annotations would be strings
    spin.__annotations__ = {"out": ti.types.ndarray()}
    spin = ti.kernel(spin)
    out = ti.ndarray(ti.f64, shape=(4096,))
    spin(out)                                  # compiled, pool running
    ti.sync()
    main = threading.get_native_id()
    start = _thread_runtimes()
    busy = []
    for _ in range(4):              # a busy machine may wake a worker late
        spin(out)
        ti.sync()
        now = _thread_runtimes()
        busy = busy_threads({t: now[t] - start.get(t, 0) for t in now if t != main}, workers)
        if len(busy) == workers:
            break
    if len(busy) != workers:
        return ()
    used = []
    try:
        for j, tid in enumerate(busy):
            cpu = cpus[j % len(cpus)]
            os.sched_setaffinity(tid, {cpu})
            used.append(cpu)
    except OSError:
        for tid in busy:
            try:
                os.sched_setaffinity(tid, set(cpus))
            except OSError:
                pass
        return ()
    return tuple(used)


def _gpu_backends() -> tuple:
    return ("metal",) + GPU_BACKENDS if sys.platform == "darwin" else GPU_BACKENDS


def vulkan_devices() -> list | None:
    """``[(name, kind)]`` of the Vulkan devices the loader lists, ``kind`` one of
    ``other``, ``integrated``, ``discrete``, ``virtual``, ``cpu``; None where
    no Vulkan loader or instance is to be had.  Asked of the Vulkan loader
    directly (Taichi does not say which device it took); a ``cpu`` device is a
    software driver such as Mesa's lavapipe, which Taichi takes as readily as
    a GPU."""
    import ctypes
    import ctypes.util
    names = [ctypes.util.find_library("vulkan"), "libvulkan.so.1", "vulkan-1", "libvulkan.1.dylib"]
    lib = None
    for name in filter(None, names):
        try:
            lib = ctypes.CDLL(name)
            break
        except OSError:
            continue
    if lib is None:
        return None

    class InstanceCreateInfo(ctypes.Structure):
        _fields_ = [("sType", ctypes.c_uint32), ("pNext", ctypes.c_void_p),
                    ("flags", ctypes.c_uint32), ("pApplicationInfo", ctypes.c_void_p),
                    ("enabledLayerCount", ctypes.c_uint32), ("ppEnabledLayerNames", ctypes.c_void_p),
                    ("enabledExtensionCount", ctypes.c_uint32),
                    ("ppEnabledExtensionNames", ctypes.c_void_p)]

    info = InstanceCreateInfo(sType=1)        # VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO
    instance = ctypes.c_void_p()
    if lib.vkCreateInstance(ctypes.byref(info), None, ctypes.byref(instance)) != 0:
        return None
    try:
        count = ctypes.c_uint32(0)
        lib.vkEnumeratePhysicalDevices(instance, ctypes.byref(count), None)
        handles = (ctypes.c_void_p * count.value)()
        lib.vkEnumeratePhysicalDevices(instance, ctypes.byref(count), handles)
        kinds = ("other", "integrated", "discrete", "virtual", "cpu")
        out = []
        for handle in handles[:count.value]:
            # VkPhysicalDeviceProperties: four uint32, the type, then the name
            props = ctypes.create_string_buffer(4096)
            lib.vkGetPhysicalDeviceProperties(ctypes.c_void_p(handle), props)
            kind = int.from_bytes(props.raw[16:20], sys.byteorder)
            name = props.raw[20:276].split(b"\0", 1)[0].decode(errors="replace")
            out.append((name, kinds[kind] if kind < len(kinds) else "other"))
        return out
    finally:
        lib.vkDestroyInstance(instance, None)


def _software_vulkan_only() -> bool:
    """Whether every Vulkan device is a CPU driver (lavapipe): Vulkan then is
    no GPU, and ``"gpu"``/``"auto"`` do not take it."""
    devices = vulkan_devices()
    return bool(devices) and all(kind == "cpu" for _, kind in devices)


#: memory mappings a long run on lavapipe wants (:func:`check_mapping_limit`)
LAVAPIPE_MAPPINGS = 1 << 20


def check_mapping_limit(path: str = "/proc/sys/vm/max_map_count") -> int | None:
    """Warn, on Mesa's lavapipe, where the kernel's limit on a process's
    memory mappings is low: lavapipe keeps the descriptor set of every kernel
    launch in a mapping of its own (it never reports a full pool, and Taichi
    1.7 opens a new one only when told), and once the limit is reached its
    next allocation segfaults (docs/arch.md).  Returns the limit read (None
    where there is none to read)."""
    try:
        with open(path) as fh:
            limit = int(fh.read().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    if limit < LAVAPIPE_MAPPINGS:
        import warnings
        warnings.warn(
            f"Vulkan runs on Mesa's lavapipe here, which keeps a memory mapping for "
            f"every kernel launch: this process will crash after about {limit} "
            f"launches (vm.max_map_count = {limit}; a scene takes some 70 a step). "
            f"Raise the limit as root (sysctl -w vm.max_map_count={LAVAPIPE_MAPPINGS}), "
            f"or use arch='cpu'", RuntimeWarning, stacklevel=4)
    return limit


def _device_name(arch: str) -> str:
    """The Vulkan device Taichi runs on: its first GPU device where there is
    one (Taichi prefers them), else the first device."""
    if arch != "vulkan":
        return ""
    devices = vulkan_devices() or []
    gpus = [name for name, kind in devices if kind != "cpu"]
    return (gpus or [name for name, _ in devices] or [""])[0]


def taichi_arch() -> str:
    """The arch Taichi itself reports it runs on (``"cpu"``, ``"vulkan"``, ...),
    read from Taichi rather than from this module's record: what a check that
    the requested arch really is in use compares with."""
    ti = _taichi()
    ensure_init()
    name = ti.lang.impl.current_cfg().arch.name
    return "cpu" if name in ("x64", "arm64") else name


def ensure_init() -> RuntimeState:
    """Initialise lazily (:func:`default_arch`, f64) unless already initialised."""
    if not _state.initialized:
        init()
    return _state


def state() -> RuntimeState:
    return _state


def real_dtype():
    """The Taichi real type of the current runtime (f32 or f64)."""
    ti = _taichi()
    ensure_init()
    return ti.f64 if _state.precision == "f64" else ti.f32


def np_real():
    """The numpy real type matching :func:`real_dtype`."""
    ensure_init()
    return _PRECISIONS[_state.precision]


def generation() -> int:
    return _state.generation


def on_gpu() -> bool:
    """Whether the kernels take the GPU's schedule: on a GPU device (CUDA,
    Vulkan or Metal on a GPU) a loop run on one thread is one GPU thread,
    thousands of times slower than the CPU's, so the loops that run serially
    on the CPU below a size (where waking the thread pool costs more than the
    work) run in parallel, and sums go through lanes
    (:mod:`taichi_hh.linalg.lanes`).  Not on the CPU, nor on a software
    Vulkan driver (Mesa's lavapipe runs on CPU threads: the CPU's schedule
    fits it; docs/arch.md).  ``$TAICHI_HH_GPU_SCHEDULE`` = 1 or 0 forces it
    on or off whatever the device (the tests of the GPU's code paths on the
    CPU and on lavapipe, as ``.ci/vulkan`` runs them)."""
    forced = os.environ.get(GPU_SCHEDULE_VARIABLE, "")
    if forced in ("0", "1"):
        return forced == "1"
    ensure_init()
    return _state.arch != "cpu" and not _state.software


def check_generation(made_in: int, what: str = "object") -> None:
    """Refuse to use Taichi arrays from an earlier runtime (they were freed)."""
    if made_in != _state.generation:
        raise RuntimeError(
            f"this {what} was created before taichi_hh.init() re-initialised Taichi; "
            "its arrays are gone. Create it again.")


#: calls on at least this many particles free the arrays their kernel launches
#: kept alive (:func:`release_launch_arguments`); below it the collection
#: (14-27 ms) would cost more than the memory is worth
RELEASE_MIN_PARTICLES = 100_000


def release_launch_arguments(n_particles: int) -> None:
    """Free what a large call's kernel launches still hold.  Taichi 1.7 builds the
    argument setters of every launch as nested closures that refer to
    themselves (a reference cycle) and to the launch's arguments, so every
    array passed to a kernel stays alive until Python's cycle collector runs,
    which may be long after: a 1M-point decomposition left 1.1 GB so, and
    the next one allocated beside it, slower (docs/notes/scattered.md, "What
    a call leaves behind").  For calls on at least
    :data:`RELEASE_MIN_PARTICLES` particles, runs the collector on its two
    young generations: a warm call's launches are found there (a full
    collection after it finds nothing more) for 0.1 ms, where a full one
    walks every object of the process (Taichi's included: 30 ms).  What a
    first call's compilation leaves older waits for Python's own full
    collections.  On a SPIR-V arch the arrays so dropped are then freed
    (:func:`~taichi_hh.ndarray_release.release_deferred`)."""
    if n_particles >= RELEASE_MIN_PARTICLES:
        import gc
        gc.collect(1)
        from . import ndarray_release
        ndarray_release.release_deferred()


def array(dtype, shape, vector: int | None = None, *, zeroed: bool = True):
    """A Taichi ndarray of ``dtype`` (None: :func:`real_dtype`) and ``shape``, of
    scalars or, with ``vector``, of vectors of that many components: what
    ``ti.ndarray`` and ``ti.Vector.ndarray`` make, without their two hidden costs.

    Taichi 1.7 records the caller's Python traceback for every ndarray (0.1-0.2 ms:
    a tenth of a 13k-point decomposition's allocations) and zero-fills it
    serially, the first touch of fresh pages: 0.4-1.25 s for a 720 MB pair
    array of 1M points, slower the more memory the process holds (4.9 s of a
    1M-point decomposition; docs/notes/scattered.md, "Allocation: Taichi's zero fill").  Here
    the traceback is left out and, with ``zeroed=False``, the fill: for arrays
    a kernel writes in full before anything reads them, whose pages the
    kernel's parallel loop then touches first.  Built with the constructor
    Taichi's own classes call; where that is missing or changed (Taichi is
    pinned below 1.8) the public constructors are used instead, zeroed."""
    ti = _taichi()
    ensure_init()
    dtype = real_dtype() if dtype is None else dtype
    shape = (int(shape),) if np.isscalar(shape) else tuple(int(s) for s in shape)
    try:
        from taichi._lib import core
        from taichi.lang import _ndarray, impl, matrix
        from taichi.lang.enums import Layout
        from taichi.lang.util import cook_dtype
        prog = impl.get_runtime().prog
        if vector is None:
            element = cook_dtype(dtype)
            made = prog.create_ndarray(element, shape, layout=Layout.NULL, zero_fill=zeroed,
                                       dbg_info=core.DebugInfo(""))
            out = _ndarray.ScalarNdarray.__new__(_ndarray.ScalarNdarray)
            _ndarray.Ndarray.__init__(out)
            out.dtype, out.element_type = element, dtype
        else:
            element = matrix._type_factory.get_tensor_type((int(vector),), cook_dtype(dtype))
            made = prog.create_ndarray(cook_dtype(element), shape, Layout.AOS,
                                       zero_fill=zeroed, dbg_info=core.DebugInfo(""))
            out = matrix.VectorNdarray.__new__(matrix.VectorNdarray)
            _ndarray.Ndarray.__init__(out)
            out.n, out.dtype, out.element_type = int(vector), cook_dtype(dtype), element
            out.layout = Layout.AOS
        out.arr = made
        out.shape = tuple(made.shape) if vector is None else shape
        return out
    except (ImportError, AttributeError, TypeError):
        if vector is None:
            return ti.ndarray(dtype, shape=shape)
        return ti.Vector.ndarray(int(vector), dtype, shape=shape)


def resident() -> bool:
    """Whether work arrays that only kernels read live on the device
    (:class:`Device`, Taichi ndarrays) rather than in numpy: on a GPU (CUDA,
    or Vulkan on a GPU).  There Taichi 1.7 copies each numpy argument of a
    kernel to the device before the launch and back after it (on CUDA
    synchronously from pageable memory), so an array written by one kernel
    and read by the next crossed the bus four times (a 1M-point window passed
    1 GB of numpy arguments; docs/arch.md).  Not on the CPU, where a numpy
    argument is not copied and is what the host code reads cheapest; not on
    a software Vulkan driver (lavapipe: the two ways timed alike there).
    Vulkan returns the dropped arrays' memory through
    :mod:`taichi_hh.ndarray_release` (Taichi 1.7 alone kept any array a
    launch had used since the last synchronisation).  ``$TAICHI_HH_RESIDENT``
    = 1 or 0 forces it on or off whatever the arch (the tests of the device
    path on the CPU and lavapipe; an A/B on a GPU)."""
    forced = os.environ.get(RESIDENT_VARIABLE, "")
    if forced in ("0", "1"):
        return forced == "1"
    ensure_init()
    return _state.arch != "cpu" and not _state.software


_NUMPY_TO_TAICHI = {np.dtype(np.float64): "f64", np.dtype(np.float32): "f32",
                    np.dtype(np.int32): "i32", np.dtype(np.int64): "i64"}


class Device:
    """A work array on the device: a flat Taichi ndarray (``nd``) seen with
    a numpy ``shape`` and ``dtype``.  Kernels that take it index it flat
    (:func:`flat`); ``reshape`` gives another view of the same ndarray (Taichi
    1.7's ndarrays have none); ``to_numpy`` copies it to the host.  Made by
    :func:`work` and :func:`to_device`; valid within the Taichi runtime it
    was made in."""

    __slots__ = ("nd", "shape", "dtype")

    def __init__(self, nd, shape, dtype):
        self.nd, self.shape, self.dtype = nd, tuple(int(s) for s in shape), np.dtype(dtype)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def nbytes(self) -> int:
        return self.size * self.dtype.itemsize

    def __len__(self) -> int:
        return self.shape[0]

    def reshape(self, *shape) -> "Device":
        shape = shape[0] if len(shape) == 1 and not np.isscalar(shape[0]) else shape
        shape = list(shape)
        if -1 in shape:
            rest = int(np.prod([s for s in shape if s != -1], dtype=np.int64))
            shape[shape.index(-1)] = self.size // max(rest, 1)
        if int(np.prod(shape, dtype=np.int64)) != self.size:
            raise ValueError(f"cannot reshape a device array of {self.size} into {tuple(shape)}")
        return Device(self.nd, shape, self.dtype)

    def to_numpy(self) -> np.ndarray:
        if self.size == 0:
            return np.empty(self.shape, dtype=self.dtype)
        return self.nd.to_numpy().reshape(self.shape)


def work(shape, dtype=np.float64):
    """An uninitialised work array of ``shape``: a :class:`Device` where
    :func:`resident`, a numpy array otherwise."""
    shape = (int(shape),) if np.isscalar(shape) else tuple(int(s) for s in shape)
    if not resident():
        return np.empty(shape, dtype=dtype)
    ti = _taichi()
    size = max(int(np.prod(shape, dtype=np.int64)), 1)
    nd = array(getattr(ti, _NUMPY_TO_TAICHI[np.dtype(dtype)]), size, zeroed=False)
    return Device(nd, shape, dtype)


def to_device(a, dtype=np.float64):
    """``a`` as a kernel argument that stays put: a :class:`Device` copy where
    :func:`resident` (made once, read by many launches), else ``a`` as a
    C-contiguous numpy array of ``dtype``."""
    if isinstance(a, Device):
        return a
    a = np.ascontiguousarray(a, dtype=dtype)
    if not resident():
        return a
    out = work(a.shape, dtype)
    if a.size:
        out.nd.from_numpy(a.reshape(-1))
    return out


def to_host(a) -> np.ndarray:
    """``a`` as a numpy array: a :class:`Device` copied to the host, else as it is."""
    return a.to_numpy() if isinstance(a, Device) else a


def writable(out, shape) -> bool:
    """Whether ``out`` is an array of ``shape`` that a kernel can write flat:
    a C-contiguous numpy array or a :class:`Device` one (a caller's ``out``,
    else the caller makes one)."""
    return out is not None and tuple(out.shape) == tuple(shape) and (
        isinstance(out, Device) or out.flags.c_contiguous)


def flat(a, dtype=np.float64):
    """``a`` as a flat kernel argument: a :class:`Device`'s ndarray, or a
    numpy array raveled (a view where it is C-contiguous of ``dtype``)."""
    if isinstance(a, Device):
        if a.dtype != np.dtype(dtype):
            raise TypeError(f"a device array of {a.dtype} where {np.dtype(dtype)} is taken")
        return a.nd
    return np.ascontiguousarray(a, dtype=dtype).reshape(-1)


def gpu_refused() -> bool:
    """Whether a GPU backend was asked for and refused in this process (Taichi
    started on it, found no device, and was reset): a process that ends then
    has nothing of Taichi's to keep, and Taichi's teardown after such a start
    has crashed (SIGSEGV, about one exit in six on a loaded machine with a
    Vulkan loader and no device) after the error was reported."""
    return _state.refused

