"""ISO 9283 path characteristics (clauses 8.2-8.5, 11) of a measured stream against a commanded path.

Pure functions, arrays in and results out: :mod:`.commanded` (the commanded
path and its normal planes), :mod:`.passes` (the cycles in a stream),
:mod:`.accuracy` (AT, RT), :mod:`.cornering` (CR, CO), :mod:`.velocity` (AV,
RV, FV), :mod:`.weaving` (WS, WF), :mod:`.path_file` (the path file),
:mod:`.analysis` (all of it for one stream), :mod:`.figures` (names, units).
"""
