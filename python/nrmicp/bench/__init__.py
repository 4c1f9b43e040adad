"""Around the library, not part of it: the command line (``nrmicp demo``, ``nrmicp bench``; cli.py, argtypes.py),
the demo table (demo.py), the work-precision benches on realistic scenes (realistic.py) and over
the whole family (family.py), and the peers they compare with (peers.py: projected SOR, QP solvers).
They use nrmicp's public API and scenes; nothing in the library imports them."""
