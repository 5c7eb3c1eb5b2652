"""`python -m map_server router|server|remove`."""

import sys

from map_server.cli import main

sys.exit(main())
