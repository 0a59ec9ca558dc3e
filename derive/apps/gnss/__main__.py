"""`python -m derive.apps.gnss`: the real-data GNSS table."""

import sys

from derive.apps.gnss.command import main

sys.exit(main())
