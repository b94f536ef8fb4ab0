"""``python -m c2farm ARGS`` runs ``c2farm ARGS``: the same entry point as the console script.

Useful where the venv's ``bin/`` is not on PATH (``.venv/bin/python -m c2farm launch``).
"""

import sys

from deploy.cli import main

if __name__ == "__main__":
    sys.exit(main())
