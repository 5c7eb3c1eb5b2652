"""`python -m map_server router|server|status|query`."""

import sys

from map_server.cli import main

sys.exit(main())
