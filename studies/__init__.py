"""The package's studies: thin scripts over the library and the ``heli-uq`` command
(``python -m studies list`` / ``python -m studies run --size quick|paper``)."""
