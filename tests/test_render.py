"""Headless frames: disc placement and colours (y up), aspect ratio, colormap,
PNG round trip, movies, and no half-written files after a failed write."""
import io as _io
import os

import imageio.v3 as iio
import numpy as np
import pytest

from taichi_hh.app import render
from taichi_hh.sph.particles import BOUNDARY, FLUID, GHOST


def test_discs_land_on_the_right_pixels_with_the_right_colours():
    r = render.FrameRenderer(200, None, (0.0, 0.0), (2.0, 1.0), radius_px=5)
    assert (r.width, r.height) == (200, 100)
    pos = np.array([[0.5, 0.25], [1.5, 0.75], [1.0, 0.5]])
    img = r.draw(pos, phase=[0, 1, 0], kind=[FLUID, FLUID, BOUNDARY])
    assert img.shape == (100, 200, 3) and img.dtype == np.uint8
    blue, orange = r.colour_of_phase(0), r.colour_of_phase(1)
    grey = tuple(render.WALL_COLOUR)
    assert blue == render.PHASE_PALETTE[0] and orange == render.PHASE_PALETTE[1]
    # y up: (0.5, 0.25) is in the lower half of the image, i.e. at a large row
    assert r.world_to_pixel(0.5, 0.25) == (50, 74)
    assert tuple(img[74, 50]) == blue
    assert tuple(img[24, 150]) == orange           # (1.5, 0.75): upper right
    assert tuple(img[49, 100]) == grey             # the wall particle at the centre
    assert tuple(img[25, 50]) == (255, 255, 255)   # where a y-down image would put it
    # disc extent: pixel centres within 5 px are covered, farther ones are not
    assert tuple(img[74, 50 + 4]) == blue and tuple(img[74 - 4, 50]) == blue
    assert tuple(img[74, 50 + 6]) == (255, 255, 255) and tuple(img[74 + 6, 50]) == (255, 255, 255)
    covered = (img != 255).any(axis=2)
    # three discs of radius 5 px: about 3 * pi * 25 pixels, background elsewhere
    assert abs(covered.sum() - 3 * np.pi * 25) < 20
    assert not covered[:, :30].any() and not covered[:, 170:].any()


def test_background_walls_hidden_and_ghosts_are_walls():
    r = render.FrameRenderer(100, None, (0, 0), (1, 1), radius_px=4, background=(10, 20, 30))
    pos = np.array([[0.25, 0.25], [0.75, 0.75], [0.25, 0.75]])
    img = r.draw(pos, phase=[0, -1, 1], kind=[FLUID, GHOST, FLUID])
    assert tuple(img[0, 0]) == (10, 20, 30)
    assert tuple(img[r.world_to_pixel(0.75, 0.75)[::-1]]) == tuple(render.WALL_COLOUR)
    img = r.draw(pos, phase=[0, -1, 1], kind=[FLUID, GHOST, FLUID], show_walls=False)
    assert tuple(img[r.world_to_pixel(0.75, 0.75)[::-1]]) == (10, 20, 30)
    assert tuple(img[r.world_to_pixel(0.25, 0.75)[::-1]]) == r.colour_of_phase(1)


def test_aspect_ratio_is_kept():
    assert render.FrameRenderer(300, None, (0, 0), (3, 1)).height == 100
    assert render.FrameRenderer(100, None, (-1, 0), (1, 4)).height == 200
    # both sizes given, box 2:1 in a square image: letterboxed, discs stay round
    r = render.FrameRenderer(200, 200, (0, 0), (2, 1), radius_px=10)
    assert r.scale == 100
    img = r.draw(np.array([[1.0, 0.5]]))
    rows, cols = np.nonzero((img != 255).any(axis=2))
    assert rows.max() - rows.min() == cols.max() - cols.min()
    assert abs(rows.mean() - 99.5) < 0.6 and abs(cols.mean() - 99.5) < 0.6
    # the box (0..1 in y) covers rows 50..149 only
    img = r.draw(np.array([[0.0, 0.0], [2.0, 1.0]]), radius_px=1)
    rows, _ = np.nonzero((img != 255).any(axis=2))
    assert rows.min() >= 49 and rows.max() <= 150


def _cmap_index(r, colour):
    d = np.abs(r.table_np[:256].astype(int) - np.asarray(colour, int)).sum(axis=1)
    return int(np.argmin(d))


def test_speed_colouring_is_monotone():
    r = render.FrameRenderer(400, None, (0, 0), (1, 0.1), radius_px=3)
    x = np.linspace(0.05, 0.95, 10)
    pos = np.c_[x, np.full(10, 0.05)]
    speed = np.linspace(0.0, 2.0, 10)
    img = r.draw(pos, scalar=speed)
    idx = [_cmap_index(r, img[r.world_to_pixel(*p)[::-1]]) for p in pos]
    assert idx[0] == 0 and idx[-1] == 255
    assert all(b > a for a, b in zip(idx, idx[1:]))
    # an explicit range clamps; a non-finite value is drawn at the top of the range
    speed2 = speed.copy()
    speed2[3] = np.nan
    img = r.draw(pos, scalar=speed2, vmin=0.0, vmax=1.0)
    idx = [_cmap_index(r, img[r.world_to_pixel(*p)[::-1]]) for p in pos]
    assert idx[3] == 255 and idx[-1] == 255 and idx[0] == 0


def test_overlaps_go_to_the_nearest_centre_whatever_the_order():
    r = render.FrameRenderer(100, None, (0, 0), (1, 1), radius_px=12)
    pos = np.array([[0.45, 0.5], [0.55, 0.5]])
    a = r.draw(pos, phase=[0, 1])
    b = r.draw(pos[::-1], phase=[1, 0])
    assert np.array_equal(a, b)
    assert tuple(a[49, 47]) == r.colour_of_phase(0) and tuple(a[49, 52]) == r.colour_of_phase(1)


def test_non_finite_and_far_positions_are_skipped():
    r = render.FrameRenderer(50, None, (0, 0), (1, 1), radius_px=2)
    pos = np.array([[np.nan, 0.5], [np.inf, -np.inf], [1e300, 0.5], [0.5, 0.5]])
    img = r.draw(pos)
    covered = (img != 255).any(axis=2)
    assert covered.sum() > 0 and covered.sum() < 20   # only the last disc


def test_render_particles_from_a_particle_set():
    from taichi_hh.sph.particles import Particles
    p = Particles.from_numpy(np.array([[0.25, 0.5], [0.75, 0.5]]), velocity=[[0, 0], [3, 4]],
                             phase=[0, 1])
    r = render.FrameRenderer(100, None, (0, 0), (1, 1), radius_px=4)
    img = r.render_particles(p)
    assert tuple(img[r.world_to_pixel(0.75, 0.5)[::-1]]) == r.colour_of_phase(1)
    img = r.render_particles(p, color="speed")
    assert _cmap_index(r, img[r.world_to_pixel(0.75, 0.5)[::-1]]) == 255
    assert _cmap_index(r, img[r.world_to_pixel(0.25, 0.5)[::-1]]) == 0


@pytest.mark.parametrize("shape", [(37, 53, 3), (20, 30), (16, 9, 4)])
def test_png_round_trip(tmp_path, shape):
    img = np.random.default_rng(1).integers(0, 256, shape, dtype=np.uint8)
    path = str(tmp_path / "a.png")
    assert render.write_png(path, img) == path
    assert np.array_equal(iio.imread(path), img)
    assert os.listdir(tmp_path) == ["a.png"]


def test_frame_path():
    assert render.frame_path("out", 7) == os.path.join("out", "frame_00007.png")


def _frames(n=3, shape=(24, 32, 3)):
    rng = np.random.default_rng(2)
    return [np.full(shape, rng.integers(0, 256, 3), dtype=np.uint8) for _ in range(n)]


def test_gif_from_frame_files(tmp_path):
    for i, f in enumerate(_frames(4)):
        render.write_png(render.frame_path(str(tmp_path), i), f)
    out = render.write_movie(str(tmp_path / "frame_*.png"), str(tmp_path / "movie.gif"), fps=10)
    assert out == str(tmp_path / "movie.gif")
    movie = iio.imread(out, index=None)
    assert movie.shape[0] == 4 and movie.shape[1:3] == (24, 32)
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".tmp")]


def test_mp4_without_ffmpeg_falls_back_to_gif(tmp_path, monkeypatch):
    monkeypatch.setattr(render, "have_mp4", lambda: False)
    msg = _io.StringIO()
    out = render.write_movie(_frames(3), str(tmp_path / "movie.mp4"), fps=5, stream=msg)
    assert out == str(tmp_path / "movie.gif")
    assert "taichi-hh[mp4]" in msg.getvalue() and msg.getvalue().count("\n") == 1
    assert iio.imread(out, index=None).shape[0] == 3


def test_bad_movie_arguments(tmp_path):
    with pytest.raises(ValueError, match="gif or .mp4"):
        render.write_movie(_frames(1), str(tmp_path / "m.avi"))
    with pytest.raises(FileNotFoundError):
        render.write_movie(str(tmp_path / "none_*.png"), str(tmp_path / "m.gif"))


def test_failed_writes_leave_nothing_half_written(tmp_path, monkeypatch):
    good = np.zeros((8, 8, 3), np.uint8)
    path = str(tmp_path / "frame_00000.png")
    render.write_png(path, good)
    before = open(path, "rb").read()

    def broken_png(target, image):
        with open(target, "wb") as fh:
            fh.write(b"\x89PNG partial")
        raise OSError("disk full")

    monkeypatch.setattr(render, "_save_png", broken_png)
    with pytest.raises(OSError, match="disk full"):
        render.write_png(path, np.full((8, 8, 3), 9, np.uint8))
    with pytest.raises(OSError, match="disk full"):
        render.write_png(str(tmp_path / "frame_00001.png"), good)
    assert sorted(os.listdir(tmp_path)) == ["frame_00000.png"]
    assert open(path, "rb").read() == before

    def broken_gif(frames, tmp, fps):
        with open(tmp, "wb") as fh:
            fh.write(b"GIF89a partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(render, "_write_gif", broken_gif)
    with pytest.raises(KeyboardInterrupt):
        render.write_movie([good, good], str(tmp_path / "movie.gif"))
    assert sorted(os.listdir(tmp_path)) == ["frame_00000.png"]


def test_bad_renderer_arguments():
    with pytest.raises(ValueError, match="box"):
        render.FrameRenderer(100, None, (0, 0), (0, 1))
    with pytest.raises(ValueError, match="background"):
        render.FrameRenderer(100, None, (0, 0), (1, 1), background=(0, 0, 300))
    r = render.FrameRenderer(10, None, (0, 0), (1, 1))
    with pytest.raises(ValueError, match="shape"):
        r.draw(np.zeros((3, 3)))


def test_mp4_when_imageio_ffmpeg_is_installed(tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    import imageio.v2 as iio2
    frames = _frames(5, shape=(25, 31, 3))              # odd sizes: padded to even
    out = render.write_movie(frames, str(tmp_path / "movie.mp4"), fps=10)
    assert out == str(tmp_path / "movie.mp4")
    reader = iio2.get_reader(out)
    assert sum(1 for _ in reader) == 5
    reader.close()
    assert os.listdir(tmp_path) == ["movie.mp4"]


# ---- the smooth style and the labels ---------------------------------------------------

def _lattice(n_side, jitter=0.0, seed=0):
    g = (np.arange(n_side) + 0.5) / n_side
    pts = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    return pts + np.random.default_rng(seed).normal(0.0, jitter / n_side, pts.shape)


def test_smooth_style_fills_the_fluid_without_gaps_and_keeps_each_phase_colour():
    pts = _lattice(40, jitter=0.2)
    phase = (pts[:, 0] > 0.5).astype(int)
    smooth = render.FrameRenderer(200, None, (0, 0), (1, 1), style="smooth")
    img = smooth.draw(pts, phase=phase)
    inner = img[10:-10, 10:-10]
    assert not (inner == 255).all(axis=2).any()          # no background speck inside
    left, right = smooth.colour_of_phase(0), smooth.colour_of_phase(1)
    assert tuple(img[100, 40]) == left and tuple(img[100, 160]) == right
    # across the interface the colour blends over about two particle spacings (10 px)
    row = img[100].astype(int)
    mixed = [c for c in range(200) if tuple(row[c]) not in (left, right)]
    assert mixed and max(mixed) - min(mixed) <= 12 and 88 <= np.mean(mixed) <= 112
    # the disc style on the same points leaves gaps between the discs where jitter opens them
    discs = render.FrameRenderer(200, None, (0, 0), (1, 1), radius_px=2.0)
    assert (discs.draw(pts, phase=phase)[10:-10, 10:-10] == 255).all(axis=2).any()


def test_smooth_style_fades_to_background_away_from_the_particles():
    pts = _lattice(20)
    pts = pts[pts[:, 1] < 0.5]                          # the lower half only
    r = render.FrameRenderer(100, None, (0, 0), (1, 1), style="smooth", background=(0, 0, 0))
    img = r.draw(pts)
    assert (img[:40] == 0).all()                         # the empty upper part
    assert tuple(img[80, 50]) == r.colour_of_phase(0)
    # the speed colouring goes through the same interpolation
    img = r.draw(pts, scalar=pts[:, 0], vmin=0.0, vmax=1.0)
    lo, hi = _cmap_index(r, img[80, 10]), _cmap_index(r, img[80, 90])
    assert lo < 40 and hi > 215


def test_style_is_checked():
    with pytest.raises(ValueError, match="style"):
        render.FrameRenderer(10, style="blobs")


def test_labelled_frame_has_walls_time_and_legend():
    from taichi_hh.app.overlay import (FRAME_GREY, FrameLabels, header_height, label_frame,
                                       text_bitmap)
    image = np.full((100, 300, 3), 200, np.uint8)
    legend = [("light", (10, 20, 30)), ("heavy", (200, 40, 40))]
    out = label_frame(image, 1.5, FrameLabels(legend=legend, wall_px=3))
    band = header_height(306)
    assert out.shape == (band + 106, 306, 3)
    assert (out[band + 3:-3, 3:-3] == 200).all()                  # the image, unchanged
    assert (out[band:band + 3] == FRAME_GREY).all() and (out[band:, :3] == FRAME_GREY).all()
    header = out[:band]
    for _, colour in legend:                                       # legend swatches
        assert (header == colour).all(axis=2).sum() > 50
    # the time stamp is text: another time changes the band only where it is written
    other = label_frame(image, 2.5, FrameLabels(legend=legend, wall_px=3))
    diff = (other[:band] != out[:band]).any(axis=2)
    text_width = text_bitmap("t = 2.50", max(10, int(band * 0.55))).shape[1]
    assert diff.any() and np.nonzero(diff)[1].max() < 3 + 4 + text_width
    assert (other[band:] == out[band:]).all()
    # too narrow for the legend beside the time: the legend is left out, not overlapped
    narrow = label_frame(image[:, :60], 1.5, FrameLabels(legend=legend, wall_px=3))
    assert not (narrow == (200, 40, 40)).all(axis=2).any()


def test_colorbar_shows_the_colormap_ramp():
    from taichi_hh.app.overlay import FrameLabels, header_height, label_frame
    table = render.colormap_table("viridis")
    out = label_frame(np.zeros((50, 400, 3), np.uint8), 0.0,
                      FrameLabels(colorbar=("speed", 0.0, 2.0, table), wall_px=0))
    header = out[:header_height(400)].reshape(-1, 3)
    for k in (0, 128, 255):
        assert (np.abs(header.astype(int) - table[k].astype(int)).sum(axis=1) <= 6).any()


def _jittered_lattice(n_side, jitter=0.3, seed=3):
    dx = 1.0 / n_side
    g = (np.arange(n_side) + 0.5) * dx
    pts = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    return pts + np.random.default_rng(seed).uniform(-jitter, jitter, pts.shape) * dx, dx


def test_vorticity_colouring_is_symmetric_and_diverging():
    pts, _ = _jittered_lattice(40)
    # v = (0, sin(2 pi x) / (2 pi)): vorticity cos(2 pi x), +1 at the sides, -1 in the middle
    vel = np.stack([0 * pts[:, 0], np.sin(2 * np.pi * pts[:, 0]) / (2 * np.pi)], 1)
    omega = np.cos(2 * np.pi * pts[:, 0])
    scalar, vmin, vmax, name = render.frame_colouring("vorticity", vel, vorticity=omega)
    assert np.array_equal(scalar, omega)
    assert name == "vorticity" and vmin == -vmax and vmax == pytest.approx(np.abs(scalar).max())
    assert vmax == pytest.approx(1.0, rel=0.05)
    r = render.FrameRenderer(300, None, (0, 0), (1, 1), style="smooth",
                             colormap=render.COLORMAPS["vorticity"])
    img = r.draw(pts, scalar=scalar, vmin=vmin, vmax=vmax)
    at = {x: img[r.world_to_pixel(x, 0.5)[::-1]] for x in (0.1, 0.25, 0.5)}
    idx = {x: _cmap_index(r, c) for x, c in at.items()}
    # cos(0.2 pi) = 0.81 and -1 over [-1, 1]: rows 231 and 0
    assert abs(idx[0.1] - 231) <= 8 and idx[0.5] <= 8
    # the diverging map: red above its white centre (zero, at x = 0.25), blue below
    assert at[0.1][0] > at[0.1][2] + 60 and at[0.5][2] > at[0.5][0] + 60
    assert min(at[0.25]) > 220
    # speed and phase colourings keep their meaning
    s, lo, hi, _ = render.frame_colouring("speed", vel)
    assert lo == 0 and hi == pytest.approx(np.linalg.norm(vel, axis=1).max())
    assert render.frame_colouring("phase", vel)[0] is None
    with pytest.raises(ValueError, match="color must be one of"):
        render.frame_colouring("pressure", vel)
    with pytest.raises(ValueError, match="needs the particles' vorticity"):
        render.frame_colouring("vorticity", vel)
