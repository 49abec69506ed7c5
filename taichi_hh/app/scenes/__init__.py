"""The two-phase scenes, importable after ``pip install`` (``taichi-hh scene
NAME``); ``scenes/*.py`` in the checkout run the same definitions."""
import importlib

#: command-line name -> module of the scene (each defines ``SCENE``)
SCENES = {"rising-droplet": "rising_droplet", "rayleigh-taylor": "rayleigh_taylor"}


def get(name: str):
    """The :class:`~taichi_hh.app.scene.Scene` called ``name`` (as in :data:`SCENES`)."""
    try:
        module = SCENES[name]
    except KeyError:
        raise ValueError(f"unknown scene {name!r}; choose one of {tuple(SCENES)}") from None
    return importlib.import_module(f"{__name__}.{module}").SCENE
