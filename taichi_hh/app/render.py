"""Headless frames: particles drawn into an RGB image, PNG, movies.

No window, no GGUI (which needs Vulkan, absent on CPU machines) and no Taichi:
numpy draws the particles into a ``(H, W, 3)`` u8 image, as discs or as the
smooth interpolated colour field (``style``), and a minimal PNG encoder (no
filtering, zlib level 1) writes it: Pillow's adaptive row filters cost more
than the whole draw (docs/notes/app.md).  Nothing here starts Taichi (a
frame coloured by vorticity takes the flow's, computed on its own neighbour
pairs), so the scenes draw their frames in a worker process beside the time
loop (:mod:`taichi_hh.app.outputs`).

How a frame is drawn.  numpy turns positions into pixel coordinates (f32, y
up) and gives every particle its colour-table row: its phase's palette entry,
the wall grey, or the colormap entry of its scalar (speed, vorticity).  Then:

* discs: every pixel whose centre lies inside a particle's disc takes the
  maximum of ``key = closeness << 9 | colour`` over those discs: closeness is
  the quantised ``1 - d^2/r^2``, so where discs overlap the pixel shows the
  particle whose centre is nearest (a Voronoi-like split of the overlap),
  ties going to the larger colour row.  The picture therefore does not depend
  on the order of particles, which the neighbour grid changes every step.
  The colour row ``key & 511`` is looked up in the colour table (phase
  palette, wall grey, a 256-entry colormap), or the background where no disc
  covers the pixel.
* smooth: the Shepard-interpolated colour on a grid of samples twice per
  particle spacing, interpolated bilinearly to the pixels.

The image's y axis points up (row 0 is the top of the box).  The box keeps its
aspect ratio: with ``height=None`` the height follows from the width; with
both given, the box is centred and letterboxed.

Every file is written through a temporary name in the same directory and
renamed (:func:`taichi_hh.app.io.atomic_path`), so an interrupted run never leaves
a half-written frame or movie.
"""

import glob as _glob
import importlib.util
import math
import os
import struct
import sys
import zlib

import numpy as np

from .io import atomic_path

#: ``taichi_hh.sph.particles.FLUID``, the kind of fluid particles (not imported from
#: there: that imports Taichi, and this module runs in the Taichi-free output worker)
FLUID = 0

# colour table layout (rows of RGB u8)
_CMAP_ROWS = 256                    # rows 0..255: the scalar colormap
WALL_ROW = 256                      # boundary / ghost particles and phase < 0
_PHASE_BASE = 257                   # rows 257..: phase palette
_MAX_ROWS = 512                     # the key: 22 bits of closeness, 9 bits of colour row

PHASE_PALETTE = (
    (66, 146, 214),     # phase 0: light fluid, blue
    (232, 106, 36),     # phase 1: heavy fluid, orange-red
    (76, 175, 80),      # phase 2: green
    (156, 93, 186),     # phase 3: purple
    (240, 196, 40),     # phase 4: yellow
    (120, 85, 72),      # phase 5: brown
)
WALL_COLOUR = (150, 150, 150)

#: frame styles: particles as discs, or the smooth interpolated colour field
STYLES = ("discs", "smooth")
#: what frames can be coloured by (the scenes' ``--color``)
COLOURINGS = ("phase", "speed", "vorticity")
#: matplotlib colormap of each colouring: sequential for speed, diverging
#: (white at zero, red counter-clockwise, blue clockwise) for vorticity
COLORMAPS = {"phase": "viridis", "speed": "viridis", "vorticity": "RdBu_r"}
#: disc radius in particle spacings: well above sqrt(2)/2, so that the discs of a
#: lattice cover its cells' centres, and most gaps of a disordered set (overlaps
#: go to the nearest centre, so larger discs do not blur)
DISC_RADIUS = 0.9
#: radius of the smooth style's interpolation weight, in particle spacings
SMOOTH_RADIUS = 1.2
#: the smooth style samples its field about this many times per particle spacing
#: (and at least once per pixel), then interpolates bilinearly to the pixels
SMOOTH_SAMPLES_PER_SPACING = 2
#: the smooth style's colour fades into the background where the interpolation
#: weights sum to less than this fraction of their value inside the fluid
SMOOTH_EDGE = 0.2


def _draw_discs(px, rows, radius: float, table, image, background) -> None:
    """Splat discs into ``image`` (numpy, in place): every pixel whose centre
    lies within ``radius`` of a disc centre gets the key ``closeness << 9 |
    colour row`` of the closest one (the largest key: closeness is the
    quantised ``1 - d^2/r^2``, ties go to the larger colour row), then the
    colour of its row in ``table``; pixels no disc covers, ``background``.

    px: (n, 2) f32 disc centres in pixel units, y up; rows: (n,) i32 colour-table
    rows, < 0 for particles not drawn.  A maximum does not depend on the order
    of its terms, so neither does the picture."""
    height, width = image.shape[:2]
    keep = rows >= 0
    u, v, rows = px[keep, 0], px[keep, 1], rows[keep].astype(np.int64)
    key = np.full(height * width, -1, dtype=np.int64)
    r2 = np.float32(radius) * np.float32(radius)
    span = int(math.floor(2.0 * radius)) + 2         # columns (rows) a disc can touch
    c = np.floor(u - np.float32(radius)).astype(np.int64)[:, None] + np.arange(span)
    du = (c.astype(np.float32) + np.float32(0.5)) - u[:, None]
    du2 = du * du
    col_ok = (c >= 0) & (c < width)
    b0 = np.floor(v - np.float32(radius)).astype(np.int64)
    for db in range(span):                            # one pixel row of every disc at a time
        b = b0 + db
        dv = (b.astype(np.float32) + np.float32(0.5)) - v
        d2 = du2 + (dv * dv)[:, None]
        ok = col_ok & (d2 <= r2) & ((b >= 0) & (b < height))[:, None]
        if not ok.any():
            continue
        close = ((np.float32(1.0) - d2[ok] / r2) * np.float32(4194303.0)).astype(np.int64)
        pix = ((height - 1 - b)[:, None] * width + c)[ok]
        np.maximum.at(key, pix, (close << 9) | np.broadcast_to(rows[:, None], ok.shape)[ok])
    flat = image.reshape(-1, 3)
    flat[:] = background
    hit = key >= 0
    flat[hit] = table[key[hit] & 511]


def _draw_smooth_field(px, colour, radius: float, full: float, stride: int, image,
                       background) -> None:
    """Shepard-interpolated colour on the pixel grid (numpy, in place).

    px: (n, 2) f32 particle centres in pixel units (y up); colour: (n, 3) f32
    RGB.  Weight (1 - d^2/R^2)^2 within ``radius``; where the weights add up
    to less than ``full`` (a fraction of their sum inside a uniformly filled
    region) the colour fades into the background, so the fluid's free edges
    stay sharp.  The field is sampled every ``stride`` pixels, at pixel centres
    ``(k stride + 1/2)`` (each particle adds its weight to the samples within
    its radius), and interpolated bilinearly to the pixels in between: it
    varies over a particle spacing, several strides."""
    height, width = image.shape[:2]
    sw = (width - 1) // stride + 2
    sh = (height - 1) // stride + 2
    r2 = np.float32(radius) * np.float32(radius)
    # each particle's window of samples: the first at or after u - R, as many as 2R spans
    m = int(math.floor(2.0 * radius / stride)) + 1
    offsets = np.arange(m)
    u, v = px[:, 0], px[:, 1]
    sx = np.ceil((u - np.float32(0.5 + radius)) / stride).astype(np.int64)[:, None] + offsets
    sy = np.ceil((v - np.float32(0.5 + radius)) / stride).astype(np.int64)[:, None] + offsets
    du = (sx * stride).astype(np.float32) + np.float32(0.5) - u[:, None]
    dv = (sy * stride).astype(np.float32) + np.float32(0.5) - v[:, None]
    q = np.float32(1.0) - (du[:, None, :] ** 2 + dv[:, :, None] ** 2) / r2   # (n, dy, dx)
    ok = (q > 0) & ((sx >= 0) & (sx < sw))[:, None, :] & ((sy >= 0) & (sy < sh))[:, :, None]
    w = q * q
    index = (sy[:, :, None] * sw + sx[:, None, :])[ok]
    den = np.bincount(index, w[ok], minlength=sw * sh)
    acc = np.stack([np.bincount(index, (w * colour[:, ch, None, None])[ok], minlength=sw * sh)
                    for ch in range(3)], axis=1)
    bg = np.asarray(background, dtype=np.float64)
    alpha = np.minimum(den / full, 1.0)[:, None]
    rgb = np.where(den[:, None] > 0, alpha * acc / np.maximum(den, 1e-300)[:, None]
                   + (1.0 - alpha) * bg, bg)
    # + 1/2: the cast to u8 below truncates, i.e. rounds (the interpolation's
    # weights add up to 1, so the offset may come first, on the samples)
    rgb = np.clip(rgb + 0.5, 0.0, 255.5).astype(np.float32).reshape(sh, sw, 3)
    # bilinear interpolation, separable: along x to every pixel column, then
    # along y to every row; a pixel at offset d within its stride takes the
    # weights (1 - d / stride, d / stride) of its two samples (strided slices)
    along_x = np.empty((sh, (sw - 1) * stride, 3), dtype=np.float32)
    for d in range(stride):
        t = np.float32(d / stride)
        np.multiply(rgb[:, :-1], np.float32(1.0) - t, out=along_x[:, d::stride])
        along_x[:, d::stride] += t * rgb[:, 1:]
    along_x = along_x[:, :width]
    field = np.empty(((sh - 1) * stride, width, 3), dtype=np.float32)
    for d in range(stride):
        t = np.float32(d / stride)
        np.multiply(along_x[:-1], np.float32(1.0) - t, out=field[d::stride])
        field[d::stride] += t * along_x[1:]
    np.copyto(image, field[height - 1::-1], casting="unsafe")   # row 0 is the top: y flipped


def frame_colouring(color: str, velocities, *, vorticity=None):
    """What a frame coloured by ``color`` (one of :data:`COLOURINGS`) shows:
    ``(scalar per particle or None, vmin, vmax, colour bar name)``.

    ``"phase"``: no scalar (the phase palette).  ``"speed"``: ``|v|`` over
    ``[0, max]``.  ``"vorticity"``: ``vorticity`` (per particle: the flow's
    :meth:`~taichi_hh.flow.TwoPhaseFlow.vorticity`, on its own neighbour pairs)
    over symmetric limits ``[-a, a]``, ``a`` its largest magnitude, so zero
    sits at the diverging colormap's white centre.  Limits are per frame (a
    frame's colours compare within it; the colour bar gives the scale)."""
    if color == "phase":
        return None, 0.0, 1.0, ""
    vel = np.asarray(velocities, dtype=np.float64)
    if color == "speed":
        scalar = np.linalg.norm(vel, axis=1)
        return scalar, 0.0, float(scalar.max()) if scalar.size else 1.0, "speed"
    if color == "vorticity":
        if vorticity is None:
            raise ValueError("color 'vorticity' needs the particles' vorticity "
                             "(TwoPhaseFlow.vorticity)")
        scalar = np.asarray(vorticity, dtype=np.float64)
        finite = scalar[np.isfinite(scalar)]
        a = float(np.abs(finite).max()) if finite.size else 0.0
        a = a if a > 0 else 1.0
        return scalar, -a, a, "vorticity"
    raise ValueError(f"color must be one of {COLOURINGS}, got {color!r}")


def colormap_table(name: str = "viridis") -> np.ndarray:
    """A (256, 3) u8 table of a matplotlib colormap."""
    import matplotlib
    rgba = matplotlib.colormaps[name](np.linspace(0.0, 1.0, _CMAP_ROWS))
    return np.round(rgba[:, :3] * 255).astype(np.uint8)


def _as_numpy(a, n=None):
    if a is None:
        return None
    if hasattr(a, "to_numpy"):            # a Taichi ndarray or field
        a = a.to_numpy()
    a = np.asarray(a)
    return a if n is None else a[:n]


class FrameRenderer:
    """Draws 2D particles as filled discs into a u8 RGB image, headless.

    width, height: image size in pixels; ``height=None`` keeps the box's aspect
    ratio; when both are given the box is centred (letterboxed) with its aspect
    ratio kept.  box_lo, box_hi: the world rectangle shown (include the walls).
    radius_px: disc radius in pixels; ``None``: ``DISC_RADIUS`` times the mean
    particle spacing estimated as sqrt(box area / particles drawn), at least
    0.75 px.
    style: ``"discs"`` (each particle a disc, overlaps split by the nearest
    centre) or ``"smooth"`` (the Shepard-interpolated colour field on the
    pixel grid: phases blend over about a spacing at their interface, no
    gaps between particles).
    colormap: matplotlib colormap name for scalar colouring (uploaded once).
    palette: RGB colours of phases 0, 1, ... (fluid particles); walls
    (non-fluid kinds, or phase < 0) are ``wall_colour``.
    """

    def __init__(self, width: int, height=None, box_lo=(0.0, 0.0), box_hi=(1.0, 1.0),
                 radius_px=None, background=(255, 255, 255), *, colormap: str = "viridis",
                 palette=PHASE_PALETTE, wall_colour=WALL_COLOUR, style: str = "discs"):
        if style not in STYLES:
            raise ValueError(f"style must be one of {STYLES}, got {style!r}")
        self.style = style
        lo = np.asarray(box_lo, dtype=np.float64)
        hi = np.asarray(box_hi, dtype=np.float64)
        if lo.shape != (2,) or hi.shape != (2,) or not np.all(np.isfinite(lo)) \
                or not np.all(np.isfinite(hi)) or np.any(hi <= lo):
            raise ValueError(f"box must satisfy box_lo < box_hi (finite 2-vectors), got {box_lo}, {box_hi}")
        width = int(width)
        if width < 1:
            raise ValueError(f"width must be >= 1 pixel, got {width}")
        extent = hi - lo
        if height is None:
            height = max(1, int(round(width * extent[1] / extent[0])))
        height = int(height)
        if height < 1:
            raise ValueError(f"height must be >= 1 pixel, got {height}")
        self.width, self.height = width, height
        self.box_lo, self.box_hi = lo, hi
        self.scale = min(width / extent[0], height / extent[1])          # pixels per unit
        self.offset = ((width - extent[0] * self.scale) / 2, (height - extent[1] * self.scale) / 2)
        self.radius_px = None if radius_px is None else float(radius_px)
        bg = tuple(int(c) for c in background)
        if len(bg) != 3 or not all(0 <= c <= 255 for c in bg):
            raise ValueError(f"background must be an RGB triple of 0..255, got {background}")
        self.background = bg
        palette = [tuple(int(c) for c in col) for col in palette]
        if not 1 <= len(palette) <= _MAX_ROWS - _PHASE_BASE:
            raise ValueError(f"palette needs 1..{_MAX_ROWS - _PHASE_BASE} colours")
        table = np.zeros((_PHASE_BASE + len(palette), 3), dtype=np.uint8)
        table[:_CMAP_ROWS] = colormap_table(colormap)
        table[WALL_ROW] = wall_colour
        table[_PHASE_BASE:] = palette
        self.table_np = table
        self.n_phase = len(palette)
        self.image = np.zeros((height, width, 3), dtype=np.uint8)   # the last frame drawn

    def world_to_pixel(self, x, y):
        """(column, row) of the pixel containing world point (x, y); row 0 is the top."""
        u = (x - self.box_lo[0]) * self.scale + self.offset[0]
        v = (y - self.box_lo[1]) * self.scale + self.offset[1]
        return int(math.floor(u)), self.height - 1 - int(math.floor(v))

    def colour_of_phase(self, phase: int) -> tuple:
        if phase < 0:
            return tuple(int(c) for c in self.table_np[WALL_ROW])
        return tuple(int(c) for c in self.table_np[_PHASE_BASE + phase % self.n_phase])

    def draw(self, positions, phase=None, kind=None, scalar=None, *, n=None, vmin=None,
             vmax=None, radius_px=None, show_walls: bool = True) -> np.ndarray:
        """Draw one frame; returns it as a numpy (H, W, 3) u8 array (also in ``self.image``).

        positions: (n, 2) numpy array or Taichi ndarray (first ``n`` used).
        phase: (n,) ints, colour from the palette (default 0).  kind: (n,) ints
        (``particles.FLUID`` == 0; anything else is drawn as a wall).
        scalar: (n,) values coloured through the colormap instead of by phase,
        over [vmin, vmax] (defaults: min and max over the fluid particles;
        non-finite values are drawn at vmax).  Non-finite positions are skipped.
        """
        pos = _as_numpy(positions, n)
        if pos.ndim != 2 or pos.shape[1] != 2:
            raise ValueError(f"positions must have shape (n, 2), got {pos.shape}")
        count = pos.shape[0]
        phase = np.zeros(count, np.int32) if phase is None else _as_numpy(phase, count)
        kind = np.full(count, FLUID, np.int32) if kind is None else _as_numpy(kind, count)
        phase = np.ascontiguousarray(phase, dtype=np.int32)
        kind = np.ascontiguousarray(kind, dtype=np.int32)
        if phase.shape != (count,) or kind.shape != (count,):
            raise ValueError(f"phase and kind must have shape ({count},)")
        wall = (kind != FLUID) | (phase < 0)
        visible = count if show_walls else int((~wall).sum())
        area = float(np.prod(self.box_hi - self.box_lo))
        spacing_px = math.sqrt(area / max(visible, 1)) * self.scale
        if radius_px is None:
            radius_px = self.radius_px
        if radius_px is None:
            radius_px = DISC_RADIUS * spacing_px
        radius_px = max(float(radius_px), 0.75)
        # disc centres in pixel units (y up), finite and small enough for i32 casts
        pad = self.box_hi - self.box_lo + (radius_px + 2.0) / self.scale
        far = self.box_lo - pad
        pos = np.asarray(pos, dtype=np.float64)
        bad = ~np.isfinite(pos).all(axis=1)
        if bad.any():
            pos = pos.copy()
            pos[bad] = far
        pos = np.clip(pos, far, self.box_hi + pad)
        px = np.ascontiguousarray((pos - self.box_lo) * self.scale + self.offset, dtype=np.float32)
        # colour-table row of every particle
        if scalar is None:
            rows = _PHASE_BASE + np.mod(phase, self.n_phase)
        else:
            s = np.asarray(_as_numpy(scalar, count), dtype=np.float64)
            if s.shape != (count,):
                raise ValueError(f"scalar must have shape ({count},), got {s.shape}")
            fin = s[~wall & np.isfinite(s)]
            lo_v = float(vmin) if vmin is not None else (float(fin.min()) if fin.size else 0.0)
            hi_v = float(vmax) if vmax is not None else (float(fin.max()) if fin.size else 1.0)
            s = np.nan_to_num(s, nan=hi_v, posinf=hi_v, neginf=lo_v)
            t = np.clip((s - lo_v) / (hi_v - lo_v), 0.0, 1.0) if hi_v > lo_v else np.zeros(count)
            rows = np.minimum((t * _CMAP_ROWS).astype(np.int32), _CMAP_ROWS - 1)
        rows = np.where(wall, WALL_ROW if show_walls else -1, rows).astype(np.int32)
        bg = self.background
        if self.style == "smooth":
            self._draw_smooth(px, rows, spacing_px)
        else:
            _draw_discs(px, rows, radius_px, self.table_np, self.image, bg)
        return self.image.copy()

    def _draw_smooth(self, px, rows, spacing_px: float) -> None:
        """The smooth style: :func:`_draw_smooth_field` with the particles' colours."""
        keep = rows >= 0
        px, rows = px[keep], rows[keep]
        radius = max(SMOOTH_RADIUS * spacing_px, 1.5)
        colour = self.table_np[rows].astype(np.float32)
        # sum of the weights inside a uniformly filled region: pi R^2 / (3 s^2);
        # full colour from a fifth of it on (gaps between disordered particles
        # stay coloured, the fluid's free edges fade over a fraction of a spacing)
        full = SMOOTH_EDGE * math.pi * radius * radius / (3.0 * spacing_px * spacing_px)
        stride = max(1, int(spacing_px // SMOOTH_SAMPLES_PER_SPACING))
        _draw_smooth_field(px, colour, radius, full, stride, self.image, self.background)

    def render_particles(self, particles, color: str = "phase", **kwargs) -> np.ndarray:
        """Draw a :class:`~taichi_hh.sph.particles.Particles` set, by ``"phase"`` or ``"speed"``."""
        pos = particles.get("position")
        scalar = None
        if color == "speed":
            scalar = np.linalg.norm(particles.get("velocity"), axis=1)
            kwargs.setdefault("vmin", 0.0)
        elif color != "phase":
            raise ValueError(f"color must be 'phase' or 'speed', got {color!r}")
        return self.draw(pos, particles.get("phase"), particles.get("kind"), scalar, **kwargs)


# ---- files -----------------------------------------------------------------------

def frame_path(directory: str, index: int) -> str:
    """``directory/frame_{index:05d}.png``."""
    return os.path.join(directory, f"frame_{int(index):05d}.png")


def png_bytes(image: np.ndarray) -> bytes:
    """PNG of a u8 (H, W), (H, W, 3) or (H, W, 4) image: filter "none" and zlib
    level 1 (about 5x faster than Pillow's adaptive filtering at its level 1,
    files about 10% larger)."""
    h, w = image.shape[:2]
    channels = 1 if image.ndim == 2 else image.shape[2]
    raw = np.empty((h, w * channels + 1), dtype=np.uint8)
    raw[:, 0] = 0                                   # filter type per scanline: none
    raw[:, 1:] = image.reshape(h, -1)
    colour_type = {1: 0, 3: 2, 4: 6}[channels]

    def chunk(tag: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + tag + data
                + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF))

    return (b"\x89PNG\r\n\x1a\n"
            + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw.data, 1))
            + chunk(b"IEND", b""))


def _save_png(target: str, image: np.ndarray) -> None:
    with open(target, "wb") as fh:
        fh.write(png_bytes(image))


def write_png(path: str, image_u8) -> str:
    """Write a u8 image (H, W), (H, W, 3) or (H, W, 4) as PNG (zlib level 1), atomically."""
    image = _as_numpy(image_u8)
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (3, 4)):
        raise ValueError(f"image must be u8 (H, W), (H, W, 3) or (H, W, 4), got {image.dtype} {image.shape}")
    with atomic_path(path, suffix=".png") as tmp:
        _save_png(tmp, np.ascontiguousarray(image))
    return path


def _frame_list(frames) -> list:
    if isinstance(frames, str):
        found = sorted(_glob.glob(frames))
        if not found:
            raise FileNotFoundError(f"no frames match {frames!r}")
        return found
    frames = list(frames)
    if not frames:
        raise ValueError("no frames to write")
    return frames


def _read_frame(frame) -> np.ndarray:
    if isinstance(frame, (str, os.PathLike)):
        import imageio.v3 as iio
        frame = iio.imread(frame)
    frame = np.asarray(frame)
    if frame.ndim == 2:
        frame = np.repeat(frame[:, :, None], 3, axis=2)
    return np.ascontiguousarray(frame[:, :, :3].astype(np.uint8, copy=False))


def have_mp4() -> bool:
    """Whether MP4 writing is available (the ``mp4`` extra: imageio-ffmpeg)."""
    return importlib.util.find_spec("imageio_ffmpeg") is not None


def write_movie(frames, path: str, fps: float = 20.0, *, stream=None) -> str:
    """Write frames (a glob pattern, or a list of PNG paths or u8 arrays) as a GIF
    or MP4 movie, chosen by the extension of ``path``; atomic.

    MP4 needs the ``mp4`` extra (imageio-ffmpeg); without it a GIF is written next to ``path``
    (same name, ``.gif``) and one message says so.  Returns the path written.
    GIF stores frame durations in 1/100 s, so fps above 50 are not honoured by
    most viewers; identical consecutive frames are merged by Pillow.
    """
    stream = sys.stderr if stream is None else stream
    frames = _frame_list(frames)
    fps = float(fps)
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".gif", ".mp4"):
        raise ValueError(f"movie path must end in .gif or .mp4, got {path!r}")
    if ext == ".mp4" and not have_mp4():
        path = os.path.splitext(path)[0] + ".gif"
        ext = ".gif"
        print(f"taichi_hh: MP4 needs the mp4 extra (pip install 'taichi-hh[mp4]', which brings "
              f"imageio-ffmpeg); "
              f"writing a GIF instead: {path}", file=stream)
    with atomic_path(path, suffix=ext) as tmp:
        if ext == ".gif":
            _write_gif(frames, tmp, fps)
        else:
            _write_mp4(frames, tmp, fps)
    return path


def _write_gif(frames, tmp: str, fps: float) -> None:
    import imageio.v3 as iio
    duration = 1000.0 / fps
    # frame by frame, quantised to 8-bit palettes as they come: 1 byte per pixel held
    with iio.imopen(tmp, "w", extension=".gif", plugin="pillow") as out:
        for frame in frames:
            out.write(_read_frame(frame), bits=8, duration=duration, loop=0)


def _write_mp4(frames, tmp: str, fps: float) -> None:
    import imageio.v2 as iio2
    writer = iio2.get_writer(tmp, format="FFMPEG", mode="I", fps=fps, codec="libx264",
                             pixelformat="yuv420p", macro_block_size=1, quality=8)
    try:
        for frame in frames:
            img = _read_frame(frame)
            h, w = img.shape[:2]
            if h % 2 or w % 2:                 # yuv420p needs even sizes: pad by edge copy
                img = np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
            writer.append_data(img)
    finally:
        writer.close()
