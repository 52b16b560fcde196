"""The runtime: polling buses, converting polls into forces, publishing snapshots.

* ``bus``: ``BusWorker``, the poll loop of one bus (retries, back-off, conversion steps);
* ``poller``: ``Poller`` (every bus, reload, poll-once) and ``SnapshotHolder``;
* ``processor``: ``DeviceProcessor``, one poll's registers into drift-corrected forces;
* ``snapshot``: the immutable ``DeviceSnapshot`` / ``GatewaySnapshot``;
* ``counters``: reads, errors and poll durations per device.
"""
