import sys

from ops_ros2cli.cli import main

sys.exit(main())
