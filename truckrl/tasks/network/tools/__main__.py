"""``python -m truckrl.tasks.network.tools``: the chained intersection cells (this package's
``main``)."""

import sys

from truckrl.tasks.network.tools import main

sys.exit(main())
