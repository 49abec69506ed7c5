"""A light circular droplet rising in a fluid twice as dense, in a closed box

The scene lives in :mod:`taichi_hh.app.scenes.rising_droplet` (also run by ``taichi-hh
scene rising-droplet`` after ``pip install``); this script is the README's command.
``python scenes/rising_droplet.py --help`` lists its options.
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from taichi_hh.app.scene import main  # noqa: E402,F401
from taichi_hh.app.scenes.rising_droplet import *  # noqa: E402,F401,F403  (SCENE, build, measures, ...)
from taichi_hh.app.scenes.rising_droplet import SCENE  # noqa: E402

if __name__ == "__main__":
    sys.exit(main(SCENE))
