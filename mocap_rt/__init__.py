"""mocap_rt: real-time marker-free multi-camera human motion capture.

The library is pure computation on numpy arrays; transport (zenoh) and viewing
(rerun) live in the ``nodes`` package.
"""

__version__ = "0.1.0"
