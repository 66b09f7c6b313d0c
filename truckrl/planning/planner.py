"""The planner's names under their former module path, for code that still imports them from here
(the package :mod:`truckrl.planning` is where they live now)."""

from truckrl.planning import *  # noqa: F403
from truckrl.planning import __all__  # noqa: F401
