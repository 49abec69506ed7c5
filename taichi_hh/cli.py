"""Command line: ``taichi-hh`` (also ``python -m taichi_hh``).

Subcommands are added as features land; each lives in its own function and
only parses arguments, calls the library and writes files.
"""
from __future__ import annotations

import argparse
import sys


def _cmd_info(args) -> int:
    import taichi_hh as thh
    st = thh.init(arch=args.arch, precision=args.precision)
    print(f"taichi_hh {thh.__version__}: Taichi arch={st.arch} (requested {st.requested_arch}), "
          f"precision={st.precision}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="taichi-hh", description=(
        "Meshless Helmholtz-Hodge decomposition and null-divergence SPH on Taichi."))
    sub = ap.add_subparsers(dest="command", required=True)
    info = sub.add_parser("info", help="show the version and the Taichi arch in use")
    info.add_argument("--arch", default="auto", choices=("cpu", "gpu", "auto"),
                      help="Taichi arch: cpu, gpu (falls back to cpu) or auto (default)")
    info.add_argument("--precision", default="f64", choices=("f32", "f64"))
    info.set_defaults(func=_cmd_info)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
