"""tactile-gateway: Modbus tactile arrays to drift-corrected forces, metrics and records.

The rooms, in the one direction their imports run (``tests/unit/gateway/test_architecture.py``):

* ``model``: the physics of the piezoresistive sensor (paper eq. 1-18), numpy and scipy only;
* ``modbus``: register map, read plan, decoding, the transport interface and its clients;
* ``config``: the TOML configuration, validated into frozen dataclasses;
* ``runtime``: bus poll loops, conversion of polls into forces, immutable snapshots;
* ``metrics``: the Prometheus collector and the ``/metrics`` server;
* ``analysis``: measurement records, fitting, calibration, the discrepancy workflow, the paper;
* ``cli``: the ``tactile-gateway`` command line, the only place that wires in the simulator.

``errors`` (the typed errors) and ``atomic`` (atomic file writes) serve every room.
"""
