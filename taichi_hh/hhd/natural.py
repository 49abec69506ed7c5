"""The natural Helmholtz-Hodge decomposition (Bhatia et al. 2014): potentials
from the free-space Green's function, no boundary condition imposed.

    phi(x) = int_Omega G(x - y) div v(y) dy,   psi(x) = -int_Omega G(x - y) curl v(y) dy,
    G(x) = ln|x| / (2 pi)   (lap G = delta in 2D),

so that lap phi = div v and lap psi = -curl v (the sign of psi keeps r = J grad
psi, J of :mod:`.rotation`), d = grad phi, r = J grad psi, h = v - d - r is
harmonic inside Omega.  d and r are the fields that the sources and vortices
inside Omega alone induce; whatever enters from outside (a constant, a
gradient of a harmonic function) is h.

Discretisation (particle-mesh, Hockney and Eastwood): div v and curl v at the
centres of a regular grid of cells about one data spacing wide, weighted by
the fraction of each cell inside Omega.  The default
(:func:`natural_decomposition`) takes them from the gradient of a cubic
moving-least-squares fit of v itself at each cell centre (no operator at
the points, no neighbour search); with other operator options the SPH
operators' div v and curl v at the points are reconstructed at the centres
by quadratic moving least squares (:func:`natural_potentials`).  Then the
convolution with G over the grid (midpoint rule, with the integral of G over
the cell itself on the diagonal) is done by zero-padded FFT in O(M log M) for
M cells, or by direct summation in a Taichi kernel (O(M^2), one gather per
target cell) as the exact reference of the same sum; the gradients of the
potentials by fourth-order central differences on the grid, interpolated to
the points.  Why a grid and not the points themselves as quadrature nodes:
the point sum sum_j grad G(x_i - y_j) div v_j V_j errs by the points'
irregularity within each cell, which does not average out near the target
(measured 4-5% mean error of d on the ``gaussian`` field at 1.5k-13k
blue-noise points, hardly falling); the midpoint rule on a uniform grid is
second order and its error is smooth, so differencing it keeps second order
(docs/notes/hhd.md).
"""
import math
import threading
import time

import numpy as np

from .. import runtime
from ..geometry.box import Box
from .cell_counts import spacing_edge_volume
from .cut_cells import (MULTIPOLE_ORDER, cut_cells, multipole_density, multipole_patches,
                        near_field_correction, part_moments)
from .free_space import (Grid, axis_rectangle, convolve_direct, convolve_fft, edge_padded,
                         with_differences)
from .grid_sampling import (ONE_SIDED_CELLS, SPLINE_PAD, lagrange_at, one_sided_gradient,
                            one_sided_weights, prefilter, spline_values)
from .natural_assemble import assemble, columns, node_densities, row_index
from .mls_reconstruct import reconstruct_on_grid
from .node_fits import FitWeights, PointBins, abs_div_curl, fit_gradients
from .options import NATURAL_EVALUATIONS
from .rotation import J

#: subsamples per side of a cell a rectangle's side may cross, for its inside
#: fraction (a polygon's cut cells have theirs exact: :func:`~.cut_cells.cut_cells`)
CUT_SUBSAMPLES = 16


class _Stopwatch:
    """Seconds per stage, each lap charged to the stage it names."""

    def __init__(self):
        self.seconds = {}
        self._t = time.perf_counter()

    def __call__(self, stage: str) -> None:
        now = time.perf_counter()
        self.seconds[stage] = self.seconds.get(stage, 0.0) + now - self._t
        self._t = now


class _Scratch(threading.local):
    """A series' work arrays, kept from batch to batch: ``scratch(name,
    shape)`` the array of that name, new only when its shape changes.  A
    batch's intermediates (the columns, the node fits, the densities and
    potentials, the spline's columns, about 17 MB at 13k points and 4
    fields) are then written to memory the process already holds: fresh
    arrays each batch cost their pages' first touches (an allocation of
    more than a few hundred kB is new pages from the system; the assembly
    kernel took 1.6x as long writing to new arrays as to kept ones).  One
    set per thread: a setup shared by threads keeps their batches apart."""

    def __init__(self):
        self.arrays = {}

    def __reduce__(self):
        # a pickled setup (a Decomposer sent to another process) takes none
        return _Scratch, ()

    def __call__(self, name: str, shape: tuple, dtype=np.float64, host: bool = False):
        a = self.arrays.get(name)
        if a is None or a.shape != tuple(shape) or a.dtype != dtype:
            a = self.arrays[name] = np.empty(shape, dtype=dtype)
        return a


def _new(name: str, shape: tuple, dtype=np.float64, host: bool = True) -> np.ndarray:
    """New work arrays in numpy."""
    return np.empty(shape, dtype=dtype)


def _work(name: str, shape: tuple, dtype=np.float64, host: bool = False):
    """New work arrays of a single split (nothing to keep them for): those
    that only kernels read (not ``host``) on the device where
    :func:`taichi_hh.runtime.resident` (:func:`taichi_hh.runtime.work`).  A
    1M-point window passed 1 GB of numpy arguments to its kernels, each copied
    to a GPU and back at every launch (docs/arch.md)."""
    return np.empty(shape, dtype=dtype) if host else runtime.work(shape, dtype)


def _check_evaluation(evaluation: str) -> None:
    if evaluation not in NATURAL_EVALUATIONS:
        raise ValueError(f"natural evaluation must be one of {NATURAL_EVALUATIONS}, "
                         f"got {evaluation!r}")


class _Cells:
    """The grid of a natural decomposition and its cells' coverage of the
    domain: ``frac`` (nx * ny,) inside fractions, ``inside`` (nx, ny) the
    centres inside, ``live`` the cells with a part inside (flat indices);
    ``cut`` the cells a polygon's boundary cuts
    (:func:`~.cut_cells.cut_cells`; None for a rectangle, whose sides are
    grid lines): their fractions exact, ``patches`` their parts' moments up
    to MULTIPOLE_ORDER as charges on the nodes around them
    (:func:`~.cut_cells.multipole_patches`)."""

    def __init__(self, domain, cell: float):
        self.grid = grid = Grid(domain, cell)
        rectangle = axis_rectangle(domain) is not None
        # a polygon's cut cells take their exact fractions below, and a cell
        # the boundary does not cut is whole or empty, as its centre says: the
        # subsamples would be spent for nothing (0.7 s at 1M points; the
        # fractions were equal bit for bit on five polygons)
        frac, self.inside = grid.coverage(domain, CUT_SUBSAMPLES if rectangle else 1,
                                          inside=True)
        self.frac = frac.ravel()
        self.cut = None if rectangle else cut_cells(grid, domain)
        self.patches = None
        if self.cut is not None:
            # the cut parts' moments are matched against cells' uniform
            # charges; without cut cells (the sides on grid lines) the kernel
            # stays G at the centre beyond EXACT_CELLS, as it always was there
            grid.cell_average = True
            self.frac[self.cut.cells] = self.cut.area / (grid.hx * grid.hy)
            self.patches = multipole_patches(grid, part_moments(grid, self.cut,
                                                                MULTIPOLE_ORDER))
        self.live = np.flatnonzero(self.frac > 0)


def _grid_potentials(cells: _Cells, at_cells: np.ndarray, evaluation: str,
                     lap, grids=None, scratch=_new) -> np.ndarray:
    """(m, nx, ny) the free-space potentials of the densities ``at_cells``
    (len(live), m) at the live cells' centres: each cell's charge its value
    times its inside area at its centre, a cut cell's part's moments up to
    MULTIPOLE_ORDER as charges on the nodes around it
    (:func:`~.cut_cells.multipole_density`), summed against G by
    ``evaluation``; next to the cut cells, their charges' exact potentials
    (:func:`~.cut_cells.near_field_correction`).  ``grids``: ``(values,
    charges)`` on the whole grid, (m, nx * ny) each, made already (then
    ``at_cells`` is not read; :func:`.natural_assemble.node_densities`);
    ``scratch``: where the potentials' array comes from (:class:`_Scratch`)."""
    grid, live = cells.grid, cells.live
    if grids is not None:
        values, dens = grids
        m = len(dens)
    else:
        m = at_cells.shape[1]
        dens = np.zeros((m, grid.nx * grid.ny))
        charge = at_cells * np.take(cells.frac, live)[:, None]
        for c in range(m):              # a row at a time: 4x a transposed scatter
            dens[c, live] = charge[:, c]
        values = None
        if cells.cut is not None:
            values = np.zeros((m, grid.nx * grid.ny))
            for c in range(m):
                values[c, live] = at_cells[:, c]
    if cells.cut is not None:
        dens += multipole_density(grid, cells.cut, cells.patches, values)
    dens = dens.reshape((m,) + grid.shape)
    lap("density")
    if evaluation == "fft":
        u = convolve_fft(grid, dens, out=scratch("potentials", dens.shape, host=True))
    else:
        u = np.stack([convolve_direct(grid, d) for d in dens])
    if cells.cut is not None:
        u += near_field_correction(grid, cells.cut, cells.patches, values).reshape(u.shape)
    lap("convolve")
    return u


def _near_points(cells: _Cells, binned: "PointBins", domain) -> np.ndarray:
    """The points (sorted order) within ONE_SIDED_CELLS of the boundary."""
    grid = cells.grid
    cell = math.hypot(grid.hx, grid.hy) / math.sqrt(2.0)
    return _near_boundary(domain, binned.points, ONE_SIDED_CELLS * cell)


def _at_points(cells: _Cells, u: np.ndarray, binned: "PointBins", near, lap,
               one_sided=None, apart: bool = False, scratch=_new):
    """(N, m, 3) each potential of ``u`` (m, nx, ny) and its gradient at the
    points (input order): the cubic spline of the potentials (continued
    linearly beyond the grid) and of their fourth-order grid gradients (the
    differences of the potentials' spline coefficients), the gradient at the points ``near`` the
    boundary (:func:`_near_points`) from the one-sided fit
    (:func:`one_sided_gradient`; ``one_sided``: those fits kept as weights,
    :func:`~.grid_sampling.one_sided_weights`).  ``apart``: ``(the spline's
    (N, m, 3), the fits (len(near), m, 2), the near points fitted)``, the
    fits not yet written over the spline's gradients.  ``scratch``: where
    the work arrays come from (:class:`_Scratch`)."""
    grid = cells.grid
    m = len(u)
    # every potential and its grid gradient, one spline through them all.  The
    # prefilter and the differences commute (both convolutions along the
    # grid's lines), so the potentials alone are filtered (a third of the
    # columns; 0.35 ms of a 13k snapshot) and the gradients' coefficients are
    # the coefficients' differences.  Near the grid's edges they commute if
    # the continuation beyond it keeps the slope: the edge value repeated
    # gave d 3e-4 off next to the corners, where no one-sided fit replaces
    # the spline's gradient; continued linearly, the windows' errors are the
    # same to 4 digits and phi within 2 cells of the edges is 3-30x closer to
    # a Gaussian source's closed form (docs/notes/series.md)
    padded = (grid.nx + 2 * SPLINE_PAD, grid.ny + 2 * SPLINE_PAD)
    c = edge_padded(grid, u, SPLINE_PAD, out=scratch("spline_values", padded + (m,)))
    prefilter(c, linear=True)
    coef = with_differences(grid, c, out=scratch("spline", padded + (m, 3))).reshape(
        padded + (3 * m,))
    sp = binned.points
    _, points, order = binned.kernel_arrays()
    at = spline_values(grid, coef, points, dest=order,       # in the input order
                       out=scratch("at_points", (len(sp), 3 * m)))
    lap("interpolate")
    # the gradient within ONE_SIDED_CELLS of the boundary from the fit
    if one_sided is None:
        fitted = one_sided_gradient(grid, np.moveaxis(u, 0, -1), cells.inside, sp[near])
        ok = np.isfinite(fitted).all(axis=(1, 2))
    else:
        weights, ok = one_sided
        fitted = weights.gradients(u.reshape(m, -1).T, out=scratch(
            "one_sided", (weights.n_targets, m, 2), host=True))
    at = at.reshape(len(sp), m, 3)
    if apart:
        lap("boundary_fit")
        return at, fitted, ok
    rows = binned.order[near[ok]]
    at[rows, :, 1:] = fitted[ok]
    lap("boundary_fit")
    return at


def natural_potentials(points, domain, sources: dict, spacing: float, *,
                       evaluation: str = "fft", cell_ratio: float = 1.0) -> dict:
    """Free-space potentials of ``sources`` (name -> values at ``points``, e.g.
    ``{"phi": div v, "psi": -curl v}``) over ``domain``: name -> ``(potential
    at the points, its gradient at the points)``.  ``evaluation``: ``fft`` or
    ``direct`` (module doc); ``cell_ratio``: grid cell size / data spacing.

    The points are sorted by grid cell once (the reconstruction's bins; the
    interpolation and the boundary fit then read the grid in order) and every
    potential goes through each stage at once: one FFT pass, one spline of
    all the potentials and their grid gradients, one boundary fit."""
    _check_evaluation(evaluation)
    lap = _Stopwatch()
    cells = _Cells(domain, cell_ratio * spacing)
    grid = cells.grid
    lap("coverage")
    names = list(sources)
    vals = np.stack([np.asarray(sources[k], dtype=np.float64) for k in names], axis=1)
    binned = PointBins(grid, points)
    lap("bins")
    at_cells = reconstruct_on_grid(grid, points, vals, cells.live, binned=binned)
    lap("reconstruct")
    u = _grid_potentials(cells, at_cells, evaluation, lap)
    at = _at_points(cells, u, binned, _near_points(cells, binned, domain), lap)
    out = {name: (at[:, m, 0].copy(), at[:, m, 1:].copy()) for m, name in enumerate(names)}
    lap("gather")
    out["grid"] = grid
    out["seconds"] = lap.seconds
    return out


#: the harmonic check fits h at about this many nodes at most (a regular
#: subgrid of the nodes inside: its means estimate the full grid's to a
#: fraction of a percent)
CHECK_NODES = 65536


class NaturalSplit:
    """The natural decomposition of a field at scattered points
    (:func:`natural_decomposition`), in the points' input order: ``phi``,
    ``psi`` (N,), ``d`` = grad phi, ``grad_psi``, ``div_free`` = J grad psi,
    ``harmonic`` = v - d - r (N, 2); ``divergence``, ``curl`` (N,) div v and
    curl v at the points; ``volume`` (N,) each point's share of the domain's
    area; ``energies``: the volume-weighted sums of |v|^2, |d|^2, |r|^2 and
    |h|^2 (the energy check's); ``grid``; ``mean_fit_points``: the mean
    number of data points in a node's fit; ``seconds`` by stage."""

    def __init__(self, **kw):
        self.__dict__.update(kw)

    @property
    def grad_psi(self) -> np.ndarray:
        """grad psi = -J r (J of :mod:`.rotation`: r = J grad psi), exactly."""
        return -J(self.div_free)

    def harmonic_ratios(self) -> tuple:
        """``(div, curl)``: mean |div h| and mean |curl h| of ``harmonic``
        (h = v - d - r) over the mean of sqrt(div v^2 + curl v^2), the same
        fit (of h, at the same nodes) as div v's: the nodes with centres
        inside the domain, every k-th along each axis for at most about
        :data:`CHECK_NODES` of them (made with the split: a batch's fields
        in one gather, :meth:`NaturalSetup.split_many`)."""
        scale = self._check_scale
        return tuple(x / scale if scale > 0 else (0.0 if x == 0 else math.inf)
                     for x in self._harmonic_means)


#: the node fits kept as weights (:class:`~.node_fits.FitWeights`) for a
#: series on the same points take about 24 bytes per point in a fit (about 45
#: per node): above this many bytes the fits are made again per field
FIT_WEIGHTS_BYTES = 1 << 30


class NaturalSetup:
    """What :func:`natural_decomposition` needs of the points alone: the grid
    and its cells' coverage (``cells``), the points binned by cell
    (``binned``), the fits' local spacing and boundary flags, the points
    within ONE_SIDED_CELLS of the boundary (``near``), the harmonic check's
    nodes, the points' areas (``volume``).  Built once for points that carry
    many fields (:class:`~taichi_hh.hhd.decomposer.Decomposer`); with
    ``reuse_fits`` (and the weights under :data:`FIT_WEIGHTS_BYTES`) the three
    sets of fits (the nodes, the near points, the check nodes) are kept as
    weights (:class:`~.node_fits.FitWeights`), each field's gradients then
    one gather, equal to the fits to rounding, and a batch's work arrays
    kept for the next (:class:`_Scratch`)."""

    def __init__(self, points, domain, spacing: float, *, evaluation: str = "fft",
                 cell_ratio: float = 1.0, reuse_fits: bool = False):
        _check_evaluation(evaluation)
        lap = _Stopwatch()
        self.evaluation = evaluation
        self.cells = cells = _Cells(domain, cell_ratio * spacing)
        grid, live = cells.grid, cells.live
        lap("coverage")
        self.binned = binned = PointBins(grid, points)
        lap("bins")
        self.nodes = grid.centres(live)
        self.scale, self.edge, self.volume = spacing_edge_volume(grid, cells.frac, binned)
        self.near = _near_points(cells, binned, domain)
        # the near points' cells: the bins holding their sorted positions
        self.near_cell = np.searchsorted(binned.start, self.near, side="right") - 1
        check = cells.inside.ravel()[live]
        if not check.any():
            check = np.ones(len(live), dtype=bool)
        # at most about CHECK_NODES of them: every k-th node along each axis
        k = max(1, math.ceil(math.sqrt(check.sum() / CHECK_NODES)))
        if k > 1:
            every = np.zeros(grid.shape, dtype=bool)
            every[::k, ::k] = True
            check &= np.take(every.ravel(), live)
        self.check = check
        self.check_rows = np.flatnonzero(check)
        lap("setup")
        self.fits = self.one_sided = None
        # a series' work arrays kept from batch to batch
        self.scratch = _Scratch() if reuse_fits else _work
        if reuse_fits and 24 * 45 * (len(live) + len(self.near)) <= FIT_WEIGHTS_BYTES:
            self.fits = {}
            for name in ("nodes", "near"):
                targets, scale, edge = self._targets(name)
                self.fits[name] = FitWeights(grid, binned, targets, scale=scale, edge=edge)
            # the check nodes are nodes: their fits are rows of the nodes'
            self.fits["check"] = self.fits["nodes"].rows(self.check_rows)
            self.one_sided = one_sided_weights(grid, cells.inside, binned.points[self.near])
            lap("fit_weights")
        self.seconds = lap.seconds

    def _targets(self, which: str) -> tuple:
        """``(targets, scale, edge)`` of the fits ``which`` (nodes, near, check)."""
        live = self.cells.live
        if which == "nodes":
            return self.nodes, self.scale[live], self.edge[live]
        if which == "near":
            return self.binned.points[self.near], self.scale[self.near_cell], \
                self.edge[self.near_cell]
        return self.nodes[self.check], self.scale[live][self.check], \
            self.edge[live][self.check]

    def gradients(self, which: str, values, counts: bool = False):
        """(T, m, 2) the gradients of the columns of ``values`` (N, m, in the
        bins' order) at the targets ``which`` (:meth:`_targets`); with
        ``counts`` also the points in each fit."""
        if self.fits is not None:
            w = self.fits[which]
            g = w.gradients(values, out=self.scratch(f"fits_{which}",
                                                     (w.n_targets, np.shape(values)[1], 2)))
            return (g, w.counts) if counts else g
        targets, scale, edge = self._targets(which)
        new = runtime.work if self.scratch is _work else None
        g, count = fit_gradients(self.cells.grid, self.binned, values, targets, counts=True,
                                 scale=scale, edge=edge, new=new)
        return (g, count) if counts else g

    def harmonic_terms(self, hs) -> np.ndarray:
        """(T, k, 2) |div h| and |curl h| at the harmonic check's nodes of
        the k fields ``hs`` (N, 2 k, in the bins' order), from the fits of
        h (:func:`~.node_fits.abs_div_curl`; with the fits kept as weights,
        in their gather)."""
        if self.fits is not None:
            w = self.fits["check"]
            return w.gradients(hs, div_curl=True, out=self.scratch(
                "check_terms", (w.n_targets, np.shape(hs)[1] // 2, 2)))
        return abs_div_curl(runtime.to_host(self.gradients("check", hs)))

    def split(self, vectors) -> "NaturalSplit":
        """The natural HHD of ``vectors`` (N, 2) at these points
        (:func:`natural_decomposition`): :meth:`split_many` of one."""
        return self.split_many([vectors])[0]

    def split_many(self, snapshots) -> list:
        """The natural HHDs of the fields ``snapshots`` (a sequence of (N, 2)
        arrays, or a (k, N, 2) array) at these points, one :class:`NaturalSplit` each: every stage
        takes the snapshots' columns together (one gather of the node fits
        for all, one FFT pass, one spline prefilter, one one-sided fit
        pass), so a batch pays each kernel launch once."""
        lap = _Stopwatch()
        cells, binned = self.cells, self.binned
        grid, live = cells.grid, cells.live
        k = len(snapshots)
        scratch = self.scratch
        # the snapshots' components side by side in the bins' order: columns
        # 2 s, 2 s + 1 (a kernel: numpy's takes and strided copies took 0.3 ms
        # of a 13k-point snapshot)
        kept = getattr(self, "_rows", None)    # made by the first split
        if kept is None:
            n = len(binned.order)
            pos = np.empty(n, dtype=np.int32)           # each point's place in the bins
            pos[binned.order] = np.arange(n, dtype=np.int32)
            near_of = row_index(n, binned.order[self.near])
            fit_of = None if self.one_sided is None else row_index(
                n, binned.order[self.near[self.one_sided[1]]],
                np.flatnonzero(self.one_sided[1]))
            kept = (row_index(grid.nx * grid.ny, live), pos, near_of, fit_of)
            if scratch is _work:    # read by kernels alone: on the device (runtime.resident)
                kept = tuple(None if a is None else runtime.to_device(a, np.int32)
                             for a in kept)
            self._rows = kept
        live_of, pos, near_of, fit_of = kept
        vs = columns(snapshots, pos, out=scratch("columns", (len(pos), 2 * k)))
        g, count = self.gradients("nodes", vs, counts=True)            # (live, 2k, 2)
        lap("fit")
        # div v and curl v at the nodes, their charges on the grid, their grid
        # for the interpolation to the points, the harmonic check's scale
        nodes = node_densities(g, live_of, cells.frac, self.check_rows,
                               with_values=cells.cut is not None, scratch=scratch)
        u = _grid_potentials(cells, None, self.evaluation, lap,
                             grids=(nodes["values"], nodes["dens"]), scratch=scratch)
        at, fitted, ok = _at_points(cells, u, binned, self.near, lap, self.one_sided,
                                    apart=True, scratch=scratch)      # (N, 2k, 3)
        # div v and curl v at the points: the nodes' values inside, the fit at
        # the point near the boundary (the nodes around it partly outside)
        # (every field's two columns in one interpolation)
        _, points, order = binned.kernel_arrays()
        lag = lagrange_at(grid, nodes["dc"].reshape(grid.shape + (2 * k,)), points, order,
                          out=scratch("lagrange", (len(binned.points), 2 * k)))
        gn = self.gradients("near", vs) if self.near.size else np.zeros((0, 2 * k, 2))
        lap("divergence")
        # every output of every field in one pass (natural_assemble): phi,
        # psi, d, grad psi, r, h (and h in the bins' order for the check's
        # fits), div v, curl v and the energy check's rows
        if fit_of is None:                 # the one-sided fits made per call
            fit_of = row_index(len(pos), binned.order[self.near[ok]], np.flatnonzero(ok))
        out = assemble(at, vs, pos, fit_of, fitted, near_of, gn, lag, self.volume,
                       scratch=scratch)
        pot, grads, comps, dc = out["pot"], out["grads"], out["comps"], out["dc"]
        energies = out["energies"]                                       # (4, k)
        check_scale = nodes["check_scale"]                              # (k,)
        mean_fit_points = float(runtime.to_host(count).mean()) if count.size else 0.0
        lap("gather")
        # the harmonic check's fits of h at the check nodes, every field in one gather
        terms = self.harmonic_terms(out["hs"])                   # (check nodes, k, 2)
        means = terms.sum(axis=0) / max(len(terms), 1)
        div_h, curl_h = means[:, 0], means[:, 1]                        # (k,)
        splits = [NaturalSplit(phi=pot[s, 0], d=grads[s], psi=pot[s, 1], div_free=comps[s, 0],
                               divergence=dc[s, 0], curl=dc[s, 1], harmonic=comps[s, 1],
                               volume=self.volume, grid=grid, mean_fit_points=mean_fit_points,
                               energies=tuple(float(e) for e in energies[:, s]),
                               _check_scale=float(check_scale[s]),
                               _harmonic_means=(float(div_h[s]), float(curl_h[s])))
                  for s in range(k)]
        lap("harmonic")
        for split in splits:
            split.seconds = {name: t / k for name, t in lap.seconds.items()}
        return splits


def natural_decomposition(points, vectors, domain, spacing: float, *,
                          evaluation: str = "fft", cell_ratio: float = 1.0) -> NaturalSplit:
    """The natural HHD of ``vectors`` (N, 2) at ``points`` over ``domain``
    (module doc) with div v and curl v taken at the grid nodes: the cubic
    moving-least-squares fit of v at each live cell's centre
    (:func:`fit_gradients`) gives its gradient there, so the densities
    need no operator at the points (and no neighbour search); the rest as
    :func:`natural_potentials`.  div v and curl v at the points (the
    result's, and the harmonic check's scale): the nodes' values by
    tensor cubic Lagrange interpolation, and within ONE_SIDED_CELLS of the
    boundary the fit of v at the point itself.  Returns a
    :class:`NaturalSplit` (:class:`NaturalSetup` then its split)."""
    setup = NaturalSetup(points, domain, spacing, evaluation=evaluation, cell_ratio=cell_ratio)
    split = setup.split(vectors)
    split.seconds = {**setup.seconds, **split.seconds}
    return split


def _near_boundary(domain, points, width: float) -> np.ndarray:
    """Indices of ``points`` whose signed distance exceeds ``-width`` (within
    ``width`` of the boundary, or outside): a rectangle in closed form
    (:meth:`Box.within <taichi_hh.geometry.box.Box.within>`), other polygons
    through the locator (exact distances only near the boundary)."""
    rect = axis_rectangle(domain)
    if rect is not None:
        return np.flatnonzero(~Box(*rect).within(points, -width))
    return np.flatnonzero(domain.classify_discs(points, 0.0, -np.inf, -width) != 1)
