"""`python -m robot_demo [--only CHAPTER ...] [--keep-running] [--rviz]`: run the demo."""
import sys

from robot_demo.app import main

sys.exit(main())
