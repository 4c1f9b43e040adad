"""The command line, ``nrmicp demo`` and ``nrmicp bench`` (or ``python -m nrmicp ...``): the
dispatch to demo.py, realistic.py and family.py."""
from __future__ import annotations

import argparse
import os
import sys
from typing import Optional


_COMMANDS = {"demo": "every method on a built-in problem (Bai's test matrices)",
             "bench": "work-precision on realistic scenes at realistic sizes, CSV and PNG "
                      "('bench --family': every member, Bai's matrices)"}


def prog_name(argv0: Optional[str] = None) -> str:
    """The command as the user typed it: 'nrmicp' for the installed script, 'python -m nrmicp'."""
    base = os.path.basename(sys.argv[0] if argv0 is None else argv0)
    return "python -m nrmicp" if base in ("__main__.py", "-m", "-c", "") else base


def _parser(prog: str) -> argparse.ArgumentParser:
    import nrmicp

    p = argparse.ArgumentParser(
        prog=prog, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="nrmicp: modulus-based solvers for sparse implicit complementarity problems.",
        epilog="commands:\n" + "\n".join(f"  {c:<6} {h}" for c, h in _COMMANDS.items())
               + f"\n\n'{prog} COMMAND --help' describes a command's options.")
    p.add_argument("--version", action="version", version=f"nrmicp {nrmicp.__version__}")
    p.add_argument("command", choices=tuple(_COMMANDS), help="what to run")
    p.add_argument("args", nargs=argparse.REMAINDER, help="options of the command")
    return p


def main(argv: Optional[list[str]] = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    prog = prog_name()
    parser = _parser(prog)
    if not argv:  # nothing asked: say how to ask, and fail (as argparse does for a missing argument)
        parser.print_usage(sys.stderr)
        print(f"{prog}: error: a command is required ({', '.join(_COMMANDS)}); see '{prog} --help'",
              file=sys.stderr)
        return 2
    ns = parser.parse_args(argv)
    if ns.command == "demo":
        from .demo import demo
        return demo(ns.args, prog=f"{prog} demo")
    if "--family" in ns.args:  # the paper's comparison: every member on Bai's matrices and the scenes
        from . import family
        return family.main([a for a in ns.args if a != "--family"], prog=f"{prog} bench --family")
    from . import realistic
    return realistic.main(ns.args, prog=f"{prog} bench")
