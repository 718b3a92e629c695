import sys

from plmarl_sitl.cli import main

sys.exit(main())
