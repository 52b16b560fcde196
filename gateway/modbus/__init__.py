"""Modbus: the register map, the read plan, register decoding and the pymodbus client.

* ``register_map``: the one module that knows the layout of ``docs/register-map.md``;
* ``plan``: the coalesced reads of one poll;
* ``decode``: uint16/uint32/uint64/float32/bitmap codecs with word and byte order;
* ``image``: the registers a poll returned, decoded into a ``RawSample``;
* ``client``: ``ModbusTransport``, the only module that imports pymodbus.
* ``scan``: what repeated reads of an unknown device suggest (``analyse``), built of
  ``scan_types`` (snapshots, thresholds, results), ``scan_stats`` (per-register statistics),
  ``scan_frames`` (ADC frame candidates), ``scan_clocks`` (clock candidates) and
  ``scan_snippet`` (constant runs, text, the TOML snippet); ``scan_read`` reads the registers
  for it (read functions only).

This layer knows the physics model's nothing and the runtime's nothing: it turns requests
into registers and registers into numbers.
"""
