"""nrmicp.bench.peers — PSOR, the QP calls, the eps tuning and the peers' stopping rule, written once
for the work-precision bench and the peer tables here — also when nrmicp is not installed
(``run_peers.py --allow-no-nrmicp``): then the source tree's python/nrmicp/bench/peers.py, which
needs only numpy and scipy."""
from __future__ import annotations

import importlib.util
import os

try:
    from nrmicp.bench import peers
except ImportError:
    _path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "python", "nrmicp", "bench",
                         "peers.py")
    _spec = importlib.util.spec_from_file_location("_nrmicp_peers_src", _path)
    peers = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(peers)

__all__ = ["peers"]
