"""The ``agrivio`` command line.

Sub-commands live in ``pipeline/commands/<name>.py``; each module defines ``register(subparsers)`` which adds
its parser and sets ``func`` (a callable taking the parsed ``argparse.Namespace`` and returning an exit code).
User errors (``AgrivioError`` and the libraries' input errors) are printed without a traceback, exit code 2.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import pkgutil
import sys

from pipeline import commands
from pipeline.errors import AgrivioError

#: OSError numbers that mean "the output cannot be written" (reported in one line, exit 2).
_DISK_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS}


def _user_error_types() -> tuple[type[BaseException], ...]:
    """Exception types that mean 'bad input', from the pipeline and each library that defines them."""
    types: list[type[BaseException]] = [AgrivioError, FileNotFoundError]
    for module_name, attr in (("inpaint.errors", "InpaintInputError"), ("eval.errors", "EvalInputError"),
                              ("msckf.errors", "MsckfInputError")):
        try:
            types.append(getattr(importlib.import_module(module_name), attr))
        except (ImportError, AttributeError):
            continue
    return tuple(types)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="agrivio",
        description="Does inpainting stereo depth holes make an MSCKF VIO more accurate on agricultural sequences?",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except _user_error_types() as exc:
        print(f"agrivio: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        if exc.errno not in _DISK_ERRNOS:
            raise
        # disk full, no permission, read-only file system: the user's environment, not a bug; what was written
        # before stays (every output is written atomically)
        where = exc.filename or "output"
        print(f"agrivio: error: {where}: {exc.strerror or exc}; files written before this are kept", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("agrivio: interrupted; results written so far are kept", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
