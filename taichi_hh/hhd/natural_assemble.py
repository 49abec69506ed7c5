"""The glue of a batch of natural splits (:meth:`.natural.NaturalSetup.split_many`)
in two kernels: what the node fits' gradients give (:func:`node_densities`)
and every field's outputs from the interpolated columns (:func:`assemble`).

Each node's div v and curl v, the charges they make on the whole grid (and
the values a polygon's cut cells read), their grid for the Lagrange
interpolant and the harmonic check's scale terms: one pass over the grid.
Each point's potentials and gradients (the spline, or the one-sided fit near
the boundary), div v and curl v (the Lagrange interpolant, or the fit of v
at the point near the boundary), r = J grad psi, h = v - d - r, h again in
the bins' order (what the harmonic check's fits read) and the squared norms
of v, d, r and h (the energy check's rows): the same arithmetic numpy did
on the batch's arrays, one copy of each output instead of a dozen strided
copies, transposes and fancy-indexed assignments (about 2 ms of a 13k-point
snapshot's glue; docs/notes/series.md).
"""
import numpy as np
import taichi as ti

from .. import runtime

# stand-ins for the arrays a call has no rows of (Taichi takes no empty ndarray)
_NONE_ROWS = np.zeros((1, 2, 2))
_NO_VALUES = np.zeros((1, 1))


@ti.kernel
def _assemble(at: ti.types.ndarray(), vs: ti.types.ndarray(), pos: ti.types.ndarray(),
              fit_of: ti.types.ndarray(), fitted: ti.types.ndarray(),
              near_of: ti.types.ndarray(), near_grad: ti.types.ndarray(),
              lag: ti.types.ndarray(), pot: ti.types.ndarray(), grads: ti.types.ndarray(),
              comps: ti.types.ndarray(), dc: ti.types.ndarray(), hs: ti.types.ndarray(),
              vol: ti.types.ndarray(), sq: ti.types.ndarray(), k: ti.template()):
    """For each point (input row i, bins' position p = pos[i]) and field s:
    pot[s, 0|1, i] phi, psi; grads[s, i, :] d; comps[s, 0|1, i, :]
    r = J grad psi, h = v - d - r; dc[s, 0|1, i] div v, curl v;
    hs[p, 2 s:2 s + 2] h; sq[0..3, s, i] |v|^2, |d|^2, |r|^2, |h|^2 times
    the point's area vol[i] (the energy check's terms).  ``at``
    (N, 2k, 3): each potential's value and gradient; ``fit_of[i]`` the row
    of ``fitted`` (n, 2k, 2) that replaces the gradients, or -1;
    ``near_of[i]`` the row of ``near_grad`` (n, 2k, 2) (the gradients of v's
    components) that gives div v and curl v, or -1, else ``lag`` (N, 2k);
    ``vs`` (N, 2k) the fields in the bins' order (the node fits' columns).
    Every array flat, indexed with the ``k`` fields' strides known at
    compile time (the same arithmetic in 0.55x the time of 2-d to 4-d
    ndarrays, whose strides are runtime values)."""
    n = pos.shape[0]
    m = 2 * k
    # by input rows: all but hs written in order (by the bins' order, a grid's
    # rows came 3-4x slower: each write another cache line)
    for i in range(n):
        p = pos[i]
        f = fit_of[i]
        q = near_of[i]
        w = vol[i]
        for s in ti.static(range(k)):
            a, b = 2 * s, 2 * s + 1
            ai = (i * m + a) * 3
            bi = (i * m + b) * 3
            pot[(2 * s) * n + i] = at[ai]
            pot[(2 * s + 1) * n + i] = at[bi]
            dx, dy = at[ai + 1], at[ai + 2]
            gx, gy = at[bi + 1], at[bi + 2]
            if f >= 0:
                fa = (f * m + a) * 2
                fb = (f * m + b) * 2
                dx, dy = fitted[fa], fitted[fa + 1]
                gx, gy = fitted[fb], fitted[fb + 1]
            g0 = ((2 * s) * n + i) * 2
            g1 = ((2 * s + 1) * n + i) * 2
            # grad psi is not kept: -J r (NaturalSplit.grad_psi)
            grads[(s * n + i) * 2] = dx
            grads[(s * n + i) * 2 + 1] = dy
            # r = J grad psi = (d psi/dy, -d psi/dx) (rotation.J)
            rx, ry = gy, -gx
            comps[g0] = rx
            comps[g0 + 1] = ry
            vx, vy = vs[p * m + a], vs[p * m + b]
            hx = (vx - dx) - rx
            hy = (vy - dy) - ry
            comps[g1] = hx
            comps[g1 + 1] = hy
            hs[p * m + a] = hx
            hs[p * m + b] = hy
            if q >= 0:
                qa = (q * m + a) * 2
                qb = (q * m + b) * 2
                dc[(2 * s) * n + i] = near_grad[qa] + near_grad[qb + 1]
                dc[(2 * s + 1) * n + i] = near_grad[qb] - near_grad[qa + 1]
            else:
                dc[(2 * s) * n + i] = lag[i * m + a]
                dc[(2 * s + 1) * n + i] = lag[i * m + b]
            sq[(0 * k + s) * n + i] = w * (vx * vx + vy * vy)
            sq[(1 * k + s) * n + i] = w * (dx * dx + dy * dy)
            sq[(2 * k + s) * n + i] = w * (rx * rx + ry * ry)
            sq[(3 * k + s) * n + i] = w * (hx * hx + hy * hy)


@ti.kernel
def _columns(fields: ti.types.ndarray(), pos: ti.types.ndarray(), out: ti.types.ndarray(),
             k: ti.template()):
    """out[pos[i], 2 s + c] = fields[s, i, c]: the k fields (k, N, 2, flat)
    side by side in the bins' order (N, 2 k, flat), one pass: the fields
    read in order, each point's row written whole (by the bins' order
    instead, the reads missed the caches: 2.6 ms for 8 fields of 13k)."""
    n = pos.shape[0]
    for i in range(n):
        p = pos[i]
        for s in ti.static(range(k)):
            out[p * 2 * k + 2 * s] = fields[(s * n + i) * 2]
            out[p * 2 * k + 2 * s + 1] = fields[(s * n + i) * 2 + 1]


def columns(fields, pos, out=None) -> np.ndarray:
    """(N, 2 k) the fields (k, N, 2) side by side, field s's components in
    columns 2 s and 2 s + 1, point i's in row ``pos[i]`` (its place in the
    bins); ``out``: the array to write (a series' batches reuse one; a
    :class:`~taichi_hh.runtime.Device` one stays on the device)."""
    runtime.ensure_init()
    f = np.ascontiguousarray(fields, dtype=np.float64)
    k, n = f.shape[0], f.shape[1]
    if not runtime.writable(out, (n, 2 * k)):
        out = np.empty((n, 2 * k))
    if n and k:
        _columns(f.reshape(-1), runtime.flat(pos, np.int32), runtime.flat(out), k)
    return out


@ti.kernel
def _node_densities(g: ti.types.ndarray(), m: ti.i32, live_of: ti.types.ndarray(),
                    frac: ti.types.ndarray(), check_rows: ti.types.ndarray(),
                    values: ti.types.ndarray(), dens: ti.types.ndarray(),
                    dcg: ti.types.ndarray(), chk: ti.types.ndarray(),
                    with_values: ti.template()):
    """For each cell c (``live_of[c]`` its row of ``g``, the node fits'
    (L, m, 2) gradients of the fields' components, or -1) and field s (k =
    m / 2 of them): values[2 s|2 s + 1, c] div v, -curl v (0 off the live
    cells; only ``with_values``), dens[...] those times the cell's inside
    fraction, dcg[c, 2 s|2 s + 1] div v, curl v; for each check node j:
    chk[s, j] sqrt(div v^2 + curl v^2).  Every array flat."""
    k = m // 2
    cells = live_of.shape[0]
    for c in range(cells):
        r = live_of[c]
        w = frac[c]
        for s in range(k):
            a, b = 2 * s, 2 * s + 1
            dv = ti.cast(0.0, ti.f64)
            cu = ti.cast(0.0, ti.f64)
            if r >= 0:
                dv = g[(r * m + a) * 2] + g[(r * m + b) * 2 + 1]
                cu = g[(r * m + b) * 2] - g[(r * m + a) * 2 + 1]
            if ti.static(with_values):
                values[a * cells + c] = dv
                values[b * cells + c] = -cu
            dens[a * cells + c] = dv * w
            dens[b * cells + c] = -cu * w
            dcg[c * m + a] = dv
            dcg[c * m + b] = cu
    n_check = check_rows.shape[0]
    for j in range(n_check):
        r = check_rows[j]
        for s in range(k):
            a, b = 2 * s, 2 * s + 1
            dv = g[(r * m + a) * 2] + g[(r * m + b) * 2 + 1]
            cu = g[(r * m + b) * 2] - g[(r * m + a) * 2 + 1]
            chk[s * n_check + j] = ti.sqrt(dv * dv + cu * cu)


def node_densities(g, live_of, frac, check_rows, with_values: bool = True,
                   scratch=None) -> dict:
    """:func:`_node_densities` of the node fits' gradients ``g`` (L, 2k, 2):
    a dict of ``values`` (None without ``with_values``: only a polygon's cut
    cells read them), ``dens`` (2k, cells), ``dc`` (cells, 2k) and
    ``check_scale`` (k,), the mean of sqrt(div v^2 + curl v^2) over the
    nodes ``check_rows``.  ``scratch``: where the arrays come from
    (``scratch(name, shape)``, a series' kept buffers or
    :class:`~taichi_hh.runtime.Device` ones; None: new numpy arrays);
    ``values`` and ``dens`` come back in numpy (the host's FFT reads them),
    ``dc`` as made (the interpolation's kernel reads it)."""
    runtime.ensure_init()
    new = scratch or (lambda name, shape: np.empty(shape))
    m, cells = g.shape[1], len(live_of)
    out = {"values": new("values", (m, cells)) if with_values else None,
           "dens": new("dens", (m, cells)), "dc": new("dc", (cells, m))}
    chk = new("check", (m // 2, len(check_rows)))
    if cells and m:
        _node_densities(runtime.flat(g), m, runtime.flat(live_of, np.int32),
                        runtime.flat(frac),
                        runtime.flat(check_rows, np.int32) if len(check_rows)
                        else np.zeros(0, dtype=np.int32),
                        runtime.flat(out["values"]) if with_values else _NO_VALUES.reshape(-1),
                        runtime.flat(out["dens"]), runtime.flat(out["dc"]), runtime.flat(chk),
                        bool(with_values))
    if with_values:
        out["values"] = runtime.to_host(out["values"])
    out["dens"] = runtime.to_host(out["dens"])
    out["check_scale"] = runtime.to_host(chk).sum(axis=-1) / max(len(check_rows), 1)
    return out



def row_index(n: int, rows, values=None) -> np.ndarray:
    """(n,) int32: ``values`` (default 0, 1, ...) at ``rows``, -1 elsewhere
    (:func:`assemble`'s ``fit_of`` and ``near_of``)."""
    out = np.full(n, -1, dtype=np.int32)
    out[rows] = np.arange(len(rows)) if values is None else values
    return out


def assemble(at, vs, pos, fit_of, fitted, near_of, near_grad, lag, vol, scratch=None) -> dict:
    """The batch's outputs (:func:`_assemble`) from ``at`` (N, 2k, 3), the
    fields ``vs`` (N, 2k: field s's components in columns 2 s, 2 s + 1) in the
    bins' order, ``pos`` (N,) each point's position in the bins' order (the
    inverse of their ``order``), the one-sided
    fits ``fitted`` (rows ``fit_of``), the fits of v near the boundary
    ``near_grad`` (rows ``near_of``) and the Lagrange interpolant ``lag``
    (N, 2k) of div v and curl v, the points' areas ``vol`` (N,): a dict of
    ``pot`` (k, 2, N) phi and psi, ``grads`` (k, N, 2) d,
    ``comps`` (k, 2, N, 2) r and h, ``dc`` (k, 2, N), ``hs`` (N, 2k) and
    ``energies`` (4, k): the volume-weighted sums of |v|^2, |d|^2, |r|^2,
    |h|^2 (each a sum over the rows in order, as numpy sums a 1-d array).
    Any input may be a :class:`~taichi_hh.runtime.Device` array.
    ``scratch``: where ``hs`` and the energy terms come from (as
    :func:`node_densities`; ``hs`` stays as made, for the harmonic check's
    fits); the outputs that results keep are new numpy arrays (made on the
    device and copied back where ``vs`` is there)."""
    runtime.ensure_init()
    k, n = vs.shape[1] // 2, vs.shape[0]
    new = scratch or (lambda name, shape: np.empty(shape))
    made = runtime.work if isinstance(vs, runtime.Device) else np.empty
    out = {"pot": made((k, 2, n)), "grads": made((k, n, 2)),
           "comps": made((k, 2, n, 2)), "dc": made((k, 2, n)),
           "hs": new("hs", (n, 2 * k))}
    sq = new("energy_terms", (4, k, n))
    if n and k:
        flat = runtime.flat
        _assemble(flat(at), flat(vs), flat(pos, np.int32), flat(fit_of, np.int32),
                  flat(fitted) if len(fitted) else _NONE_ROWS.reshape(-1),
                  flat(near_of, np.int32),
                  flat(near_grad) if len(near_grad) else _NONE_ROWS.reshape(-1), flat(lag),
                  flat(out["pot"]), flat(out["grads"]), flat(out["comps"]),
                  flat(out["dc"]), flat(out["hs"]), flat(vol), flat(sq), k)
    for name in ("pot", "grads", "comps", "dc"):
        out[name] = runtime.to_host(out[name])
    out["energies"] = runtime.to_host(sq).sum(axis=-1)
    return out
