"""Run ``accel-calib`` as ``python -m accel_calib_ros.cli``."""

import sys

from . import main

sys.exit(main())
