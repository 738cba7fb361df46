"""`adsm` command line: one module per subcommand, each exposing ``add_parser(subparsers)``.

Errors are reported here, once for every subcommand: a model folder that cannot be loaded or served
(:class:`~service.features.ModelError`), and bad input (``ValueError``, ``OSError``), each as one line
``adsm: error: ...`` on stderr and exit status 1. A subcommand raises and leaves the wording to
:func:`main`.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

# Subcommands are imported lazily by name so that `adsm predict` never pays for FastAPI's import.
_SUBCOMMANDS = ("predict", "serve", "eval", "stats")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="adsm", description="ADSM stereo: rectified stereo pair -> dense disparity, depth, point cloud."
    )
    parser.add_argument("--version", action="version", version=_version())
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in _SUBCOMMANDS:
        try:
            module = importlib.import_module(f"service.cli.{name}")
        except ModuleNotFoundError as error:
            if error.name == f"service.cli.{name}":
                continue  # subcommand not part of this build
            raise
        module.add_parser(subparsers)
    return parser


def _version() -> str:
    """``adsm 0.1.0 (default model adsm-rf17-int8)``: the package and the model a bare command uses, read
    without importing the runtime (a version query must not pay for ONNX Runtime or Numba)."""
    from importlib.resources import files

    from service import __version__

    try:
        model = files("service").joinpath("models", "DEFAULT").read_text(encoding="utf-8").strip()
    except OSError:
        model = "unknown"
    return f"adsm {__version__} (default model {model})"


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from service import jit
    from service.features import ModelError

    jit.configure_cache()  # the compiled-kernel cache is chosen when the command starts, not at import
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except ModelError as error:  # whichever subcommand loaded the folder: its manifest, hashes or towers
        print(f"adsm: error: bad model folder: {_one_line(error)}", file=sys.stderr)
        return 1
    except (OSError, ValueError) as error:
        print(f"adsm: error: {error}", file=sys.stderr)
        return 1


def _one_line(error: BaseException) -> str:
    """The error's message on one line (an ONNX Runtime load error can span several)."""
    return " ".join(str(error).split())


if __name__ == "__main__":
    sys.exit(main())
