import sys

from .cli import main

# `python -m tensorid` exits as Python does (runpy, profilers); the installed
# `tensorid` command uses cli.console, which skips the interpreter's teardown
sys.exit(main())
