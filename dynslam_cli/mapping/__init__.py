"""Mapping (paper Sec. 3): what the scans say about the world.

``grid`` holds the growable log-odds grids and traces each beam through them; ``dynamic``
holds Tables 1 and 2, the neighbourhood rule and ``DynamicMapper``, which updates the
static map S and the dynamic map D from each scan and its pose. The compiled inner loops
are in ``_grid.pyx``. Nothing here knows how the pose was found.
"""
