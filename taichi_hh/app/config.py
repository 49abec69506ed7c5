"""Scene options from a TOML file (``--config``), and the options of a run
written back as TOML so that it can be repeated.

A config file holds ``option = value`` pairs, the option named as on the
command line without the dashes (``end-time`` or ``end_time``).  Its values
become command-line tokens placed before the real ones, so they pass the same
checks as typed options and an option given on the command line wins.
"""
from __future__ import annotations

import argparse
import math

from .io import atomic_path

#: options that say how to run, not what: never read from or written to a config
RUN_ONLY = ("help", "config", "resume", "docs", "quiet")


def _options(parser: argparse.ArgumentParser) -> dict:
    """dest -> action, for the optional arguments a config may set."""
    return {a.dest: a for a in parser._actions      # argparse keeps no public list of them
            if a.option_strings and a.dest not in RUN_ONLY}


def _load(path: str) -> dict:
    try:
        import tomllib
    except ModuleNotFoundError:                 # Python 3.10
        import tomli as tomllib
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except OSError as exc:
        raise ValueError(f"--config {path}: cannot read it ({exc.strerror or exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"--config {path}: not valid TOML ({exc})") from None


def config_tokens(parser: argparse.ArgumentParser, path: str) -> list[str]:
    """The command-line tokens that the TOML file ``path`` stands for."""
    options = _options(parser)
    tokens = []
    for key, value in _load(path).items():
        dest = key.replace("-", "_")
        action = options.get(dest)
        if action is None:
            known = ", ".join(sorted(d.replace("_", "-") for d in options))
            raise ValueError(f"--config {path}: unknown option {key!r} (known: {known})")
        flag = action.option_strings[0]
        if isinstance(action, argparse.BooleanOptionalAction):
            if not isinstance(value, bool):
                raise ValueError(f"--config {path}: {key} must be true or false, got {value!r}")
            tokens.append(flag if value else "--no-" + flag[2:])
        elif action.nargs == 0 and action.const is True:          # store_true
            if not isinstance(value, bool):
                raise ValueError(f"--config {path}: {key} must be true or false, got {value!r}")
            if value:
                tokens.append(flag)
        else:
            if isinstance(value, (dict, list)):
                raise ValueError(f"--config {path}: {key} must be a single value, got {value!r}")
            tokens += [flag, str(value)]
    return tokens


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ("inf" if value > 0 else "-inf")
    text = str(value).replace("\\", "\\\\").replace('"', '\\"')
    return f'"{text}"'


def write_config(path: str, parser: argparse.ArgumentParser, args: argparse.Namespace,
                 header: str = "") -> str:
    """Write the options of ``args`` that a config may set as TOML, atomically
    (options left at None are left out)."""
    lines = [f"# {line}" for line in header.splitlines()]
    for dest in _options(parser):
        value = getattr(args, dest, None)
        if value is not None:
            lines.append(f"{dest.replace('_', '-')} = {_toml_value(value)}")
    with atomic_path(path, suffix=".toml") as tmp, open(tmp, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    return path
