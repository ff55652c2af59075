"""The ``cgenreg`` console script this package installs: the command line, run in-process by
the extension (every headless command: register, bench, study, table, diff, cache, generate,
merge, status, slurm). ``inspect``/``screenshot`` need the GUI: they run in-process when the
extension was built with it, else they are handed to the native ``cgenreg`` binary when one is
found (``$CGENREG_BIN`` or ``PATH``)."""

from __future__ import annotations

import os
import sys
from typing import List, Optional

from . import _cgenreg

_GUI_COMMANDS = {"inspect", "gui", "screenshot"}


def _wants_gui(args: List[str]) -> bool:
    first = next((a for a in args if not a.startswith("-")), None)
    if first is None:
        return not any(a in ("-h", "--help", "-V", "--version") for a in args)
    return first in _GUI_COMMANDS


def main(argv: Optional[List[str]] = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not _cgenreg.HAS_GUI and _wants_gui(args):
        from .errors import CgenregError
        from .inspector import HANDOFF_ENV, inspector_command

        try:
            cmd = inspector_command()
        except CgenregError as e:
            print("cgenreg: error: %s" % e, file=sys.stderr)
            return 1
        # the program handed to knows it was: if it is this console script again, it stops
        # instead of handing the command on forever
        env = dict(os.environ)
        env[HANDOFF_ENV] = "1"
        if os.name == "posix":
            # replaces this process; an argument vector, no shell
            os.execvpe(cmd[0], cmd + args, env)
        import subprocess

        return subprocess.call(cmd + args, env=env)
    return _cgenreg.cli_main(["cgenreg"] + args)


if __name__ == "__main__":
    sys.exit(main())
