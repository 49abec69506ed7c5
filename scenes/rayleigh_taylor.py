"""Rayleigh-Taylor instability: heavy fluid over light with a single-mode

The scene lives in :mod:`taichi_hh.app.scenes.rayleigh_taylor` (also run by ``taichi-hh
scene rayleigh-taylor`` after ``pip install``); this script is the README's command.
``python scenes/rayleigh_taylor.py --help`` lists its options.
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from taichi_hh.app.scene import main  # noqa: E402,F401
from taichi_hh.app.scenes.rayleigh_taylor import *  # noqa: E402,F401,F403  (SCENE, build, measures, ...)
from taichi_hh.app.scenes.rayleigh_taylor import SCENE  # noqa: E402

if __name__ == "__main__":
    sys.exit(main(SCENE))
