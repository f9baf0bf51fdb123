"""Compatibility shim for Debian's ParaView 5.11 under Python 3.11.

ParaView 5.11's Python-plugin decorators (``paraview/detail/pythonalgorithm.py``)
do ``from inspect import getargspec``, which Python 3.11 removed, so
``LoadPlugin`` of any Python plugin fails with "Problem loading plugin". Python
imports a module named ``sitecustomize`` from ``sys.path`` at start-up, so a
directory holding this file on ``PYTHONPATH`` restores the name before the
plugin loader runs. ``getfullargspec`` returns a superset of what the decorators
read (``.args``). ParaView 5.12 no longer needs this; the shim does nothing
where ``getargspec`` exists.
"""

import inspect

if not hasattr(inspect, "getargspec"):
    inspect.getargspec = inspect.getfullargspec
