"""``python -m actors.demos --task reach_target --episodes 2 --out /tmp/d``."""

import sys

from actors.demos.cli import main

sys.exit(main())
