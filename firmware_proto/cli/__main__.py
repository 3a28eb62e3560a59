"""``python -m firmware_proto.cli``: the ``rover`` command, where no console script is
installed (docs/ros2.md)."""

import sys

from firmware_proto.cli import main

sys.exit(main())
