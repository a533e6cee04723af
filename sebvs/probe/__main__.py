"""`python -m sebvs.probe`: the same command as `sebvs probe` (sebvs/probe/cli.py)."""
import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
