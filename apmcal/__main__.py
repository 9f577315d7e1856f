import sys

from apmcal.cli import main

sys.exit(main())
