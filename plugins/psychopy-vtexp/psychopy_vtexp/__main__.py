"""``python -m psychopy_vtexp EXPERIMENT.psyexp [SCRIPT.py]``: compile a Builder experiment
as Builder does, with PsychoPy's plugins active (``python -m
psychopy.scripts.psyexpCompile`` loads none, and drops every Tactile stimulus component as
an unknown one). The script is written beside the experiment unless named."""

from __future__ import annotations

import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args or len(args) > 2 or args[0] in ("-h", "--help"):
        print(__doc__.strip())
        return 0 if args and args[0] in ("-h", "--help") else 2
    psyexp = Path(args[0])
    if psyexp.suffix != ".psyexp" or not psyexp.is_file():
        print(f"psychopy-vtexp: error: {psyexp}: no such Builder experiment (.psyexp)",
              file=sys.stderr)
        return 2
    script = Path(args[1]) if len(args) == 2 else psyexp.with_suffix(".py")
    from psychopy import plugins
    plugins.activatePlugins()
    from psychopy.scripts.psyexpCompile import compileScript
    compileScript(str(psyexp), None, str(script))
    print(f"compiled: {script}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
