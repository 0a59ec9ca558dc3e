"""`python -m derive.gnss`: the real-data GNSS table."""

import sys

from derive.gnss.command import main

sys.exit(main())
