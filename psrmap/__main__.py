import sys

from psrmap.cli import main

sys.exit(main())
