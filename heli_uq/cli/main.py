"""Command line interface ``heli-uq`` (also ``python -m heli_uq.cli``).

Subcommands (one module each)::

    heli-uq run [--data experimental|synthetic|FILE.csv] [--effects ...] [--out DIR]
    heli-uq simulate --inputs table3|experiment|FILE.csv [--effects ...] [--params P.json] ...
    heli-uq data show experimental|FILE.csv [--window a:b] --out DIR
    heli-uq sample --data experimental|FILE.csv [--effects ...] [--train a:b --test c:d] ...
    heli-uq identifiability --data experimental|FILE.csv [--effects ...] [--free NAMES] ...
    heli-uq discover experimental|FILE.csv [--train a:b --test c:d] [--max-effects N] --out DIR
    heli-uq design [--posterior posterior.nc | --discovery DIR] [--duration S] --out DIR

Adding a subcommand is one module with ``add_parser(subparsers)`` (building its parser,
setting ``handler=<function(args) -> int>`` and returning the parser) plus one entry in
:data:`_COMMANDS`.

Exit codes: 0 success, 1 the simulation failed (diverged), 2 bad input or usage (any
:class:`~heli_uq.errors.HeliUQError`, an output that cannot be written, or an argparse
usage error, a ``--seed`` outside 0..2**32-1), 3 a health check failed under ``--strict``,
70 an internal error (an exception no check caught: a bug, reported in one line; the
environment variable ``HELI_UQ_TRACEBACK=1`` lets its traceback through), 130
interrupted (SIGINT; the finished draws are saved and one line says how to resume).
Errors are reported as one line ``heli-uq: error: <message>`` on stderr; a message from
the library that starts with an argument name (``effects: ...``) is shown with the option that set it
(``--effects: ...``).

JAX: the commands that sample set one XLA host device per chain
(``numpyro.set_host_device_count``) before JAX starts, so chains run in parallel.  Every
command keeps compiled programs on disk (:func:`heli_uq.executor.use_compilation_cache`,
``~/.cache/heli_uq/jax`` unless ``JAX_COMPILATION_CACHE_DIR`` names another): a rerun, a
resumed run or the next record of the same length reads them instead of compiling again.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import sys
from pathlib import Path

from heli_uq.cli import data, design, discover, identifiability, run, sample, simulate
from heli_uq.cli.options import Formatter
from heli_uq.errors import HeliUQError
from heli_uq.executor import use_compilation_cache
from heli_uq.log import configure_cli

__all__ = ["main", "build_parser"]

PROG = "heli-uq"
#: Subcommand modules, in the order shown by ``--help``.
_COMMANDS = (run, simulate, data, sample, identifiability, discover, design)


def build_parser() -> argparse.ArgumentParser:
    """The ``heli-uq`` argument parser with all subcommands."""
    parser, _ = _build()
    return parser


class _Parser(argparse.ArgumentParser):
    """argparse with its usage errors on one line (``heli-uq sample: error: argument
    --seed: invalid int value: '1.5' (see 'heli-uq sample --help')``), exit status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


#: Seeds numpy and JAX both take: 0 <= seed < 2**32.
SEED_LIMIT = 2**32
#: Exit status of an unexpected exception (a bug; EX_SOFTWARE of sysexits.h).
EXIT_INTERNAL = 70
#: Environment variable that lets an unexpected exception's traceback through (tests set it).
TRACEBACK_ENV = "HELI_UQ_TRACEBACK"


def _internal_error(exc: BaseException) -> str:
    """One line for an exception no check caught: its type, message and where it rose."""
    import traceback

    frames = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in frames if "heli_uq" in f.filename] or frames
    where = f" at {Path(ours[-1].filename).name}:{ours[-1].lineno}" if ours else ""
    text = " ".join(str(exc).split())
    return (f"{PROG}: internal error (a bug: please report it with the command): "
            f"{type(exc).__name__}: {text}{where}; set {TRACEBACK_ENV}=1 for the traceback")


def _build():
    parser = _Parser(
        prog=PROG,
        description="Bayesian uncertainty quantification of a 2-DOF laboratory helicopter.\n"
                    "States (theta, psi, omega_theta, omega_psi) in rad and rad/s; voltages "
                    "in V;\nparameters in SI units (paper Table 2).",
        epilog="Run 'heli-uq COMMAND --help' for the options of a command.",
        formatter_class=Formatter,
    )  # fmt: skip
    sub = parser.add_subparsers(title="commands", dest="command", required=True, metavar="COMMAND")
    options = {}
    for module in _COMMANDS:
        leaf = module.add_parser(sub)
        if "--quiet" not in {s for a in leaf._actions for s in a.option_strings}:
            leaf.add_argument("--quiet", action="store_true",
                              help="no progress messages or bars (results and errors still shown)")
        options[leaf.get_default("handler")] = {s for a in leaf._actions for s in a.option_strings}
    return parser, options


def _with_option(message: str, options: set) -> str:
    """``"effects: ..."`` -> ``"--effects: ..."`` when ``--effects`` is an option here."""
    match = re.match(r"([a-z][a-z0-9_]*)([: ])", message)
    if match:
        flag = "--" + match.group(1).replace("_", "-")
        if flag in options:
            return flag + message[len(match.group(1)):]
    return message


#: Exit status after SIGINT (128 + 2, the shell's convention).
EXIT_INTERRUPTED = 130


def _interrupt_message(exc: KeyboardInterrupt, args, argv: list[str]) -> str:
    """One line: what was saved and the command that continues: the same one with
    ``--resume`` for a command that has it, the same one unchanged for a command whose
    parser sets ``rerun_reuses`` (what a rerun picks up, e.g. ``discover``)."""

    from heli_uq.inference.interrupt import Interrupted
    from heli_uq.inference.manifest import MANIFEST_FILE

    resumes = hasattr(args, "resume")
    again = [PROG, *argv] + (["--resume"] if resumes and "--resume" not in argv else [])
    reuses = getattr(args, "rerun_reuses", None)
    if reuses is not None:
        saved = f"{exc.saved}; " if isinstance(exc, Interrupted) else ""
        return f"interrupted: {saved}the same command reuses {reuses}: {shlex.join(again)}"
    if isinstance(exc, Interrupted):
        return f"interrupted: {exc.saved}; continue with: {shlex.join(again)}"
    out = getattr(args, "out", None)
    saved = sorted(Path(out).rglob(MANIFEST_FILE)) if out and resumes else []
    if saved:  # between sampler blocks' safe points (MAP, post-processing): chunks are on disk
        what = ("the draws saved in" if any(saved[0].parent.glob("*_chunk_*.pkl"))
                else "no draws yet; the MAP start saved in")  # before the first block ended
        return f"interrupted; {what} {saved[0].parent} continue with: {shlex.join(again)}"
    return "interrupted before anything was saved; run the command again"


def main(argv: list[str] | None = None) -> int:
    """Run ``heli-uq`` with *argv* (default ``sys.argv[1:]``); return the exit status."""
    parser, options = _build()
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(argv)
    if not 0 <= getattr(args, "seed", 0) < SEED_LIMIT:
        parser.exit(2, f"{PROG}: error: --seed: expected an integer in 0..{SEED_LIMIT - 1}, "
                       f"found {args.seed}\n")  # fmt: skip
    configure_cli(args.quiet)
    use_compilation_cache()
    if args.quiet and hasattr(args, "no_progress"):
        args.no_progress = True
    try:
        return int(args.handler(args))
    except KeyboardInterrupt as exc:
        print(f"{PROG}: {_interrupt_message(exc, args, argv)}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (HeliUQError, OSError) as exc:
        if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
            message = f"{exc.filename}: {exc.strerror}"  # e.g. an --out that is a file
        else:
            message = " ".join(str(exc).split()) or type(exc).__name__
            message = _with_option(message, options.get(args.handler, set()))
        print(f"{PROG}: error: {message}", file=sys.stderr)
        return 2
    except Exception as exc:
        if os.environ.get(TRACEBACK_ENV):
            raise
        print(_internal_error(exc), file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":
    raise SystemExit(main())
