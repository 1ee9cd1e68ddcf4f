"""The front doors: the command line, the operator's page, the acceptance API and its pytest plugin,
and the assembly of a run. The roof of the house: it may import procedures, drivers, fakes and the core;
nothing below imports it."""
