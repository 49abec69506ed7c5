"""Particle state: one Taichi array per quantity, with a capacity.

Quantities are Taichi ndarrays (``position``/``velocity``/``normal``: 2-vectors,
the normal being the outward unit normal of boundary particles; ``mass``,
``density``, ``volume``: reals; ``phase``, ``kind``: int32), allocated at a
capacity and used on their first ``n`` entries.  ``original_index`` records,
for every slot, which input point lives there, because the neighbour grid
physically reorders particles by cell (for memory locality: in random order
the same kernels run several times slower, docs/notes/sph.md).

Why ndarrays and not ``ti.field``: a kernel taking fields is compiled once per
field *object* (every new particle set would recompile), whereas a kernel taking ndarrays is compiled once per dtype and cached on disk,
so every new particle set of any size reuses the compiled code.
"""

from enum import IntEnum

import numpy as np
import taichi as ti

from .. import runtime


class Kind(IntEnum):
    """What a particle is (the ``kind`` quantity; kernels compare against these).

    ``FLUID``: a data point of a decomposition, a fluid particle of a flow.
    ``BOUNDARY``: a particle on the domain's boundary carrying its outward
    normal, whose row holds the boundary condition (collocation, Colin Eq. 37).
    ``GHOST``: a particle outside the domain whose value continues the
    interior's by a Shepard sum over its FLUID neighbours: Petronetto's fake
    particles (Eq. 14) and the flow's wall particles, named ``WALL`` there
    (the same role, so the same rows: the wall's pressure is the Shepard sum
    of the fluid's plus the hydrostatic term).
    """
    FLUID = 0
    BOUNDARY = 1
    GHOST = 2
    WALL = 2                # an alias of GHOST: the flow's wall particles


FLUID, BOUNDARY, GHOST, WALL = Kind.FLUID, Kind.BOUNDARY, Kind.GHOST, Kind.WALL
KIND_NAMES = {FLUID: "fluid", BOUNDARY: "boundary", GHOST: "ghost"}

VECTOR_QUANTITIES = ("position", "velocity", "normal")
REAL_QUANTITIES = ("mass", "density", "volume")
INT_QUANTITIES = ("phase", "kind", "original_index")
QUANTITIES = VECTOR_QUANTITIES + REAL_QUANTITIES + INT_QUANTITIES


@ti.kernel
def _gather_all(order: ti.types.ndarray(), n: ti.i32,
                pos: ti.types.ndarray(), vel: ti.types.ndarray(), nrm: ti.types.ndarray(),
                mass: ti.types.ndarray(),
                rho: ti.types.ndarray(), vol: ti.types.ndarray(), phase: ti.types.ndarray(),
                kind: ti.types.ndarray(), orig: ti.types.ndarray(),
                pos2: ti.types.ndarray(), vel2: ti.types.ndarray(), nrm2: ti.types.ndarray(),
                mass2: ti.types.ndarray(),
                rho2: ti.types.ndarray(), vol2: ti.types.ndarray(), phase2: ti.types.ndarray(),
                kind2: ti.types.ndarray(), orig2: ti.types.ndarray()):
    # one fused gather for every standard quantity: new[k] = old[order[k]]
    for k in range(n):
        j = order[k]
        pos2[k] = pos[j]
        vel2[k] = vel[j]
        nrm2[k] = nrm[j]
        mass2[k] = mass[j]
        rho2[k] = rho[j]
        vol2[k] = vol[j]
        phase2[k] = phase[j]
        kind2[k] = kind[j]
        orig2[k] = orig[j]


@ti.kernel
def gather_real(order: ti.types.ndarray(), n: ti.i32, src: ti.types.ndarray(), dst: ti.types.ndarray()):
    """dst[k] = src[order[k]] for k < n (any element type)."""
    for k in range(n):
        dst[k] = src[order[k]]


@ti.kernel
def _scatter(rank: ti.types.ndarray(), n: ti.i32, src: ti.types.ndarray(), dst: ti.types.ndarray()):
    """dst[rank[i]] = src[i] for i < n (any element type); rank a permutation."""
    for i in range(n):
        dst[rank[i]] = src[i]


@ti.kernel
def to_slots(values: ti.types.ndarray(), slot: ti.types.ndarray(), ncomp: ti.template(),
              vector: ti.template(), out: ti.types.ndarray()):
    """out[slot[i]] = values[i, :] in the runtime's precision (``vector``: out
    holds vectors of ``ncomp``, else scalars)."""
    for i in range(values.shape[0]):
        if ti.static(not vector):
            out[slot[i]] = ti.cast(values[i, 0], float)
        else:
            v = ti.Vector.zero(float, ncomp)
            for c in ti.static(range(ncomp)):
                v[c] = ti.cast(values[i, c], float)
            out[slot[i]] = v


@ti.kernel
def from_slots(nd: ti.types.ndarray(), slot: ti.types.ndarray(), ncomp: ti.template(),
                vector: ti.template(), out: ti.types.ndarray()):
    """out[i, :] = nd[slot[i]] in float64 (``vector``: nd holds vectors)."""
    for i in range(out.shape[0]):
        if ti.static(not vector):
            out[i, 0] = ti.cast(nd[slot[i]], ti.f64)
        else:
            v = nd[slot[i]]
            for c in ti.static(range(ncomp)):
                out[i, c] = ti.cast(v[c], ti.f64)


def _alloc(name: str, capacity: int):
    real = runtime.real_dtype()
    if name in VECTOR_QUANTITIES:
        return runtime.array(real, capacity, vector=2)
    if name in REAL_QUANTITIES:
        return runtime.array(real, capacity)
    return runtime.array(ti.i32, capacity)


class Particles:
    """A set of 2D particles held in Taichi arrays.

    Build with :meth:`from_numpy`; grow with :meth:`reserve` / :meth:`append`.
    """

    def __init__(self, capacity: int):
        runtime.ensure_init()
        self._generation = runtime.generation()
        self.capacity = max(int(capacity), 1)
        self.n = 0
        self.arrays = {name: _alloc(name, self.capacity) for name in QUANTITIES}
        self._scratch: dict | None = None

    def __getattr__(self, name):
        arrays = self.__dict__.get("arrays")
        if arrays is not None and name in arrays:
            return arrays[name]
        raise AttributeError(name)

    # ---- construction -------------------------------------------------------
    @classmethod
    def from_numpy(cls, points, *, velocity=None, mass=None, kind=FLUID, phase=0,
                   capacity: int | None = None) -> "Particles":
        points = np.asarray(points)
        n = points.shape[0]
        p = cls(capacity or n)
        p.append(points, velocity=velocity, mass=mass, kind=kind, phase=phase)
        return p

    def reserve(self, capacity: int) -> None:
        """Grow the capacity (contents kept); never shrinks."""
        runtime.check_generation(self._generation, "particle set")
        if capacity <= self.capacity:
            return
        new_cap = max(int(capacity), int(self.capacity * 1.5))
        for name in QUANTITIES:
            old = self.arrays[name]
            new = _alloc(name, new_cap)
            if self.n:
                new_np = new.to_numpy()
                new_np[: self.n] = old.to_numpy()[: self.n]
                new.from_numpy(new_np)
            self.arrays[name] = new
        self.capacity = new_cap
        self._scratch = None

    def append(self, points, *, velocity=None, mass=None, kind=FLUID, phase=0,
               normal=None) -> slice:
        """Append particles; returns the slice of slots they occupy."""
        runtime.check_generation(self._generation, "particle set")
        points = np.asarray(points, dtype=np.float64)
        m = points.shape[0]
        start = self.n
        self.reserve(start + m)
        values = {
            "position": points,
            "velocity": np.zeros((m, 2)) if velocity is None else np.asarray(velocity, float),
            "normal": np.zeros((m, 2)) if normal is None else np.asarray(normal, float),
            "mass": np.broadcast_to(np.asarray(0.0 if mass is None else mass, float), (m,)),
            "density": np.zeros(m),
            "volume": np.zeros(m),
            "phase": np.broadcast_to(np.asarray(phase, np.int32), (m,)),
            "kind": np.broadcast_to(np.asarray(kind, np.int32), (m,)),
            "original_index": np.arange(start, start + m, dtype=np.int32),
        }
        for name, val in values.items():
            self.set(name, val, start=start)
        self.n = start + m
        return slice(start, start + m)

    # ---- numpy access ---------------------------------------------------------
    def get(self, name: str) -> np.ndarray:
        """The first ``n`` entries of a quantity as a numpy copy."""
        runtime.check_generation(self._generation, "particle set")
        return self.arrays[name].to_numpy()[: self.n].copy()

    def set(self, name: str, values, start: int = 0) -> None:
        """Write ``values`` into slots ``start:start+len(values)``."""
        runtime.check_generation(self._generation, "particle set")
        arr = self.arrays[name]
        values = np.asarray(values)
        if start == 0 and values.shape[0] == arr.shape[0]:
            # the whole array: nothing of the old contents to keep (no read back)
            dtype = np.int32 if name in INT_QUANTITIES else runtime.np_real()
            full = np.ascontiguousarray(values, dtype=dtype)
        else:
            full = arr.to_numpy()
            full[start: start + values.shape[0]] = values
        arr.from_numpy(full)

    # ---- reordering -----------------------------------------------------------
    def permute(self, order, *, inverse=None) -> None:
        """Physically reorder: slot k receives the particle that was in ``order[k]``.

        ``order`` is an int32 Taichi ndarray (or numpy array) of length >= n.
        ``inverse`` (optional, same kinds of array): the inverse permutation,
        ``inverse[order[k]] == k``; when given, particles are written to their
        slots instead of gathered from theirs (faster when ``order`` is far
        from sorted), with the same result.
        """
        runtime.check_generation(self._generation, "particle set")
        perm = order if inverse is None else inverse
        if isinstance(perm, np.ndarray):
            nd = runtime.array(ti.i32, max(perm.shape[0], 1))
            nd.from_numpy(perm.astype(np.int32))
            perm = nd
        if self._scratch is None:
            self._scratch = {name: _alloc(name, self.capacity) for name in QUANTITIES}
        a, s = self.arrays, self._scratch
        if inverse is None:
            _gather_all(perm, self.n, *(a[q] for q in QUANTITIES), *(s[q] for q in QUANTITIES))
        else:
            # one pass per quantity: each pass's scattered writes then stay within
            # one array, which stays in cache far more often than all of them
            for q in QUANTITIES:
                _scatter(perm, self.n, a[q], s[q])
        self.arrays, self._scratch = s, a

    def kinds(self) -> np.ndarray:
        return self.get("kind")
